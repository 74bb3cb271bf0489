"""File I/O at the edges: atomic writes and safe reads."""

from __future__ import annotations

import contextlib
import contextvars
import os
import re
import stat
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from ilcnc.errors import InputError


def read_bytes(path: str | Path) -> bytes:
    """Read a whole input file, turning OS errors into one-line input errors (:func:`open_input`'s checks)."""
    p = Path(path)
    with open_input(p) as fh:
        try:
            return fh.read()
        except OSError as exc:
            raise InputError(p, None, f"cannot read: {exc.strerror}") from None


def open_input(path: str | Path) -> BinaryIO:
    """Open an input file for reading in binary, with :func:`read_bytes`'s checks and one-line errors (to read a
    large file line by line instead of whole)."""
    p = Path(path)
    try:
        if p.exists() and not p.is_dir() and not p.is_file():  # a FIFO or a device would block or never end
            raise InputError(p, None, "is not a regular file (a pipe or a device): give a file")
        return p.open("rb")
    except FileNotFoundError:
        raise InputError(p, None, "file not found") from None
    except IsADirectoryError:
        raise InputError(p, None, "is a directory, expected a file") from None
    except OSError as exc:
        raise InputError(p, None, f"cannot read: {exc.strerror}") from None


def inside(path: str | Path, folder: str | Path) -> bool:
    """``path`` is ``folder`` or lies under it, symbolic links followed."""
    p, f = Path(path).resolve(), Path(folder).resolve()
    return p == f or f in p.parents


def same_file(a: str | Path, b: str | Path) -> bool:
    """True when both paths name the same existing file, or the same path (resolved) when one does not exist."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.exists() and pb.exists():
            return os.path.samefile(pa, pb)
    except OSError:
        pass
    return pa.resolve() == pb.resolve()


_UMASK_LOCK = threading.Lock()


def current_umask() -> int:
    """The process's umask (read from ``/proc/self/status`` where it is, else set and restored at once)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def output_mode(dest: Path) -> int:
    """The permissions an output gets: those of the file it replaces, else ``0o666`` less the umask (what
    ``open()`` would give a new file; ``mkstemp`` alone gives ``0o600``)."""
    try:
        return stat.S_IMODE(os.stat(dest).st_mode)
    except OSError:
        return 0o666 & ~current_umask()


#: Whether :func:`write_atomic` syncs the file to disk before the rename (this thread; see :func:`unsynced_writes`).
_SYNC: contextvars.ContextVar[bool] = contextvars.ContextVar("ilcnc_fileio_sync", default=True)


@contextlib.contextmanager
def unsynced_writes() -> Iterator[None]:
    """Inside the block, :func:`write_atomic` in this thread (only) skips ``fsync``: for files in a private
    temporary folder that is thrown away (a batch part on a Dask worker, whose client writes the results
    again, synced). ``fsync`` is ~7 ms a file here, 60 ms of a small part's ~250 ms."""
    token = _SYNC.set(False)
    try:
        yield
    finally:
        _SYNC.reset(token)


def write_atomic(path: str | Path, data: bytes | str, *, protect: tuple[str | Path, ...] = ()) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file + rename), with the permissions of the file it
    replaces or, for a new file, those the user's umask gives (:func:`output_mode`).

    Parameters
    ----------
    path : str or Path
        Destination.
    data : bytes or str
        Content; ``str`` is encoded as UTF-8.
    protect : tuple of paths
        Input files that must never be overwritten; writing over one of them
        raises :class:`InputError`.
    """
    dest = Path(path)
    for src in protect:
        if same_file(dest, src):
            raise InputError(dest, None, "refusing to write over an input file; choose another output path")
    if isinstance(data, str):
        data = data.encode("utf-8")
    parent = dest.parent if str(dest.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(dest, None, f"output directory {parent} does not exist")
    mode = output_mode(dest)
    remove_stale_temporaries(parent, dest.name)
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.{os.getpid()}.", suffix=".tmp", dir=parent)
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            if _SYNC.get():
                os.fsync(fh.fileno())
        os.replace(tmp, dest)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return dest


#: A temporary file of :func:`write_atomic`: ``.NAME.PID.RANDOM.tmp`` (``mkstemp``'s random part has no dot).
_TEMP_RE = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.[A-Za-z0-9_]+\.tmp$")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's live process
    return True


def remove_stale_temporaries(directory: str | Path, name: str | None = None) -> list[Path]:
    """Remove what :func:`write_atomic` left behind when its process was killed: ``.NAME.PID.*.tmp`` files of
    ``directory`` (of the file ``name`` only, if given) whose process no longer runs. Returns the files removed.

    A live writer's temporary file (its process still runs) is left alone; files named otherwise are never
    touched.
    """
    d = Path(directory) if str(directory) else Path(".")
    removed: list[Path] = []
    try:
        entries = list(d.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = _TEMP_RE.match(p.name)
        if m is None or (name is not None and m["name"] != name) or _pid_alive(int(m["pid"])):
            continue
        try:
            p.unlink()
            removed.append(p)
        except OSError:
            pass
    return removed
