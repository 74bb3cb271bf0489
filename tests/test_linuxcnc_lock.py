"""The LinuxCNC run lock: who holds it, the waiting line, ``--lock-timeout``, the tests' skip helper.

None of these tests needs LinuxCNC or launches it: the lock, the state file and
LinuxCNC's own lock file are redirected to ``tmp_path``, and launching is
replaced by a failure. Another holder is a subprocess (``flock`` conflicts
between processes, and between separate open files within one).
"""

from __future__ import annotations

import getpass
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.shop import linuxcnc as lcnc
from tests.integration._lcnc import SessionLock, busy_reason

REPO = Path(__file__).resolve().parents[1]
SQUARE = REPO / "samples" / "own" / "square.ngc"

_HOLDER = """
import sys
from ilcnc.shop import linuxcnc as lcnc
with lcnc.run_lock(0, sys.argv[1]):
    print("ready", flush=True)
    sys.stdin.read()
"""


@pytest.fixture
def private_lock(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The lock, state file and LinuxCNC's lock file in tmp_path; launching LinuxCNC fails the test."""
    monkeypatch.setattr(lcnc, "LOCK_PATH", tmp_path / "ilcnc-linuxcnc.lock")
    monkeypatch.setattr(lcnc, "STATE_PATH", tmp_path / "ilcnc-linuxcnc.json")
    monkeypatch.setattr(lcnc, "LINUXCNC_LOCKFILE", tmp_path / "linuxcnc.lock")
    monkeypatch.setattr(lcnc, "linuxcnc_available", lambda: None)

    def no_launch(*args: object) -> None:
        raise AssertionError("the test must not launch LinuxCNC")

    monkeypatch.setattr(lcnc, "_launch", no_launch)
    return tmp_path


@pytest.fixture
def holder(private_lock: Path) -> Iterator[subprocess.Popen[str]]:
    """Another process holding the (private) lock for program 'held.ngc'."""
    env = dict(os.environ, TMPDIR=str(private_lock), PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, "held.ngc"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
    yield proc
    if proc.stdin is not None:
        proc.stdin.close()
    proc.wait(timeout=10)


def _release(proc: subprocess.Popen[str]) -> None:
    assert proc.stdin is not None
    proc.stdin.close()
    proc.wait(timeout=10)


def test_holder_record_names_pid_user_program_since(holder: subprocess.Popen[str]) -> None:
    t0 = time.time()
    h = lcnc.lock_holder()
    assert h is not None
    assert (h.pid, h.user, h.program, h.kind) == (holder.pid, getpass.getuser(), "held.ngc", "ilcnc")
    assert h.since is not None and t0 - 30 < h.since <= time.time()
    rec = json.loads(lcnc.LOCK_PATH.read_text().splitlines()[0])  # readable by anyone: one JSON line
    assert rec["pid"] == holder.pid and rec["program"] == "held.ngc"
    _release(holder)
    assert lcnc.lock_holder() is None
    assert lcnc.LOCK_PATH.read_text() == ""  # no stale record once released


def test_holder_without_record_is_found_through_proc_locks(private_lock: Path) -> None:
    # an older ilcnc holds the lock without writing a record
    code = ("import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDONLY | os.O_CREAT); fcntl.flock(fd, fcntl.LOCK_EX);"
            " print('ready', flush=True); sys.stdin.read()")
    proc = subprocess.Popen([sys.executable, "-c", code, str(lcnc.LOCK_PATH)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        h = lcnc.lock_holder()
        assert h is not None and h.pid == proc.pid and "fcntl" in (h.command or "")
        assert "since unknown" in h.describe()
    finally:
        _release(proc)


def test_describe_is_one_line_with_who_and_how_long() -> None:
    now = time.time()
    h = lcnc.LockHolder(pid=42, user="ann", program="part.ngc", command="ilcnc linuxcnc run part.ngc", since=now - 75)
    text = h.describe(now)
    assert text.startswith("pid 42 (user ann, program part.ngc, command 'ilcnc linuxcnc run part.ngc', since ")
    assert text.endswith("held for 75 s)") and "\n" not in text
    assert lcnc.LockHolder(pid=7, user="bob", since=now - 600, kind="linuxcnc").describe(now).endswith("running for 10 min)")
    assert lcnc.LockHolder(pid=None).describe() == "an unknown process"


def test_run_lock_says_once_whom_it_waits_for_then_names_the_holder(holder: subprocess.Popen[str]) -> None:
    lines: list[str] = []
    t = time.monotonic()
    with pytest.raises(lcnc.LinuxCNCBusyError) as err, lcnc.run_lock(0.4, "mine.ngc", lines.append):
        pass
    assert 0.35 < time.monotonic() - t < 5
    assert len(lines) == 1 and lines[0].startswith("waiting up to 0.4 s for the LinuxCNC run lock")
    assert f"pid {holder.pid} (user {getpass.getuser()}, program held.ngc" in lines[0]
    msg = err.value.format()
    assert msg.startswith("mine.ngc: another ilcnc LinuxCNC run holds") and f"pid {holder.pid}" in msg
    assert msg.endswith("gave up after the lock timeout of 0.4 s") and err.value.holder.pid == holder.pid
    lines.clear()
    with pytest.raises(lcnc.LinuxCNCBusyError, match="not waiting"), lcnc.run_lock(0, "mine.ngc", lines.append):
        pass
    assert lines == []


def test_run_lock_nests_in_its_thread_and_conflicts_across_threads(private_lock: Path) -> None:
    errors: list[BaseException] = []

    def other_thread() -> None:
        try:
            with lcnc.run_lock(0, "thread.ngc"):
                pass
        except lcnc.LinuxCNCBusyError as exc:
            errors.append(exc)

    with lcnc.run_lock(0, "outer.ngc") as outer:
        with lcnc.run_lock(0, "inner.ngc") as inner:  # same thread: nested, no wait
            assert inner.since == outer.since and inner.program == "inner.ngc"
            assert json.loads(lcnc.LOCK_PATH.read_text())["program"] == "inner.ngc"
        assert json.loads(lcnc.LOCK_PATH.read_text())["program"] == "outer.ngc"
        th = threading.Thread(target=other_thread)
        th.start()
        th.join(10)
    assert len(errors) == 1 and f"pid {os.getpid()}" in str(errors[0])
    assert lcnc.lock_holder() is None


def _invoke(*args: object):  # type: ignore[no-untyped-def]
    return CliRunner().invoke(app, [str(a) for a in args])


def test_cli_lock_timeout_0_fails_at_once_naming_the_holder(holder: subprocess.Popen[str], tmp_path: Path) -> None:
    t = time.monotonic()
    r = _invoke("linuxcnc", "run", SQUARE, "--log-out", tmp_path / "x.csv", "--lock-timeout", 0)
    assert r.exit_code == 1, r.output
    assert time.monotonic() - t < 5
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {SQUARE}: another ilcnc LinuxCNC run holds"), r.stderr
    assert f"pid {holder.pid} (user {getpass.getuser()}, program held.ngc" in lines[0] and "not waiting" in lines[0]
    assert not (tmp_path / "x.csv").exists()


def test_cli_prints_whom_it_waits_for_and_for_how_long(holder: subprocess.Popen[str], tmp_path: Path) -> None:
    r = _invoke("linuxcnc", "run", SQUARE, "--log-out", tmp_path / "x.csv", "--lock-timeout", 0.5)
    assert r.exit_code == 1, r.output
    lines = r.stderr.splitlines()
    assert len(lines) == 2, r.stderr
    assert lines[0].startswith("waiting up to 0.5 s for the LinuxCNC run lock") and f"pid {holder.pid}" in lines[0]
    assert lines[1].startswith("error: ") and lines[1].endswith("gave up after the lock timeout of 0.5 s")


@pytest.mark.parametrize("value", ["-1", "nan", "abc"])
def test_cli_lock_timeout_range_is_a_usage_error(value: str, tmp_path: Path) -> None:
    r = _invoke("linuxcnc", "run", SQUARE, "--log-out", tmp_path / "x.csv", "--lock-timeout", value)
    assert r.exit_code == 2 and "--lock-timeout" in r.output, r.output  # like --timeout, --settle


def test_library_refuses_a_negative_or_nan_lock_timeout(private_lock: Path, tmp_path: Path) -> None:
    for bad in (-1.0, float("nan")):
        with pytest.raises(lcnc.InputError, match="lock timeout must be >= 0 s"):
            lcnc.run_program(SQUARE, log_path=tmp_path / "x.log", lock_timeout_s=bad)


def test_a_linuxcnc_not_started_by_ilcnc_is_named_not_collided_with(private_lock: Path, tmp_path: Path) -> None:
    fake = tmp_path / "milltask"  # /proc/PID/comm of a copy of sleep is 'milltask'
    shutil.copy(shutil.which("sleep") or "/bin/sleep", fake)
    proc = subprocess.Popen([str(fake), "60"])
    try:
        deadline = time.monotonic() + 5
        while proc.pid not in lcnc._linuxcnc_pids()[1] and time.monotonic() < deadline:
            time.sleep(0.02)
        assert proc.pid in lcnc._linuxcnc_pids()[1]
        other = lcnc.other_linuxcnc()
        assert other is not None and other.kind == "linuxcnc" and other.since is not None
        r = _invoke("linuxcnc", "run", SQUARE, "--log-out", tmp_path / "x.csv", "--lock-timeout", 0)
        assert r.exit_code == 1, r.output
        lines = r.stderr.splitlines()
        assert len(lines) == 1 and "another LinuxCNC is running, not started by ilcnc: pid " in lines[0], r.stderr
        assert "does not stop someone else's; not waiting (lock timeout 0)" in lines[0]
        assert lcnc.lock_holder() is None  # the lock was released again
    finally:
        proc.kill()
        proc.wait()


def test_skip_helper_names_the_holder_and_takes_the_lock_when_free(
    holder: subprocess.Popen[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(lcnc, "other_linuxcnc", lambda: None)  # a LinuxCNC running elsewhere on this machine is no matter here
    reason = busy_reason()
    assert reason is not None and f"pid {holder.pid}" in reason and "program held.ngc" in reason and "held for" in reason
    lock = SessionLock()
    reason = lock.acquire()
    assert reason is not None and reason.startswith("another ilcnc LinuxCNC run holds")
    assert reason.endswith("not waiting (lock timeout 0)")
    assert f"pid {holder.pid}" in reason and not lock.held
    _release(holder)
    assert busy_reason() is None
    try:
        assert lock.acquire() is None and lock.held
        assert busy_reason() is None  # held by this process: not a reason to skip
        h = lcnc.lock_holder()
        assert h is not None and h.pid == os.getpid() and h.program == "pytest: LinuxCNC integration tests"
        with lcnc.run_lock(0, "a-test.ngc"):  # a run inside the session nests, no wait
            pass
        fake = lcnc.LockHolder(pid=99, user="eve", command="linuxcnc -r sim.ini", since=time.time() - 3, kind="linuxcnc")
        monkeypatch.setattr(lcnc, "other_linuxcnc", lambda: fake)
        reason = lock.acquire()
        assert reason is not None and reason.startswith("another LinuxCNC (not started by ilcnc) is running")
        assert "pid 99 (user eve" in reason and "running for 3 s" in reason
    finally:
        lock.release()
    assert lcnc.lock_holder() is None
