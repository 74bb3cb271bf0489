"""What the LinuxCNC integration modules share: paths, the skip marks, the CLI in JSON, the machine lock.

LinuxCNC tests never wait for the machine: ``conftest.py`` takes ilcnc's run
lock for this pytest process (:class:`SessionLock`, lock timeout 0) before the
first test marked ``linuxcnc`` and keeps it until the last test of this
folder; every ``run_program`` in between nests inside it. When another
process holds the lock, or a LinuxCNC that ilcnc did not start is running, the
test is skipped with a reason naming it (pid, user, program, how long).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.shop import linuxcnc as lcnc

REPO = Path(__file__).resolve().parents[2]
PROFILE = REPO / "configs" / "linuxcnc-sim.yaml"
HAVE_LINUXCNC = shutil.which("linuxcnc") is not None
runner = CliRunner()


def needs_linuxcnc(what: str = "cannot run programs on LinuxCNC's motion controller") -> list[Any]:
    """Marks of a test that runs LinuxCNC: ``linuxcnc``, and a skip with a visible reason where it is missing."""
    return [
        pytest.mark.linuxcnc,
        pytest.mark.skipif(not HAVE_LINUXCNC, reason="LinuxCNC is not installed ('linuxcnc' not on PATH; Debian 12: "
                           f"apt-get install linuxcnc-uspace): {what}"),
    ]


def cli_json(*args: object) -> dict[str, Any]:
    """Run ``ilcnc ARGS --json``; it must succeed. Returns its JSON object."""
    res = runner.invoke(app, [str(a) for a in args] + ["--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


def busy_reason() -> str | None:
    """Why a LinuxCNC test cannot run now without waiting (another process holds the lock, or another LinuxCNC runs)."""
    h = lcnc.lock_holder()
    if h is not None and h.pid != os.getpid():
        return f"another ilcnc LinuxCNC run holds {lcnc.LOCK_PATH}: {h.describe()}"
    other = lcnc.other_linuxcnc()
    if other is not None:
        return f"another LinuxCNC (not started by ilcnc) is running: {other.describe()}"
    return None


class SessionLock:
    """ilcnc's run lock, held by this pytest process across its LinuxCNC tests (the runs nest inside it)."""

    def __init__(self) -> None:
        self._stack: contextlib.ExitStack | None = None

    @property
    def held(self) -> bool:
        return self._stack is not None

    def acquire(self, what: str = "pytest: LinuxCNC integration tests") -> str | None:
        """Take the lock without waiting (if not held yet). Returns the skip reason when the machine is busy."""
        if self._stack is None:
            stack = contextlib.ExitStack()
            try:
                stack.enter_context(lcnc.run_lock(0, program=what))
            except lcnc.LinuxCNCBusyError as exc:
                return exc.problem  # names the holder, ends 'not waiting (lock timeout 0)'
            self._stack = stack
            lcnc._recover_previous()  # what a crashed earlier ilcnc run left behind, as run_program does
        other = lcnc.other_linuxcnc()
        if other is not None:
            return f"another LinuxCNC (not started by ilcnc) is running, not waiting: {other.describe()}"
        return None

    def release(self) -> None:
        if self._stack is not None:
            stack, self._stack = self._stack, None
            stack.close()
