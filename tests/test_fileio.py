"""Outputs get the permissions a shop expects (issue 25 item 12).

``write_atomic`` wrote every output mode 0600 (``mkstemp``'s), whatever the umask; replacing an output
dropped its mode; ``identify --write`` turned a 0644 profile into 0600. Now a new output has ``0666``
less the umask, as ``open()`` gives, and a replaced one keeps its mode.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.fileio import current_umask, write_atomic

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def umask() -> Iterator[None]:
    old = os.umask(0o022)
    os.umask(old)
    yield
    os.umask(old)


def _mode(p: Path) -> int:
    return stat.S_IMODE(p.stat().st_mode)


@pytest.mark.parametrize(("mask", "want"), [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_a_new_output_has_the_mode_the_umask_gives(tmp_path: Path, umask: None, mask: int, want: int) -> None:
    os.umask(mask)
    assert current_umask() == mask
    out = write_atomic(tmp_path / "part.ngc", "G1 X1\n")
    assert _mode(out) == want
    assert [p.name for p in tmp_path.iterdir()] == ["part.ngc"]  # no temporary file left


def test_a_replaced_output_keeps_its_mode(tmp_path: Path, umask: None) -> None:
    os.umask(0o077)
    p = tmp_path / "part.ngc"
    p.write_text("old\n")
    p.chmod(0o640)
    write_atomic(p, "new\n")
    assert p.read_text() == "new\n" and _mode(p) == 0o640


def test_identify_write_keeps_the_profile_mode(tmp_path: Path, umask: None) -> None:
    os.umask(0o022)
    prof = tmp_path / "mill.yaml"
    prof.write_bytes((REPO / "configs" / "example-mill.yaml").read_bytes())
    prof.chmod(0o644)
    res = CliRunner().invoke(app, ["identify", str(REPO / "tests" / "data" / "identify" / "tncscope_x_sopdt.csv"),
                                   "--axis", "x", "--profile", str(prof), "--write"])
    assert res.exit_code == 0, res.output
    assert "omega0_rad_s: 96." in prof.read_text() and _mode(prof) == 0o644


def test_unsynced_writes_skip_fsync_in_this_thread_only(tmp_path, monkeypatch) -> None:
    import threading

    from ilcnc import fileio

    synced: list[str] = []
    real = os.fsync
    monkeypatch.setattr(fileio.os, "fsync", lambda fd: (synced.append(threading.current_thread().name), real(fd)))
    other_done = threading.Event()

    def other() -> None:  # another thread of the process (the client of an in-process cluster) keeps syncing
        fileio.write_atomic(tmp_path / "kept.txt", "kept\n")
        other_done.set()

    with fileio.unsynced_writes():
        fileio.write_atomic(tmp_path / "scratch.txt", "scratch\n")
        t = threading.Thread(target=other, name="client")
        t.start()
        t.join(10)
    fileio.write_atomic(tmp_path / "after.txt", "after\n")
    assert other_done.is_set() and synced == ["client", threading.current_thread().name]
    assert (tmp_path / "scratch.txt").read_text() == "scratch\n" and (tmp_path / "kept.txt").read_text() == "kept\n"
