"""LinuxCNC tests never wait for the machine: they hold ilcnc's run lock or are skipped naming who has it."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.integration._lcnc import SessionLock

HERE = Path(__file__).resolve().parent
_LOCK = SessionLock()


def pytest_runtest_setup(item: pytest.Item) -> None:
    # runs before the test's fixtures (module-scoped runs included) and after the 'LinuxCNC is not installed' skips
    if item.get_closest_marker("linuxcnc") is None:
        return
    reason = _LOCK.acquire()
    if reason is not None:
        pytest.skip(reason)


def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> None:
    if nextitem is None or HERE not in Path(nextitem.path).resolve().parents:
        _LOCK.release()  # the last test of this folder: let other runs have the machine


def pytest_sessionfinish(session: pytest.Session) -> None:
    _LOCK.release()
