"""How much memory this process may still take, to refuse a job that needs more before it starts.

Linux overcommits: an allocation beyond the machine's memory succeeds and the
kernel's out-of-memory killer ends the process later, with no message. A job
whose size is known up front (a log's sample count) is checked against
:func:`available_memory_bytes` instead, and refused with what it needs.
"""

from __future__ import annotations

import resource
from pathlib import Path

__all__ = ["available_memory_bytes"]


def _status_kib(path: str, key: str) -> int | None:
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def available_memory_bytes() -> int | None:
    """Bytes this process may still allocate: the least of the machine's available memory (``MemAvailable``)
    and what its address-space limit (``ulimit -v``) leaves; None where neither is known."""
    known = []
    avail = _status_kib("/proc/meminfo", "MemAvailable")
    if avail is not None:
        known.append(avail * 1024)
    soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        used = _status_kib("/proc/self/status", "VmSize")
        known.append(max(0, soft - (used or 0) * 1024))
    return min(known) if known else None
