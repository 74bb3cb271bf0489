"""The one place that decides how many threads ilcnc's own pools may use.

A part's drive stage (the axes side by side, :mod:`ilcnc.vcnc.drives`) and its
contour stage (chunks of samples, :func:`ilcnc.contour.search.contour_error`) run in
thread pools; :func:`thread_limit` is the size they take. By default it is the
number of cores this process may run on (``os.sched_getaffinity``): one part
alone uses the whole machine.

When several parts run side by side (:func:`ilcnc.shop.batch.run_batch` with
``workers`` processes, or a Dask worker with several threads), every part
running on every core only makes the processes fight over the cores (and
multi-threaded BLAS spin-waits on a loaded machine). The batch therefore gives
each part ``max(1, cores // workers)`` threads:

* :func:`set_thread_limit` -- process-wide (a worker process of the local pool);
* :func:`thread_limit_scope` -- for the calling thread only (a task of a Dask
  worker, whose other threads run other parts);
* :func:`limit_process` -- a worker process as a whole: ilcnc's pools, and the
  thread pools of BLAS/OpenMP (``threadpoolctl``; for libraries not loaded yet
  the ``OMP_NUM_THREADS``-style variables) and numba's parallel layer.

The thread count never changes a result: the drive threads simulate one axis
each into its own column, and the contour threads take fixed chunks of
samples, each sample computed alone, into disjoint slices of the output.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator

__all__ = ["available_cores", "limit_process", "one_blas_thread", "set_thread_limit", "thread_limit", "thread_limit_scope",
           "threads_per_part"]

#: Environment variables read by BLAS/OpenMP/numba when they are loaded.
THREAD_ENV_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
                   "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS", "NUMBA_NUM_THREADS")

_process_limit: int | None = None
_local = threading.local()
_blas_controller: object | None = None
_blas_lock = threading.RLock()  # one thread at a time changes and restores the BLAS limit


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity; ``os.cpu_count()`` where that is unknown)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def thread_limit() -> int:
    """Threads ilcnc's own pools may use now (>= 1).

    The calling thread's :func:`thread_limit_scope`, else the process-wide
    :func:`set_thread_limit`, else :func:`available_cores`.
    """
    n = getattr(_local, "limit", None)
    if n is None:
        n = _process_limit
    return n if n is not None else available_cores()


def _check(n: int | None) -> int | None:
    if n is None:
        return None
    n = int(n)
    if n < 1:
        raise ValueError(f"a thread limit must be >= 1, not {n}")
    return n


def set_thread_limit(n: int | None) -> int | None:
    """Set the process-wide limit (``None``: back to the default); returns the previous setting."""
    global _process_limit
    prev, _process_limit = _process_limit, _check(n)
    return prev


@contextlib.contextmanager
def thread_limit_scope(n: int | None) -> Iterator[int]:
    """Limit ilcnc's pools started from the calling thread to ``n`` threads inside the block."""
    prev = getattr(_local, "limit", None)
    _local.limit = _check(n)
    try:
        yield thread_limit()
    finally:
        _local.limit = prev


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block on one BLAS thread (the BLAS libraries loaded at the first call; a no-op without threadpoolctl).

    For tiny matrices (a drive model's 4x4 exponential): OpenBLAS computes them on one thread anyway, so the
    results are the same, but with its pool of threads it spent 9-16 ms per 4x4 ``scipy.linalg.expm`` on the
    shared 2-core machine against 0.04 ms on one thread (70 ms of a 1.3 s ``ilcnc simulate``, issue 24).
    The libraries are looked up once per process (12 ms; entering the block later costs 0.1 ms). The limit is
    the process's: threads take turns in the block (it is meant for microseconds of work), so each one
    restores what it found.
    """
    global _blas_controller
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        yield
        return
    with _blas_lock:
        if _blas_controller is None:
            _blas_controller = ThreadpoolController()
        with _blas_controller.limit(limits=1, user_api="blas"):  # type: ignore[attr-defined]
            yield


def threads_per_part(workers: int, cores: int | None = None) -> int:
    """``max(1, cores // workers)``: the threads of each of ``workers`` parts running side by side."""
    cores = available_cores() if cores is None else cores
    return max(1, cores // max(1, int(workers)))


def limit_process(n: int) -> dict[str, object]:
    """Limit this whole process to ``n`` threads per pool: ilcnc's, BLAS/OpenMP's and numba's.

    Meant for a worker process that runs one part at a time next to others.
    Libraries already loaded are limited through ``threadpoolctl`` (a
    dependency; skipped if missing) and ``numba.set_num_threads`` (only when
    numba's parallel layer is already running: ilcnc's kernels do not use it,
    and starting it would only add idle threads); libraries loaded later read
    the environment variables set here. Returns what was done (for tests and
    diagnostics).
    """
    n = _check(n)
    assert n is not None
    set_thread_limit(n)
    for var in THREAD_ENV_VARS:
        os.environ[var] = str(n)
    done: dict[str, object] = {"ilcnc": n, "env": n, "blas": None, "numba": None}
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        pass
    else:
        threadpool_limits(limits=n)  # kept for the life of the process (not used as a context)
        done["blas"] = n
    if "numba" in sys.modules:
        try:
            import numba
            from numba.np.ufunc import parallel

            if parallel._is_initialized:
                numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
                done["numba"] = numba.get_num_threads()
        except Exception:  # pragma: no cover - a numba without these internals: its default stays
            pass
    return done
