"""File I/O at the edges: atomic writes and safe reads."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ilcnc.errors import InputError


def read_bytes(path: str | Path) -> bytes:
    """Read a whole input file, turning OS errors into one-line input errors."""
    p = Path(path)
    try:
        return p.read_bytes()
    except FileNotFoundError:
        raise InputError(p, None, "file not found") from None
    except IsADirectoryError:
        raise InputError(p, None, "is a directory, expected a file") from None
    except OSError as exc:
        raise InputError(p, None, f"cannot read: {exc.strerror}") from None


def same_file(a: str | Path, b: str | Path) -> bool:
    """True when both paths name the same existing file (or the same path)."""
    pa, pb = Path(a), Path(b)
    try:
        return pa.exists() and pb.exists() and os.path.samefile(pa, pb)
    except OSError:
        return pa.resolve() == pb.resolve()


def write_atomic(path: str | Path, data: bytes | str, *, protect: tuple[str | Path, ...] = ()) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file + rename).

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
        if same_file(dest, src) or Path(src).resolve() == dest.resolve():
            raise InputError(dest, None, "refusing to write over an input file; choose another output path")
    if isinstance(data, str):
        data = data.encode("utf-8")
    parent = dest.parent if str(dest.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(dest, None, f"output directory {parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, dest)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return dest
