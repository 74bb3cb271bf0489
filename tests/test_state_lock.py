"""One ``ilcnc learn`` at a time on a learning state (issue 25 item 10).

Before, two learns on one ``--state`` both exited 0; 1 of 4 trials left the state damaged for good and 3
of 4 lost an output. Now the second is refused with one line naming the holder, the lock leaves no file
behind, and a holder killed with SIGKILL leaves no lock.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.shop.state import state_lock

from .conftest import cli_output

REPO = Path(__file__).resolve().parents[1]
MILL = REPO / "configs" / "example-mill.yaml"
STAR = REPO / "samples" / "own" / "star.ngc"
runner = CliRunner()


def _learn(tmp: Path, out: str = "o.ngc") -> object:
    return runner.invoke(app, ["learn", str(STAR), "--profile", str(MILL), "--out", str(tmp / out), "--state",
                               str(tmp / "S"), "--iterations", "1"])


def test_a_second_learn_on_a_state_in_use_is_refused(tmp_path: Path) -> None:
    with state_lock(tmp_path / "S"):
        res = _learn(tmp_path)
        assert res.exit_code == 1, res.output  # type: ignore[attr-defined]
        line = res.output.strip()  # type: ignore[attr-defined]
        assert line.startswith(f"error: {tmp_path / 'S'}: is in use by another ilcnc learn (pid {os.getpid()}, since ")
        assert not (tmp_path / "S").exists() and not (tmp_path / "o.ngc").exists()
    assert _learn(tmp_path).exit_code == 0  # type: ignore[attr-defined]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["S", "o.ngc"]  # the lock file is gone again


def test_a_killed_holder_leaves_no_lock(tmp_path: Path) -> None:
    code = ("import sys, time\nfrom pathlib import Path\nfrom ilcnc.shop.state import state_lock\n"
            "with state_lock(Path(sys.argv[1])):\n    print('held', flush=True)\n    time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "S")], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
        assert _learn(tmp_path).exit_code == 1  # type: ignore[attr-defined]
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    res = _learn(tmp_path)  # the kernel freed the lock with the process: taken at once
    assert res.exit_code == 0, res.output  # type: ignore[attr-defined]


def test_what_a_killed_run_left_before_its_first_index_is_replaced(tmp_path: Path) -> None:
    """Issue 25 item 11: a run killed between creating its state and writing state.json left a folder that
    blocked every rerun ("is not empty and holds no learning state"). Its own files are replaced now; a folder
    with anything else in it is still refused."""
    s = tmp_path / "S"
    s.mkdir()
    (s / "original.ngc").write_bytes(STAR.read_bytes())
    (s / "iter-000.ngc").write_bytes(STAR.read_bytes())
    (s / "iter-000.corrections.csv").write_text("k,dx,dy,dz\n")
    (s / ".iter-000.errors.csv.k2j4x.tmp").write_text("k,ex")
    res = _learn(tmp_path)
    assert res.exit_code == 0, res.output  # type: ignore[attr-defined]
    assert (s / "state.json").is_file() and not list(s.glob(".*.tmp"))
    t = tmp_path / "T"
    t.mkdir()
    (t / "original.ngc").write_bytes(STAR.read_bytes())
    (t / "notes.txt").write_text("the operator's notes\n")
    res = runner.invoke(app, ["learn", str(STAR), "--profile", str(MILL), "--out", str(tmp_path / "p.ngc"), "--state",
                              str(t), "--iterations", "1"])
    assert res.exit_code == 1 and "is not empty and holds no learning state" in res.output  # type: ignore[attr-defined]
    assert (t / "notes.txt").read_text() == "the operator's notes\n" and (t / "original.ngc").exists()


def test_a_corrections_file_changed_by_hand_is_refused(tmp_path: Path) -> None:
    """Issue 25 item 9: a row of iter-001.corrections.csv changed to 0.4 mm by hand was used silently (and kept
    at 669 µm max). Every CSV the state relies on is hash-checked now, like its programs."""
    log = tmp_path / "run0.csv"
    assert runner.invoke(app, ["simulate", str(STAR), "--profile", str(MILL), "--log-out", str(log)]).exit_code == 0
    s = tmp_path / "S"
    res = runner.invoke(app, ["learn", str(STAR), "--profile", str(MILL), "--log", str(log), "--state", str(s),
                              "--out", str(tmp_path / "star.1.ngc")])
    assert res.exit_code == 0, res.output  # type: ignore[attr-defined]
    csv = s / "iter-001.corrections.csv"
    rows = csv.read_text().splitlines()
    k, *_ = rows[3].split(",")
    rows[3] = f"{k},0.400000000,0.000000000,0.000000000"
    csv.write_text("\n".join(rows) + "\n")
    res = runner.invoke(app, ["learn", str(tmp_path / "star.1.ngc"), "--profile", str(MILL), "--log", str(log),
                              "--state", str(s), "--out", str(tmp_path / "star.2.ngc")])
    assert res.exit_code == 1, res.output  # type: ignore[attr-defined]
    assert cli_output(res).strip() == (f"error: {csv}: changed since ilcnc wrote it (hash mismatch): the learning state is"  # type: ignore[attr-defined]
                                  " damaged")
    assert not (tmp_path / "star.2.ngc").exists()
