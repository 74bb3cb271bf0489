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
   launch kills the first).
3. Leftovers of a crashed earlier run are cleaned up: a launcher that an
   earlier ilcnc process started and did not see finish is stopped; a stale
   ``/tmp/linuxcnc.lock`` with no launcher alive is left to the launcher's
   own automatic clean-up (it runs without a tty). A LinuxCNC that someone
   else is running is never touched: that is an error.
4. ``linuxcnc -r sim.ini`` runs in its own process group with the driver
   (``driver.py``, run by Debian's ``/usr/bin/python3``, which has the
   ``linuxcnc`` module) as its display: home, run the program, settle, drain
   the sampler, exit. As root, ``RTAPI_UID``/``RTAPI_FIFO_PATH`` are set
   (rtapi_app refuses root otherwise). ``linuxcnc`` is never imported here.
5. The driver's JSON result tells how it ended; the raw halsampler output is
   copied to ``log_path`` and read with :func:`ilcnc.logs.read_halsampler`.

Time scaling (``time_scale = k``): the servo period is divided by k, velocity
limits multiplied by k, accelerations by k^2, jerks by k^3, the loop gain
``[ILCNC] KV`` by k, and the program's F words by k (dwell times divided by k)
in a temporary copy. Every servo cycle is then the same as in the unscaled
run, so the log is the same sample sequence, produced k times faster; it is
returned in real-time units. Two things could still make it differ, and both
are handled: (1) the planner's first segments depend on what task has queued
when motion starts -- the simulation holds motion (``motion.feed-inhibit``)
until the queue stops growing and starts sampling in the cycle it releases
it; (2) task feeds the queue in wall-clock time (a few blocks per ms), so a
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
import re
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes, write_atomic
from ilcnc.logs import HALSAMPLER_COLUMNS, AxisLog, read_halsampler

__all__ = [
    "DEFAULT_CONFIG_DIR",
    "MAX_TIME_SCALE",
    "RunResult",
    "linuxcnc_available",
    "read_ini",
    "run_program",
    "scale_program_time",
    "scaled_ini_text",
]

#: The simulation configuration shipped with ilcnc (source checkout).
DEFAULT_CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs" / "linuxcnc-sim"
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
        The raw halsampler output (columns :data:`ilcnc.logs.HALSAMPLER_COLUMNS`,
        one line per servo cycle of the scaled run).
    log : AxisLog
        The log aligned on the first non-zero program line (t_s = 0), in
        real-time units (t_s = sample x unscaled period), trimmed to
        ``settle_s`` after the last program line; ``k`` is -1 (see
        :func:`ilcnc.logs.commands_from_lines`).
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


# ---------------------------------------------------------------------------
# INI handling (line based: LinuxCNC INIs repeat keys and keep comments)
# ---------------------------------------------------------------------------

_SECTION = re.compile(r"^\s*\[([^\]]+)\]\s*$")
_KEYVAL = re.compile(r"^(\s*)([A-Za-z0-9_]+)(\s*=\s*)(.*?)(\s*)$")


def read_ini(path: str | Path) -> dict[str, dict[str, str]]:
    """The INI file as ``{SECTION: {KEY: value}}`` (first value of a repeated key; ``#``/``;`` comments skipped)."""
    p = Path(path)
    if p.is_dir():
        p = _ini_in(p)
    return read_ini_text(read_bytes(p).decode("utf-8", errors="replace"))


def _fmt(v: float) -> str:
    """A number for an INI or G-code word: integers without a dot, others with up to 12 significant digits."""
    if v == int(v) and abs(v) < 1e15:
        return str(int(v))
    s = f"{v:.12g}"
    if "e" in s or "E" in s:
        s = f"{v:.9f}".rstrip("0").rstrip(".")
    return s


def _scale_factor(section: str, key: str, k: int) -> float | None:
    """How an INI value scales with time scale k (None: unchanged). SERVO_PERIOD is handled apart."""
    key_u = key.upper()
    if section.upper() == "ILCNC" and key_u == "KV":
        return float(k)
    if "JERK" in key_u:
        return float(k) ** 3
    if "ACCEL" in key_u:
        return float(k) ** 2
    if "VEL" in key_u:
        return float(k)
    return None


def scaled_ini_text(
    text: str,
    time_scale: int = 1,
    overrides: Mapping[str, Mapping[str, object]] | None = None,
    *,
    ini_path: str | Path | None = None,
) -> str:
    """The INI text with ``overrides`` applied, then scaled for ``time_scale`` (see module docstring).

    Overrides are real-time values (``{"JOINT_0": {"FERROR": 1}}``); a key that
    is not in its section is appended to it, a missing section at the end.
    """
    k = int(time_scale)
    pending = {sec.upper(): {str(key).upper(): str(v) for key, v in vals.items()} for sec, vals in (overrides or {}).items()}
    seen: dict[str, set[str]] = {}
    out: list[str] = []
    section = ""

    def flush(sec: str) -> None:
        for key, v in pending.get(sec.upper(), {}).items():
            if key not in seen.get(sec.upper(), set()):
                out.append(f"{key} = {_scaled_value(sec, key, v, k, ini_path)}")
                seen.setdefault(sec.upper(), set()).add(key)

    for raw in text.splitlines():
        m = _SECTION.match(raw)
        if m:
            flush(section)
            section = m.group(1).strip()
            out.append(raw)
            continue
        s = raw.strip()
        m = _KEYVAL.match(raw)
        if not s or s[0] in "#;" or m is None:
            out.append(raw)
            continue
        key = m.group(2)
        value = m.group(4)
        ov = pending.get(section.upper(), {})
        if key.upper() in ov:
            value = ov[key.upper()]
            seen.setdefault(section.upper(), set()).add(key.upper())
        out.append(f"{m.group(1)}{key}{m.group(3)}{_scaled_value(section, key, value, k, ini_path)}")
    flush(section)
    for sec, vals in pending.items():
        if sec not in seen and not any(_SECTION.match(r) and _SECTION.match(r).group(1).strip().upper() == sec for r in out):  # type: ignore[union-attr]
            out.append(f"[{sec}]")
            for key, v in vals.items():
                out.append(f"{key} = {_scaled_value(sec, key, v, k, ini_path)}")
    return "\n".join(out) + "\n"


def _scaled_value(section: str, key: str, value: str, k: int, ini_path: str | Path | None) -> str:
    if k == 1:
        return value
    if section.upper() == "EMCMOT" and key.upper() == "SERVO_PERIOD":
        try:
            ns = int(float(value))
        except ValueError:
            raise InputError(ini_path, None, f"[EMCMOT] SERVO_PERIOD {value!r} is not a number of nanoseconds") from None
        if ns % k:
            raise InputError(ini_path, None, f"[EMCMOT] SERVO_PERIOD {ns} ns is not divisible by the time scale {k}")
        return str(ns // k)
    f = _scale_factor(section, key, k)
    if f is None:
        return value
    try:
        v = float(value)
    except ValueError:
        return value  # not a number (e.g. a comment-like value): leave it
    return _fmt(v * f)


# ---------------------------------------------------------------------------
# Time scaling of the program text
# ---------------------------------------------------------------------------

_NUMBER = re.compile(r"[+-]?[ \t]*(?:\d[\d \t]*(?:\.[\d \t]*)?|\.[ \t]*\d[\d \t]*)")
_FUNC = re.compile(r"(?i)(atan|abs|acos|asin|cos|exp|fix|fup|round|ln|sin|sqrt|tan|exists)[ \t]*(?=\[)")
_DWELL_G = (4.0, 82.0, 86.0, 88.0, 89.0)


class _Unscannable(Exception):
    pass


def _skip_bracket(s: str, i: int) -> int:
    """Index after the ``[...]`` expression starting at ``s[i] == '['`` (nested)."""
    depth = 0
    while i < len(s):
        c = s[i]
        if c == "[":
            depth += 1
        elif c == "]":
            depth -= 1
            if depth == 0:
                return i + 1
        elif c == "(":
            j = s.find(")", i)
            if j < 0:
                raise _Unscannable
            i = j
        i += 1
    raise _Unscannable


def _scan_value(s: str, i: int) -> int:
    """Index after the real value starting at ``i`` (number, #parameter, [expression], function)."""
    while i < len(s) and s[i] in " \t":
        i += 1
    if i >= len(s):
        raise _Unscannable
    c = s[i]
    if c == "[":
        return _skip_bracket(s, i)
    if c == "#":
        i += 1
        while i < len(s) and s[i] in " \t":
            i += 1
        if i < len(s) and s[i] == "<":
            j = s.find(">", i)
            if j < 0:
                raise _Unscannable
            return j + 1
        return _scan_value(s, i)
    m = _FUNC.match(s, i)
    if m:
        j = _skip_bracket(s, m.end())
        if m.group(1).lower() == "atan":  # ATAN[a]/[b]
            k = j
            while k < len(s) and s[k] in " \t":
                k += 1
            if k < len(s) and s[k] == "/":
                k += 1
                while k < len(s) and s[k] in " \t":
                    k += 1
                if k < len(s) and s[k] == "[":
                    return _skip_bracket(s, k)
        return j
    m = _NUMBER.match(s, i)
    if m:
        return m.end()
    raise _Unscannable


def _scale_line(line: str, k: int) -> str:
    """One block with its F words x k and its dwell P words / k (comments and O-word lines untouched)."""
    body = line
    lead = re.match(r"[ \t]*(?:/[ \t]*)?(?:[Nn][ \t]*\d+(?:\.\d*)?[ \t]*)?", body)
    i = lead.end() if lead else 0
    if i < len(body) and body[i] in "Oo%":
        return line
    words: list[tuple[str, int, int]] = []  # (letter, value start, value end)
    try:
        while i < len(body):
            c = body[i]
            if c in " \t\r":
                i += 1
            elif c == "(":
                j = body.find(")", i)
                if j < 0:
                    return line
                i = j + 1
            elif c == ";":
                break
            elif c == "#":  # parameter setting #n = value
                j = _scan_value(body, i)
                while j < len(body) and body[j] in " \t":
                    j += 1
                if j >= len(body) or body[j] != "=":
                    raise _Unscannable
                i = _scan_value(body, j + 1)
            elif c.isalpha():
                j = _scan_value(body, i + 1)
                words.append((c.upper(), i + 1, j))
                i = j
            else:
                raise _Unscannable
    except _Unscannable:
        pass  # leave the rest as it is: LinuxCNC will say what is wrong with it
    dwell = False
    for letter, a, b in words:
        if letter == "G":
            with contextlib.suppress(ValueError):
                dwell = dwell or float(body[a:b].replace(" ", "").replace("\t", "")) in _DWELL_G
    edits: list[tuple[int, int, str]] = []
    for letter, a, b in words:
        if letter == "F" or (letter == "P" and dwell):
            raw = body[a:b]
            trail = len(raw) - len(raw.rstrip(" \t"))
            b -= trail  # keep the spacing after the number
            raw = body[a:b]
            op = "*" if letter == "F" else "/"
            try:
                v = float(raw.replace(" ", "").replace("\t", ""))
            except ValueError:
                edits.append((a, b, f"[{raw.strip()}{op}{k}]"))
                continue
            edits.append((a, b, _fmt(v * k if letter == "F" else v / k)))
    for a, b, new in reversed(edits):
        body = body[:a] + new + body[b:]
    return body


def scale_program_time(text: str, time_scale: int) -> str:
    """The program with every F word multiplied by ``time_scale`` and dwell P words divided by it.

    Line structure (and so every source line number) is kept; comments, ``%``
    and O-word lines are untouched. F words given as parameters or
    expressions become ``[... * k]``. Feed-per-revolution (G95) and
    spindle-synchronised moves are not time-scaled (the simulation has no
    spindle); F words in external subroutine files are not scaled either.
    """
    k = int(time_scale)
    if k == 1:
        return text
    parts = text.split("\n")
    return "\n".join(_scale_line(p, k) for p in parts)


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


def _ini_in(config: Path) -> Path:
    if config.is_file():
        return config
    if not config.is_dir():
        raise InputError(config, None, "LinuxCNC configuration directory not found")
    inis = sorted(config.glob("*.ini"))
    if (config / "sim.ini").is_file():
        return config / "sim.ini"
    if len(inis) != 1:
        raise InputError(config, None, f"expected one .ini file in the configuration directory, found {len(inis)}")
    return inis[0]


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


def _recover_previous(program: Path) -> None:
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
    if LINUXCNC_LOCKFILE.exists():
        alive = _launchers_alive()
        if alive:
            raise InputError(
                program, None,
                f"another LinuxCNC is running (launcher pid {alive[0]}, {LINUXCNC_LOCKFILE} exists); "
                "ilcnc runs one instance at a time and does not stop someone else's",
            )
        # no launcher alive: leftovers of a crash that ilcnc has no record of. The launcher cleans them up
        # itself when started without a tty ("trying to clean up other instance automatically", ~2 s).


@contextlib.contextmanager
def _run_lock(timeout_s: float, program: Path) -> Iterator[None]:
    try:
        fd = os.open(LOCK_PATH, os.O_RDONLY | os.O_CREAT, 0o666)  # flock needs no write access
    except OSError as exc:
        raise InputError(LOCK_PATH, None, f"cannot open the LinuxCNC run lock: {exc.strerror}") from None
    with contextlib.suppress(OSError):
        os.fchmod(fd, 0o666)  # other users' runs must be able to take the lock too
    try:
        end = time.monotonic() + timeout_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > end:
                    msg = f"another ilcnc LinuxCNC run held {LOCK_PATH} for {timeout_s:.0f} s"
                    raise InputError(program, None, msg) from None
                time.sleep(0.1)
        yield
    finally:
        os.close(fd)  # releases the lock


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

    Returns
    -------
    RunResult

    Raises
    ------
    InputError
        LinuxCNC is not installed; the program or configuration is missing;
        LinuxCNC refused the program (its message, and the line); the run
        stopped on a following error (the message and the block that was
        running); another LinuxCNC is running; the run timed out or LinuxCNC
        failed to start.
    """
    program = Path(program_path)
    if not isinstance(time_scale, int) or isinstance(time_scale, bool) or not 1 <= time_scale <= MAX_TIME_SCALE:
        msg = f"time scale must be an integer 1..{MAX_TIME_SCALE} (the range verified exact), got {time_scale!r}"
        raise InputError(program, None, msg)
    if not (settle_s >= 0 and math.isfinite(settle_s)):
        raise InputError(program, None, f"settle time must be >= 0 s, got {settle_s!r}")
    why = linuxcnc_available()
    if why is not None:
        raise InputError(program, None, why)
    data = read_bytes(program)
    text = data.decode("latin-1")
    config = Path(config_dir) if config_dir is not None else DEFAULT_CONFIG_DIR
    ini_src = _ini_in(config)
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

        with _run_lock(timeout_s + _STARTUP_MARGIN_S, program):
            _recover_previous(program)
            t0 = time.monotonic()
            with out_path.open("wb") as out:
                proc = subprocess.Popen(
                    ["linuxcnc", "-r", str(ini)], cwd=run_dir, env=env, stdin=subprocess.DEVNULL,
                    stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                )
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
                                ini_overrides=ini_overrides, keep_run_dir=keep_run_dir, retry_low_queue=True)
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
        if low:
            result.messages.append(f"the motion queue ran low ({low.get('queue')} blocks at line {low.get('motion_line')}) "
                                   "while blocks were still to come (task could not keep ahead, or a queue-busting block)")
        return result
    finally:
        if not keep_run_dir:
            shutil.rmtree(run_dir, ignore_errors=True)


def _lower_scale(k: int, period_ns: int) -> int:
    """The next time scale to try after k: about half, dividing the servo period."""
    k2 = max(1, k // 2)
    while k2 > 1 and period_ns % k2:
        k2 -= 1
    return k2


def read_ini_text(text: str) -> dict[str, dict[str, str]]:
    """:func:`read_ini` on a string."""
    out: dict[str, dict[str, str]] = {}
    section = ""
    for raw in text.splitlines():
        s = raw.strip()
        if not s or s[0] in "#;":
            continue
        m = _SECTION.match(raw)
        if m:
            section = m.group(1).strip()
            out.setdefault(section, {})
            continue
        m = _KEYVAL.match(raw)
        if m:
            out.setdefault(section, {}).setdefault(m.group(2), m.group(4))
    return out


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
