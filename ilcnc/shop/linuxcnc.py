"""Run a part program on LinuxCNC's own motion controller (headless simulation) and log it.

LinuxCNC (Debian package ``linuxcnc-uspace``) plans and interpolates the
program exactly as it would on a machine; the configuration in
``configs/linuxcnc-sim`` closes a lagging position loop in HAL (P loop and a
first-order velocity drive), so the log has a commanded *and* an actual
position, sampled every servo cycle by ``halsampler``. See
``configs/linuxcnc-sim/README.md`` and ``docs/linuxcnc.md``.

How a run works (:func:`run_program`)
--------------------------------------
1. The configuration folder is copied to a private run directory; the INI is
   rewritten there (overrides, time scaling) -- the folder itself is never
   modified (the interpreter rewrites its parameter file in the copy).
2. A machine-wide ``fcntl`` lock serialises runs: LinuxCNC is a single
   instance per machine (fixed lock file and shared-memory keys; a second
   launch kills the first). The holder writes who it is into the lock file
   (pid, user, program, since); a run that has to wait tells ``on_wait`` who
   holds it and how long it will wait (``lock_timeout_s``), then gives up
   with :class:`LinuxCNCBusyError` naming the holder (:func:`run_lock`).
3. Leftovers of a crashed earlier run are cleaned up: a launcher that an
   earlier ilcnc process started and did not see finish is stopped; a stale
   ``/tmp/linuxcnc.lock`` with no launcher alive is left to the launcher's
   own automatic clean-up (it runs without a tty). A LinuxCNC that someone
   else is running (a launcher, ``linuxcncsvr``, ``milltask`` or
   ``rtapi_app`` alive) is never touched: the run waits for it like for the
   lock, and names it (:func:`other_linuxcnc`).
4. ``linuxcnc -r sim.ini`` runs in its own process group with the driver
   (``driver.py``, run by Debian's ``/usr/bin/python3``, which has the
   ``linuxcnc`` module) as its display: home, run the program, settle, drain
   the sampler, exit. As root, ``RTAPI_UID``/``RTAPI_FIFO_PATH`` are set
   (rtapi_app refuses root otherwise). ``linuxcnc`` is never imported here.
5. The driver's JSON result tells how it ended; the raw halsampler output is
   copied to ``log_path`` and read with :func:`ilcnc.axislog.halsampler.read_halsampler`.

Time scaling (``time_scale = k``): the servo period is divided by k, velocity
limits multiplied by k, accelerations by k^2, jerks by k^3, the loop gain
``[ILCNC] KV`` and every rate (``*FREQ``, with ``[TRAJ] ARC_BLEND_RAMP_FREQ``
written out at LinuxCNC's default when the INI leaves it out) by k, and the
program's F words by k (dwell times divided by k) in a temporary copy. Every
servo cycle is then the same as in the unscaled run, so the log is the same
sample sequence, produced k times faster; it is returned in real-time units.
Three things could still make it differ, and all are handled: (1) the
planner's first segments depend on what task has queued when motion starts
-- the simulation holds motion (``motion.feed-inhibit``) until the queue
stops growing and starts sampling in the cycle it releases it, and its dwell
gate does the same after each ``G4`` (task waits out a dwell in wall-clock
time, then refills the queue) with the simulated world frozen while it
waits; (2) task feeds the queue in wall-clock time (a few blocks per ms), so a
scaled run of many short blocks can drain the queue and the planner then sees
less look-ahead than in real time -- the driver detects a queue that ran low
while blocks were still to come, and the run is repeated at a smaller k
(``RunResult.time_scale`` is the k actually used; a message says so).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import pwd
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ilcnc.axislog.halsampler import HALSAMPLER_COLUMNS, read_halsampler
from ilcnc.axislog.log import AxisLog
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes, write_atomic
from ilcnc.shop.linuxcnc_config import ini_in, read_ini_text, scale_program_time, scaled_ini_text

__all__ = [
    "DEFAULT_CONFIG_DIR",
    "DEFAULT_LOCK_TIMEOUT_S",
    "MAX_TIME_SCALE",
    "LinuxCNCBusyError",
    "LockHolder",
    "RunResult",
    "linuxcnc_available",
    "lock_holder",
    "other_linuxcnc",
    "record_run",
    "run_lock",
    "run_program",
    "stray_percent_line"
]

#: The simulation configuration shipped with ilcnc (source checkout).
DEFAULT_CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs" / "linuxcnc-sim"
#: Largest time scale accepted. With the start gate of sim.hal, k = 2, 4, 5, 8 (and 10, 20, 40) gave logs
#: identical to k = 1 (LinuxCNC 2.9, 1 ms base period) as long as task keeps the motion queue filled;
#: a run whose queue ran low is repeated at a smaller k (see run_program). Above 8 the launch (~2.5 s)
#: dominates anyway and queue starvation gets likely, so 8 is the limit.
MAX_TIME_SCALE = 8
#: ilcnc's machine-wide run lock and the record of the launcher it started.
LOCK_PATH = Path(tempfile.gettempdir()) / "ilcnc-linuxcnc.lock"
STATE_PATH = Path(tempfile.gettempdir()) / "ilcnc-linuxcnc.json"
#: LinuxCNC's own single-instance lock (hard-coded in /usr/bin/linuxcnc).
LINUXCNC_LOCKFILE = Path("/tmp/linuxcnc.lock")
SYSTEM_PYTHON = Path("/usr/bin/python3")
FALLBACK_UID = 65534  # 'nobody': rtapi_app drops root to this uid
DEFAULT_TIMEOUT_S = 600.0
#: How long a run waits for the machine (another run's lock, another LinuxCNC) by default, s.
DEFAULT_LOCK_TIMEOUT_S = 600.0
_RUN_PREFIX = "ilcnc-lcnc-"
_STARTUP_MARGIN_S = 60.0  # launch, homing, settle, shutdown on top of the program's own time limit


@dataclass(slots=True)
class RunResult:
    """One program run on the LinuxCNC simulation.

    Attributes
    ----------
    program : Path
        The program that was run (the caller's path; a time-scaled run used a
        temporary copy with scaled F words).
    log_path : Path
        The raw halsampler output (columns :data:`ilcnc.axislog.halsampler.HALSAMPLER_COLUMNS`,
        one line per servo cycle of the scaled run).
    log : AxisLog
        The log aligned on the first non-zero program line (t_s = 0), in
        real-time units (t_s = sample x unscaled period), trimmed to
        ``settle_s`` after the last program line; ``k`` is -1 (see
        :func:`ilcnc.axislog.halsampler.commands_from_lines`).
    time_scale : int
        k.
    period_s : float
        Unscaled servo period, s (the log's sample period).
    wall_s : float
        Wall time of the whole LinuxCNC launch (start to shutdown), s.
    program_wall_s : float or None
        Wall time from AUTO_RUN to "program done", s.
    program_s : float
        Duration of the program in the log (first to last sample with a
        non-zero program line), real-time s.
    messages : list of str
        Non-error texts LinuxCNC reported (operator messages, ``(MSG,...)``).
    dwells_held : int
        Restarts after a stop (a dwell, a queue-busting block) that the configuration's dwell gate held until
        task had queued the next blocks (``configs/linuxcnc-sim/README.md``, "Dwell gate"; 0 for a configuration
        without one).
    dwells_missed : int
        Restarts the gate could not hold (their restart raced task); 0 with ``configs/linuxcnc-sim``, whose gate
        arms itself.
    """

    program: Path
    log_path: Path
    log: AxisLog
    time_scale: int
    period_s: float
    wall_s: float
    program_wall_s: float | None
    program_s: float
    messages: list[str] = field(default_factory=list)
    dwells_held: int = 0
    dwells_missed: int = 0


# ---------------------------------------------------------------------------
# Process handling
# ---------------------------------------------------------------------------


def linuxcnc_available() -> str | None:
    """None when LinuxCNC can be run here, else why not (one line)."""
    for exe in ("linuxcnc", "halsampler", "halcmd"):
        if shutil.which(exe) is None:
            return f"LinuxCNC is not installed ('{exe}' not on PATH; Debian 12: apt-get install linuxcnc-uspace)"
    if not SYSTEM_PYTHON.is_file():
        return f"{SYSTEM_PYTHON} (the Python with LinuxCNC's 'linuxcnc' module) does not exist"
    return None





def _proc_cmdline(pid: int) -> list[str] | None:
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return None
    return [a.decode("utf-8", "replace") for a in raw.split(b"\0") if a]


def _is_launcher(cmd: list[str] | None) -> bool:
    """True for the ``linuxcnc`` launcher script (``bash /usr/bin/linuxcnc ...``)."""
    if not cmd:
        return False
    return any(Path(a).name == "linuxcnc" for a in cmd[:2]) and "-ini" not in cmd[:3]


def _launchers_alive() -> list[int]:
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and _is_launcher(_proc_cmdline(int(d.name))):
            pids.append(int(d.name))
    return pids


def _wait_gone(pid: int, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        cmd = _proc_cmdline(pid)
        if cmd is None or not _is_launcher(cmd):
            return True
        time.sleep(0.05)
    return False


def _stop_group(pgid: int, pid: int, *, grace_s: float = 15.0) -> None:
    """Stop a launcher's process group that ilcnc started: SIGTERM (driver exits, launcher cleans up), then SIGKILL."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, signal.SIGTERM)
    if _wait_gone(pid, grace_s):
        return
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, signal.SIGKILL)
    _wait_gone(pid, 5.0)


def _pids_of_run(run_dir: Path) -> list[int]:
    """Processes started for one ilcnc run: every one of them inherited ``HOME=<its run directory>``."""
    marker = f"HOME={run_dir}".encode()
    me = os.getpid()
    pids = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == me:
            continue
        try:
            env = (d / "environ").read_bytes()
        except OSError:
            continue
        if marker in env.split(b"\0"):
            pids.append(int(d.name))
    return pids


def _run_env(run_dir: Path) -> dict[str, str]:
    """The environment LinuxCNC gets for a run in ``run_dir`` (without the ILCNC_* variables)."""
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}  # DISPLAY set: the launcher would ask via Tk
    env["HOME"] = str(run_dir)  # private tool mmap and debug files; also marks the run's processes
    env["PATH"] = env.get("PATH", "") + os.pathsep + "/usr/bin:/bin"
    if os.geteuid() == 0:
        # rtapi_app refuses to run as root unless given a fallback uid and a socket dir that uid can write
        env["RTAPI_UID"] = str(int(env.get("RTAPI_UID") or FALLBACK_UID))
        env["RTAPI_FIFO_PATH"] = str(run_dir / "fifo" / "rtapi_fifo")
    return env


def _cleanup_crashed(run_dir: Path) -> None:
    """Remove what a LinuxCNC run in ``run_dir`` left behind after being killed (linuxcnc.md §3.8 item 4).

    ``halrun -U`` through that run's rtapi socket stops its rtapi_app and frees
    the HAL shared memory; the run's other processes (``linuxcncsvr`` detaches
    and survives a killed process group) get SIGTERM (``linuxcncsvr`` then frees
    the NML shared memory), SIGKILL if they hang. The lock file is removed
    only when everything went away cleanly; otherwise the next launcher's own
    clean-up runs too.
    """
    env = _run_env(run_dir)
    if shutil.which("halrun") and run_dir.is_dir():
        with contextlib.suppress(OSError, subprocess.TimeoutExpired):
            subprocess.run(["halrun", "-U"], cwd=run_dir, env=env, stdin=subprocess.DEVNULL,
                           capture_output=True, timeout=30)
    pids = _pids_of_run(run_dir)
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGTERM)
    end = time.monotonic() + 5.0
    while pids and time.monotonic() < end:
        pids = [p for p in pids if Path(f"/proc/{p}").exists() and _state_of(p) not in ("Z", "X", "")]
        time.sleep(0.05)
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)
    if not pids and not _launchers_alive():
        with contextlib.suppress(OSError):
            LINUXCNC_LOCKFILE.unlink()


def _state_of(pid: int) -> str:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return ""
    return stat.rsplit(")", 1)[-1].split()[0]


def _recover_previous() -> None:
    """Clean up after an earlier ilcnc run that did not finish (called with the run lock held)."""
    state: dict = {}
    if STATE_PATH.exists():
        with contextlib.suppress(OSError, ValueError):
            state = json.loads(STATE_PATH.read_text())
    old_dir = None
    with contextlib.suppress(KeyError, TypeError, ValueError):
        d = Path(state["run_dir"])
        if d.parent == Path(tempfile.gettempdir()) and d.name.startswith(_RUN_PREFIX):
            old_dir = d
    with contextlib.suppress(KeyError, TypeError, ValueError):
        pid, pgid = int(state["pid"]), int(state["pgid"])
        if _is_launcher(_proc_cmdline(pid)):
            _stop_group(pgid, pid)  # the launcher we started is still up: normal shutdown
    if old_dir is not None:
        if LINUXCNC_LOCKFILE.exists() and not _launchers_alive():
            _cleanup_crashed(old_dir)
        shutil.rmtree(old_dir, ignore_errors=True)
    with contextlib.suppress(OSError):
        STATE_PATH.unlink()
    # A LinuxCNC still running now is someone else's (_wait_other_linuxcnc). A stale /tmp/linuxcnc.lock with no
    # LinuxCNC process alive is left over from a crash ilcnc has no record of: the launcher cleans it up itself
    # when started without a tty ("trying to clean up other instance automatically", ~2 s).


class LinuxCNCBusyError(InputError):
    """Another LinuxCNC run holds the machine (ilcnc's run lock, or a LinuxCNC ilcnc did not start).

    ``holder`` is the :class:`LockHolder` named in the message.
    """

    def __init__(self, file: str | Path | None, problem: str, holder: LockHolder | None) -> None:
        super().__init__(file, None, problem)
        self.holder = holder


@dataclass(frozen=True, slots=True)
class LockHolder:
    """Who holds the machine: an ilcnc run (its lock record) or a LinuxCNC that ilcnc did not start.

    Attributes
    ----------
    pid : int or None
        Process id (None when it could not be found out).
    user : str or None
        Its user name (or uid).
    program : str or None
        The part program an ilcnc run is running.
    command : str or None
        Its command line (shortened).
    since : float or None
        When it took the lock (ilcnc) or started (another LinuxCNC), seconds since the epoch.
    kind : str
        ``"ilcnc"`` (holds :data:`LOCK_PATH`) or ``"linuxcnc"`` (a LinuxCNC not started by ilcnc).
    """

    pid: int | None
    user: str | None = None
    program: str | None = None
    command: str | None = None
    since: float | None = None
    kind: str = "ilcnc"

    def held_s(self, now: float | None = None) -> float | None:
        """How long it has held the lock (or run), s."""
        if self.since is None:
            return None
        return max(0.0, (time.time() if now is None else now) - self.since)

    def describe(self, now: float | None = None) -> str:
        """One line: ``pid N (user U, program P, command 'C', since HH:MM:SS, held for S s)``."""
        if self.pid is None:
            return "an unknown process"
        parts = [f"user {self.user or '?'}"]
        if self.program:
            parts.append(f"program {self.program}")
        if self.command:
            parts.append(f"command '{self.command}'")
        held = self.held_s(now)
        if held is not None and self.since is not None:
            since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.since))
            parts.append(f"since {since}, {'held' if self.kind == 'ilcnc' else 'running'} for {_fmt_duration(held)}")
        else:
            parts.append("since unknown")
        return f"pid {self.pid} ({', '.join(parts)})"


def _fmt_duration(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


def _user_of(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except (KeyError, OverflowError):
        return str(uid)


def _short(cmd: list[str] | None, n: int = 100) -> str | None:
    if not cmd:
        return None
    text = " ".join(" ".join(cmd).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _process_start(pid: int) -> float | None:
    """When process ``pid`` started, seconds since the epoch (from /proc)."""
    try:
        ticks = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[-1].split()[19])
        btime = next(int(r.split()[1]) for r in Path("/proc/stat").read_text().splitlines() if r.startswith("btime "))
    except (OSError, ValueError, IndexError, StopIteration):
        return None
    return btime + ticks / os.sysconf("SC_CLK_TCK")


def _process_holder(pid: int, kind: str, program: str | None = None, since: float | None = None) -> LockHolder | None:
    """A :class:`LockHolder` from what /proc says about ``pid`` (None when it is gone)."""
    try:
        uid = Path(f"/proc/{pid}").stat().st_uid
    except OSError:
        return None
    return LockHolder(pid=pid, user=_user_of(uid), program=program, command=_short(_proc_cmdline(pid)),
                      since=since if since is not None else (_process_start(pid) if kind != "ilcnc" else None),
                      kind=kind)


def _flock_pid(path: Path) -> int | None:
    """The pid that holds a flock on ``path``, from /proc/locks (None when unknown or not held)."""
    try:
        st = path.stat()
        rows = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    dev = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for row in rows:
        cells = row.split()
        if len(cells) >= 6 and cells[1] == "FLOCK" and cells[5] == dev and cells[4].isdigit():
            return int(cells[4])  # blocked waiters are listed as '-> FLOCK ...' and do not match
    return None


def _read_record(path: Path) -> dict | None:
    """The holder record in the lock file (its first line, JSON), or None. Retries a torn read."""
    for _ in range(5):
        try:
            first = path.read_bytes()[:4096].split(b"\n", 1)[0]
        except OSError:
            return None
        if not first.strip():
            return None
        try:
            rec = json.loads(first)
            return rec if isinstance(rec, dict) else None
        except ValueError:
            time.sleep(0.01)  # written while we read: read again
    return None


def _holder_of_lock() -> LockHolder:
    """Who holds :data:`LOCK_PATH` (called when it is held): its record, else what /proc/locks and /proc say."""
    rec = _read_record(LOCK_PATH)
    locker = _flock_pid(LOCK_PATH)
    if rec is not None:
        with contextlib.suppress(KeyError, TypeError, ValueError):
            pid = int(rec["pid"])
            if (locker is None or locker == pid) and Path(f"/proc/{pid}").exists():
                return LockHolder(pid=pid, user=rec.get("user"), program=rec.get("program"),
                                  command=rec.get("command"), since=float(rec["since"]), kind="ilcnc")
    if locker is not None:  # no record (an older ilcnc, or not written yet): what /proc says
        h = _process_holder(locker, "ilcnc")
        if h is not None:
            return h
    return LockHolder(pid=None)


def _open_lock() -> int:
    """Open :data:`LOCK_PATH` for the lock and its record (read-only if it is another user's and not writable)."""
    try:
        try:
            return os.open(LOCK_PATH, os.O_RDWR)
        except FileNotFoundError:
            fd = os.open(LOCK_PATH, os.O_RDWR | os.O_CREAT, 0o666)
            with contextlib.suppress(OSError):
                os.fchmod(fd, 0o666)  # other users' runs must be able to take the lock and write their record
            return fd
        except PermissionError:
            return os.open(LOCK_PATH, os.O_RDONLY)  # flock needs no write access; no record then
    except OSError as exc:
        raise InputError(LOCK_PATH, None, f"cannot open the LinuxCNC run lock: {exc.strerror}") from None


def lock_holder() -> LockHolder | None:
    """Who holds ilcnc's run lock :data:`LOCK_PATH` now, or None when it is free.

    A lock this thread holds (:func:`run_lock`) is reported as held by this process.
    """
    own = _held.get(str(LOCK_PATH))
    if own is not None:
        return own[2]
    try:
        fd = os.open(LOCK_PATH, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _holder_of_lock()
        return None
    finally:
        os.close(fd)


#: Processes of a running LinuxCNC (``/proc/PID/comm``).
LINUXCNC_PROCESSES = ("linuxcncsvr", "milltask", "rtapi_app")


def _linuxcnc_pids() -> tuple[list[int], list[int]]:
    """(launcher pids, pids of the LinuxCNC processes) alive now, zombies left out."""
    launchers, procs = [], []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        pid = int(d.name)
        try:
            comm = (d / "comm").read_text().strip()
        except OSError:
            continue
        is_proc = comm in LINUXCNC_PROCESSES
        is_launcher = not is_proc and _is_launcher(_proc_cmdline(pid))
        if (is_proc or is_launcher) and _state_of(pid) not in ("Z", "X", ""):
            (procs if is_proc else launchers).append(pid)
    return sorted(launchers), sorted(procs)


def other_linuxcnc() -> LockHolder | None:
    """A LinuxCNC running now (its launcher, else a ``linuxcncsvr``/``milltask``/``rtapi_app``), or None.

    Called with ilcnc's run lock held this is a LinuxCNC that ilcnc did not
    start (or the leftovers of one that crashed); ilcnc never stops it.
    """
    launchers, procs = _linuxcnc_pids()
    for pid in launchers + procs:
        h = _process_holder(pid, "linuxcnc")
        if h is not None:
            return h
    return None


_held: dict[str, tuple[int, int, LockHolder]] = {}  # lock path -> (fd, depth, record) held by this process
_held_thread: dict[str, int] = {}


@contextlib.contextmanager
def run_lock(timeout_s: float = 0.0, program: str | Path | None = None,
             on_wait: Callable[[str], None] | None = None) -> Iterator[LockHolder]:
    """Hold ilcnc's machine-wide LinuxCNC run lock :data:`LOCK_PATH` (an ``flock``).

    The holder writes a record into the lock file (one JSON line: pid, user,
    program, command, since; readable by everyone) so that a waiting run can
    say who it waits for. When the lock is held by another process, ``on_wait``
    gets one line (who holds it, how long this call will wait) and the call
    waits up to ``timeout_s`` (0: not at all); then it raises
    :class:`LinuxCNCBusyError` naming the holder. Re-entrant within a thread:
    a nested call (e.g. :func:`run_program` inside a test session that holds
    the lock) only updates the record's program.
    """
    key = str(LOCK_PATH)
    prog = str(program) if program is not None else None
    if key in _held and _held_thread.get(key) == threading.get_ident():
        fd, depth, rec = _held[key]
        inner = LockHolder(pid=rec.pid, user=rec.user, program=prog or rec.program, command=rec.command,
                           since=rec.since)
        _held[key] = (fd, depth + 1, inner)
        _write_record(fd, inner)
        try:
            yield inner
        finally:
            _held[key] = (fd, depth, rec)
            _write_record(fd, rec)
        return
    fd = _open_lock()
    locked = False
    try:
        end = time.monotonic() + timeout_s
        told = False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                locked = True
                break
            except BlockingIOError:
                if time.monotonic() >= end:
                    h = _holder_of_lock()
                    how = (f"gave up after the lock timeout of {timeout_s:g} s" if timeout_s > 0
                           else "not waiting (lock timeout 0)")
                    raise LinuxCNCBusyError(program or LOCK_PATH,
                                            f"another ilcnc LinuxCNC run holds {LOCK_PATH}: {h.describe()}; {how}",
                                            h) from None
                if not told and on_wait is not None:
                    on_wait(f"waiting up to {_fmt_wait(timeout_s)} for the LinuxCNC run lock {LOCK_PATH}, "
                            f"held by another ilcnc run: {_holder_of_lock().describe()}")
                told = True
                time.sleep(0.1)
        rec = LockHolder(pid=os.getpid(), user=_user_of(os.geteuid()), program=prog,
                         command=_short(_proc_cmdline(os.getpid())), since=time.time())
        _write_record(fd, rec)
        _held[key] = (fd, 1, rec)
        _held_thread[key] = threading.get_ident()
        yield rec
    finally:
        if locked:
            _held.pop(key, None)
            _held_thread.pop(key, None)
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)  # no stale record once released
        os.close(fd)  # releases the lock


def _fmt_wait(timeout_s: float) -> str:
    return "forever" if math.isinf(timeout_s) else f"{timeout_s:g} s"


def _write_record(fd: int, rec: LockHolder) -> None:
    """Write the holder record into the lock file: one JSON line, one write (readers retry a torn read)."""
    data = json.dumps({"pid": rec.pid, "user": rec.user, "program": rec.program, "command": rec.command,
                       "since": rec.since}).encode() + b"\n"
    with contextlib.suppress(OSError):  # a read-only lock fd (another user's file): no record
        os.pwrite(fd, data, 0)
        os.ftruncate(fd, len(data))


def _wait_other_linuxcnc(program: Path, timeout_s: float, on_wait: Callable[[str], None] | None,
                         end: float) -> None:
    """Wait (until ``end``, monotonic) for a LinuxCNC that ilcnc did not start to go away; raise naming it."""
    told: int | None = None
    while True:
        h = other_linuxcnc()
        if h is None:
            return
        if time.monotonic() >= end:
            how = (f"gave up after the lock timeout of {timeout_s:g} s" if timeout_s > 0
                   else "not waiting (lock timeout 0)")
            raise LinuxCNCBusyError(
                program, f"another LinuxCNC is running, not started by ilcnc: {h.describe()}; "
                f"ilcnc runs one instance at a time and does not stop someone else's; {how}", h)
        if on_wait is not None and told != h.pid:
            on_wait(f"waiting up to {_fmt_wait(max(0.0, end - time.monotonic()))} for another LinuxCNC "
                    f"(not started by ilcnc) to end: {h.describe()}")
        told = h.pid
        time.sleep(0.5)


def _tail(text: str, n: int = 6) -> str:
    noise = ("Running with fallback_uid", "Note: Using POSIX", "latency excursion")
    rows = [r.strip() for r in text.splitlines() if r.strip() and not any(x in r for x in noise)]
    return " | ".join(rows[-n:])


_LINE_IN_MESSAGE = re.compile(r"\bline\s+(\d+)", re.IGNORECASE)
_N_WORD = re.compile(r"([ \t]*/?[ \t]*)(?:[Nn][ \t]*\d+(?:\.\d*)?)?")


def _n_prefixed(text: str) -> str:
    """Every line prefixed with ``N<line>`` (an existing N word replaced), '%' lines untouched."""
    out = []
    lines = text.split("\n")
    for i, raw in enumerate(lines, start=1):
        head = raw.lstrip(" \t")[:1]
        if head == "%" or (i == len(lines) and raw == ""):
            out.append(raw)
        elif head and head not in "/Nn":
            out.append(f"N{i} {raw}")
        else:
            m = _N_WORD.match(raw)
            rest = raw[m.end():] if m else raw
            out.append(f"{m.group(1) if m else ''}N{i} {rest}")
    return "\n".join(out)


def _refused_line(program_text: str, run_dir: Path, env: dict[str, str]) -> int | None:
    """The line LinuxCNC's standalone interpreter refuses (rs274 on an N-numbered copy), or None."""
    rs274 = shutil.which("rs274")
    if rs274 is None:
        return None
    copy = run_dir / "refusal-check.ngc"
    copy.write_bytes(_n_prefixed(program_text).encode("latin-1"))
    cmd = [rs274, "-g"]
    tbl = run_dir / "sim.tbl"
    if tbl.is_file():
        cmd += ["-t", str(tbl)]
    try:
        p = subprocess.run([*cmd, str(copy)], cwd=run_dir, env=env, capture_output=True, text=True, timeout=60,
                           stdin=subprocess.DEVNULL, errors="replace")
    except (OSError, subprocess.TimeoutExpired):
        return None
    if p.returncode == 0:
        return None
    rows = [r for r in p.stderr.splitlines() if r.strip() and r.strip() != "executing"]
    if rows:
        m = re.match(r"\s*/?\s*N(\d+)", rows[-1])
        if m:
            return int(m.group(1))
    return None


def _program_span(raw_log: Path) -> int:
    """Samples from the first to the last non-zero program line in a raw halsampler log."""
    first = last = None
    with raw_log.open("r", errors="replace") as fh:
        for i, row in enumerate(r for r in fh if r.strip() and r.strip() != "overrun"):
            cells = row.split()
            if len(cells) > 1 and cells[1] != "0":
                if first is None:
                    first = i
                last = i
    return 0 if first is None or last is None else last - first


def _last_program_line(raw_log: Path) -> int | None:
    """The last non-zero ``motion.program-line`` in a raw halsampler log (column 1 after the sample number)."""
    last = None
    try:
        with raw_log.open("r", errors="replace") as fh:
            for row in fh:
                cells = row.split()
                if len(cells) > 1 and cells[1].lstrip("-").isdigit() and cells[1] != "0":
                    last = int(cells[1])
    except OSError:
        return None
    return last


def stray_percent_line(text: str) -> int | None:
    """The line of a ``%`` LinuxCNC refuses: any line that is only ``%`` when the program's first non-blank line is
    not ``%`` (rs274ngc reads ``%`` as a delimiter only in pairs from the first line). None when there is none."""
    lines = text.splitlines()
    first = next((ln.strip() for ln in lines if ln.strip()), "")
    if first == "%":
        return None
    return next((i for i, ln in enumerate(lines, start=1) if ln.strip() == "%"), None)


def run_program(
    program_path: str | Path,
    config_dir: str | Path | None = None,
    log_path: str | Path = "linuxcnc-run.log",
    *,
    time_scale: int = 1,
    settle_s: float = 0.2,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    ini_overrides: Mapping[str, Mapping[str, object]] | None = None,
    keep_run_dir: bool = False,
    retry_low_queue: bool = True,
    lock_timeout_s: float = DEFAULT_LOCK_TIMEOUT_S,
    on_wait: Callable[[str], None] | None = None,
) -> RunResult:
    """Run a G-code program on the headless LinuxCNC simulation and return its log.

    Parameters
    ----------
    program_path : str or Path
        The LinuxCNC (RS-274NGC) program.
    config_dir : str or Path, optional
        The configuration folder (default :data:`DEFAULT_CONFIG_DIR`,
        ``configs/linuxcnc-sim``), or its INI file. Not modified.
    log_path : str or Path
        Where the raw halsampler output goes (written atomically; the program
        is never overwritten).
    time_scale : int
        k in 1..:data:`MAX_TIME_SCALE`, dividing ``SERVO_PERIOD``: run k times
        faster than real time with an identical log (see the module
        docstring); repeated at a smaller k if the motion queue ran low.
    settle_s : float
        Time logged after the commanded motion ends (the axes still lag), s.
    timeout_s : float
        Limit of the program's run in machine time, s: at ``time_scale`` k it may take ``timeout_s / k`` of
        wall-clock time (launch and shutdown get another minute).
    ini_overrides : mapping, optional
        INI values to change for this run, in real-time units, e.g.
        ``{"JOINT_0": {"FERROR": 1, "MIN_FERROR": 1}}`` or ``{"ILCNC": {"KV": 50}}``.
    keep_run_dir : bool
        Keep the temporary run directory (INI, copies, LinuxCNC output) for debugging.
    retry_low_queue : bool
        Repeat a time-scaled run whose motion queue ran low at a smaller k
        (default); when False, keep it and say so in ``messages``.
    lock_timeout_s : float
        How long to wait for the machine, s (>= 0; 0: do not wait; ``inf``: no limit): for another ilcnc run
        holding :data:`LOCK_PATH`, then for a LinuxCNC that ilcnc did not start. Separate from ``timeout_s``.
    on_wait : callable, optional
        Gets one line when the run has to wait: who holds the machine (pid, user, program, since when) and
        how long it will wait. ilcnc's library prints nothing; the command line prints it on stderr.

    Returns
    -------
    RunResult

    Raises
    ------
    InputError
        LinuxCNC is not installed; the program or configuration is missing;
        LinuxCNC refused the program (its message, and the line); the run
        stopped on a following error (the message and the block that was
        running); the run timed out or LinuxCNC failed to start.
    LinuxCNCBusyError
        (an InputError) the machine was still busy after ``lock_timeout_s``: another ilcnc run held the lock,
        or a LinuxCNC not started by ilcnc was running; the message names it.
    """
    program = Path(program_path)
    if not isinstance(time_scale, int) or isinstance(time_scale, bool) or not 1 <= time_scale <= MAX_TIME_SCALE:
        msg = f"time scale must be an integer 1..{MAX_TIME_SCALE} (the range verified exact), got {time_scale!r}"
        raise InputError(program, None, msg)
    if not (settle_s >= 0 and math.isfinite(settle_s)):
        raise InputError(program, None, f"settle time must be >= 0 s, got {settle_s!r}")
    if not (isinstance(lock_timeout_s, int | float) and lock_timeout_s >= 0):
        raise InputError(program, None, f"lock timeout must be >= 0 s, got {lock_timeout_s!r}")
    data = read_bytes(program)
    text = data.decode("latin-1")
    line = stray_percent_line(text)
    if line is not None:  # LinuxCNC says so only when the run reaches the line: minutes for a long program
        raise InputError(program, line, "LinuxCNC refuses a '%' line unless the program's first line is '%' as well"
                         " (\"Bad character '%' used\", reported only when the run gets there): add '%' as the first"
                         " line, or remove this one")
    why = linuxcnc_available()
    if why is not None:
        raise InputError(program, None, why)
    config = Path(config_dir) if config_dir is not None else DEFAULT_CONFIG_DIR
    ini_src = ini_in(config)
    cfg_dir = ini_src.parent
    log_dest = Path(log_path)
    if not (log_dest.parent if str(log_dest.parent) else Path(".")).is_dir():
        raise InputError(log_dest, None, f"output directory {log_dest.parent} does not exist")

    ini_text = scaled_ini_text(read_bytes(ini_src).decode("utf-8", errors="replace"), time_scale, ini_overrides, ini_path=ini_src)
    unscaled = read_ini_text(scaled_ini_text(read_bytes(ini_src).decode("utf-8", errors="replace"), 1, ini_overrides))
    try:
        period_s = int(float(unscaled.get("EMCMOT", {}).get("SERVO_PERIOD", "1000000"))) * 1e-9
    except ValueError:
        raise InputError(ini_src, None, "[EMCMOT] SERVO_PERIOD is not a number") from None
    display = unscaled.get("DISPLAY", {}).get("DISPLAY", "").split()

    run_dir = Path(tempfile.mkdtemp(prefix=_RUN_PREFIX))
    try:
        os.chmod(run_dir, 0o755)  # rtapi_app's fallback uid must reach the socket directory
        for f in cfg_dir.iterdir():
            if f.is_file() and not f.name.startswith("."):
                shutil.copy2(f, run_dir / f.name)
        ini = run_dir / ini_src.name
        ini.write_text(ini_text)
        if display and display[0].startswith("./"):
            drv = run_dir / display[0][2:]
            if drv.is_file():
                drv.chmod(0o755)
        if time_scale == 1:
            run_prog = program.resolve()
        else:
            run_prog = run_dir / f"scaled-{program.name}"
            run_prog.write_bytes(scale_program_time(text, time_scale).encode("latin-1"))
        raw_log = run_dir / "run.log"
        result_path = run_dir / "result.json"
        out_path = run_dir / "linuxcnc.out"

        env = _run_env(run_dir)
        if "RTAPI_FIFO_PATH" in env:
            fifo_dir = run_dir / "fifo"
            fifo_dir.mkdir(exist_ok=True)
            os.chown(fifo_dir, int(env["RTAPI_UID"]), -1)  # the socket dir must be writable by that uid
        env.update(
            ILCNC_PROGRAM=str(run_prog),
            ILCNC_LOG=str(raw_log),
            ILCNC_RESULT=str(result_path),
            ILCNC_SETTLE=f"{settle_s / time_scale + 0.1:.4f}",
            ILCNC_TIMEOUT=f"{timeout_s / time_scale if time_scale > 1 else timeout_s:.3f}",
            ILCNC_TIMEOUT_LABEL=f"{timeout_s:g} s of machine time (--timeout; give a longer one for this program)",
        )

        busy_until = time.monotonic() + lock_timeout_s
        with run_lock(lock_timeout_s, program, on_wait):
            _recover_previous()
            _wait_other_linuxcnc(program, lock_timeout_s, on_wait, busy_until)
            t0 = time.monotonic()
            with out_path.open("wb") as out:
                proc = _launch(ini, run_dir, env, out)
            try:
                with contextlib.suppress(OSError):  # best effort: lets the next run clean up if we die
                    STATE_PATH.write_text(json.dumps({"pid": proc.pid, "pgid": proc.pid, "run_dir": str(run_dir)}))
                try:
                    rc = proc.wait(timeout=timeout_s + _STARTUP_MARGIN_S)
                except subprocess.TimeoutExpired:
                    _stop_group(proc.pid, proc.pid)
                    proc.wait()
                    if LINUXCNC_LOCKFILE.exists():
                        _cleanup_crashed(run_dir)
                    msg = f"LinuxCNC run did not finish within {timeout_s + _STARTUP_MARGIN_S:.0f} s; stopped it"
                    raise InputError(program, None, msg) from None
            except BaseException:
                if proc.poll() is None:  # interrupted (Ctrl-C): do not leave LinuxCNC running
                    _stop_group(proc.pid, proc.pid)
                    proc.wait()
                    if LINUXCNC_LOCKFILE.exists():
                        _cleanup_crashed(run_dir)
                raise
            finally:
                if proc.poll() is not None:
                    with contextlib.suppress(OSError):
                        STATE_PATH.unlink()
            wall = time.monotonic() - t0

        output = out_path.read_text(errors="replace")
        try:
            res = json.loads(result_path.read_text())
        except (OSError, ValueError):
            raise InputError(program, None, f"LinuxCNC did not run the program (exit {rc}): {_tail(output)}") from None
        errors = [e["text"] for e in res.get("errors", [])]
        if res.get("status") != "ok" or errors:
            _raise_run_error(program, text, res, errors, raw_log, run_dir, env, output)
        if not raw_log.is_file():
            raise InputError(program, None, f"LinuxCNC ran but halsampler wrote no log: {_tail(output)}")
        low = res.get("queue_low")
        if low and time_scale > 1 and retry_low_queue:
            k2 = _lower_scale(time_scale, round(period_s * 1e9))
            note = (f"time scale {time_scale}: the motion queue ran low ({low.get('queue')} blocks at line "
                    f"{low.get('motion_line')}) while blocks were still to come; repeated at time scale {k2}")
            again = run_program(program, config, log_dest, time_scale=k2, settle_s=settle_s, timeout_s=timeout_s,
                                ini_overrides=ini_overrides, keep_run_dir=keep_run_dir, retry_low_queue=True,
                                lock_timeout_s=lock_timeout_s, on_wait=on_wait)
            again.messages.insert(0, note)
            again.wall_s += wall
            return again
        write_atomic(log_dest, raw_log.read_bytes(), protect=(program,))
        if _last_program_line(raw_log) is None:
            raise InputError(program, None, "LinuxCNC ran the program but no block moved (no program line in the log)")
        log = read_halsampler(raw_log, columns=HALSAMPLER_COLUMNS, period_s=period_s, tail_s=settle_s)
        span = _program_span(raw_log)
        result = RunResult(
            program=program, log_path=log_dest, log=log, time_scale=time_scale, period_s=period_s, wall_s=wall,
            program_wall_s=res.get("program_wall_s"), program_s=span * period_s,
            messages=list(res.get("messages", [])),
        )
        want = span + 1 + round(settle_s / period_s)
        if log.n_samples < want:
            result.messages.append(f"settle tail shorter than asked: {log.n_samples} of {want} samples logged")
        dwells = res.get("dwells") or {}
        result.dwells_held = int(dwells.get("held", 0))
        result.dwells_missed = missed = int(dwells.get("missed", 0))
        if missed:
            result.messages.append(f"{missed} dwell(s) ended before the driver could hold the restart after them: "
                                   "motion started while task was still queueing the next blocks")
        if low:
            result.messages.append(f"the motion queue ran low ({low.get('queue')} blocks at line {low.get('motion_line')}) "
                                   "while blocks were still to come (task could not keep ahead, or a queue-busting block)")
        return result
    finally:
        if not keep_run_dir:
            shutil.rmtree(run_dir, ignore_errors=True)


def _launch(ini: Path, run_dir: Path, env: dict[str, str], out) -> subprocess.Popen:  # type: ignore[no-untyped-def]
    """Start ``linuxcnc -r INI`` in its own process group (called with the run lock held)."""
    return subprocess.Popen(["linuxcnc", "-r", str(ini)], cwd=run_dir, env=env, stdin=subprocess.DEVNULL,
                            stdout=out, stderr=subprocess.STDOUT, start_new_session=True)


def _lower_scale(k: int, period_ns: int) -> int:
    """The next time scale to try after k: about half, dividing the servo period."""
    k2 = max(1, k // 2)
    while k2 > 1 and period_ns % k2:
        k2 -= 1
    return k2





def _raise_run_error(program: Path, text: str, res: dict, errors: list[str], raw_log: Path, run_dir: Path,
                     env: dict[str, str], output: str) -> None:
    """Turn the driver's result into one InputError naming the program line."""
    kinds = [e.get("kind") for e in res.get("errors", [])]
    first = errors[0] if errors else f"driver stopped in phase {res.get('phase')!r}: {_tail(output)}"
    ferr = next((e for e in errors if "following error" in e.lower()), None)
    if ferr is not None:
        line = _last_program_line(raw_log) or res.get("motion_line") or None
        raise InputError(program, line, f"LinuxCNC stopped on a following error: {ferr} (the axis lagged more than its "
                                        "[JOINT_n] FERROR/MIN_FERROR allow)")
    if kinds and all(k is not None and k < 0 for k in kinds):
        raise InputError(program, None, f"LinuxCNC run failed: {first}")
    line = None
    for e in errors:
        m = _LINE_IN_MESSAGE.search(e)
        if m:
            line = int(m.group(1))
            break
    if line is None:
        line = _refused_line(text, run_dir, env)
    if line is None and res.get("line"):
        line = int(res["line"]) + 1  # stat.read_line was one before the refused line in every probe
    raise InputError(program, line, f"LinuxCNC refused the program: {first}")


def record_run(program_path: Path, config_dir: Path | None, log_out: Path, raw_path: Path | None = None,
               **run_kw: object) -> RunResult:
    """``ilcnc linuxcnc run``: run the program (:func:`run_program`, keyword arguments passed on) and write its
    axis log to ``log_out`` as an ilcnc CSV with each sample's command index (the program is never written
    over); the raw halsampler output goes to ``raw_path``, or a temporary file that is removed."""
    from ilcnc.axislog.halsampler import commands_from_lines
    from ilcnc.axislog.log import write_axis_log
    from ilcnc.program import read_program

    prog = read_program(program_path)
    with tempfile.TemporaryDirectory(prefix="ilcnc-lcnc-") as tmp:
        res = run_program(program_path, config_dir, raw_path if raw_path is not None else Path(tmp) / "run.hal.log",
                          **run_kw)
        res.log.k = commands_from_lines(res.log.line, prog)
        write_axis_log(log_out, res.log, protect=(program_path,))
    return res
