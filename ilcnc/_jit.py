"""The one place that imports numba, on first use.

A command that never runs a compiled kernel never imports numba (issue 24: ``import numba`` costs
~0.2-0.3 s and the first cached kernel another ~0.15-0.25 s of numba's own set-up). :func:`njit` and
:func:`intrinsic` give a stand-in (:class:`LazyKernel`) until then; the first call of any of them imports
numba, makes every stand-in made so far into the real dispatcher and puts the dispatcher where the stand-in
was in the namespace of every loaded ``ilcnc`` module (a kernel finds the kernels it calls in its module's
globals when it is compiled, so they must be numba's own objects by then). Kernels made after that are
numba's dispatchers straight away. The dispatchers are the ones ``numba.njit`` makes from the same Python
functions, so numba's cache (``__pycache__``, or ``NUMBA_CACHE_DIR``) holds the same entries as before.

numba is a runtime dependency; when it is missing (a stripped install) :func:`njit`
leaves a function as plain Python, sets ``py_func`` like numba does, and
:data:`HAVE_NUMBA` tells the callers to take their numpy paths instead.

The first run after an install compiles the kernels it uses (20-40 s; later runs load them from the cache
in milliseconds). When a kernel has to be compiled, a line on stderr says so, once per process, and on a
terminal a progress line names the kernel being compiled and the seconds so far (cleared when it is done;
under a command's own progress bar the bar shows it: :func:`compiling_now`).
``ilcnc selftest`` compiles the kernels of the usual commands ahead of time.

A small job does not import numba at all (issue 24: ``import numba`` and loading the cached kernels cost
~0.5 s, more than a small program's whole run as Python). A caller that knows how much work a kernel call
is wraps the call in :func:`kernels_for`: below :data:`SMALL_WORK` items, while numba is not imported yet,
every stand-in called in that block (the kernel and the kernels it calls) runs its ``py_func``, the same
Python code numba compiles; an intrinsic runs the Python twin it was made with. Once numba is imported
(a big job ran, or anything else imported it), kernels run compiled whatever the size. The two agree to
within a few ulps (numba may reorder a sum or take another libm path), which ``tests/test_startup.py``
checks on real programs.
"""

from __future__ import annotations

import functools
import importlib.util
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["HAVE_NUMBA", "PLAN_ONLY_WEIGHT", "SMALL_WORK", "LazyKernel", "compile_stats", "compiled_for",
           "compiling_now", "intrinsic", "kernels_for", "njit", "numba_loaded", "numba_types", "python_kernels",
           "python_when_small", "set_component"]

#: numba can be imported (found without importing it: importing it is what start-up saves).
HAVE_NUMBA = importlib.util.find_spec("numba") is not None

#: Said on stderr once per process when a kernel has to be compiled (no cache entry yet).
COMPILE_NOTICE = ("ilcnc: compiling the numba kernels, once after install (20-40 s; later runs load them from"
                  " the cache; `ilcnc selftest` compiles them all)")

_lock = threading.RLock()
_plock = threading.RLock()  # the progress line's
_pending: list[LazyKernel] = []
_numba: Any = None

#: Samples of Python work (:func:`kernels_for`) after which a process imports numba and runs compiled.
#: A linear-drive run costs ~8-25 us per sample as Python (star.ngc 23 us, spiral.ngc 12 us; the friction
#: loop ~65 us, counted 3 times); numba's import and set-up cost ~0.45 s: at 20,000 samples the Python run
#: costs about what loading numba would.
#: ``ILCNC_SMALL_WORK`` overrides it (0: always compile, as before issue 24).
SMALL_WORK = 20_000


def _small_work() -> int:
    import os

    raw = os.environ.get("ILCNC_SMALL_WORK", "")
    try:
        return max(0, int(raw)) if raw.strip() else SMALL_WORK
    except ValueError:
        return SMALL_WORK


#: What a sample of a plan alone (no drives, no contour search: the corner report's passes) costs as Python
#: against one of a whole run: star.ngc on the example mill, 10-12 ms against 76-81 ms (7,553 samples).
PLAN_ONLY_WEIGHT = 1.0 / 6.0

_local = threading.local()
_python_work = 0.0  # items run as Python in kernels_for blocks so far (compiled_for), weighted


def _python_mode() -> bool:
    return getattr(_local, "python", False)


def python_kernels() -> bool:
    """A kernel called now (by this thread) runs as Python: inside a :func:`kernels_for` block of a small job."""
    return _numba is None and _python_mode()


def compiled_for(work: int) -> bool:
    """A step that brings ``work`` new items (samples: the planner counts them, the stages after it, which take
    the same samples, pass 0) runs compiled; True means numba is imported now.

    Outside a Python block (:func:`kernels_for`) the answer is True wherever numba is installed (the step
    would import numba on its first kernel anyway). Inside one, the items are added to the process's count
    of work done as Python, and once that count reaches :data:`SMALL_WORK` numba is imported and every
    kernel from then on runs compiled (a run that turns out bigger than its estimate stops paying Python's
    price). False: take the step's Python or numpy path.
    """
    global _python_work
    if not HAVE_NUMBA:
        return False
    if _numba is not None:
        return True
    if _python_mode():
        with _lock:
            _python_work += max(int(work), 0) * getattr(_local, "weight", 1)
            if _python_work < _small_work():
                return False
    _load_numba()
    return True


class kernels_for:
    """Context: the kernels called inside run as Python (``py_func``) while numba is not imported and the work
    done as Python so far plus ``work`` (the block's estimated items) is below :data:`SMALL_WORK`.

    Steps inside that know their size ask :func:`compiled_for`, which may still import numba part way;
    from then on every kernel runs compiled. ``weight`` is what an item costs as Python against the
    cheapest kernels (a sample through the friction loop costs ~3 samples of a linear drive): items count
    ``weight`` times; a block that only plans (no drives, no contour search) counts :data:`PLAN_ONLY_WEIGHT`.
    ``python`` tells how the block started.
    """

    __slots__ = ("_prev", "python", "weight")

    def __init__(self, work: int, weight: float = 1) -> None:
        self.weight = max(float(weight), PLAN_ONLY_WEIGHT)
        self.python = HAVE_NUMBA and _numba is None and _python_work + max(int(work), 0) * self.weight < _small_work()
        self._prev: tuple[bool, float] = (False, 1)

    def __enter__(self) -> kernels_for:
        self._prev = (_python_mode(), getattr(_local, "weight", 1))
        if self.python:
            _local.python = True
            _local.weight = self.weight
        return self

    def __exit__(self, *exc: object) -> None:
        _local.python, _local.weight = self._prev


def python_when_small(estimate: Callable[..., tuple[int, int]]) -> Callable[[Callable[..., Any]], Any]:
    """Decorator: the function runs in a :func:`kernels_for` block of ``estimate(*args, **kwargs)`` =
    ``(work, weight)`` (a whole job, e.g. every run of a learning loop, decided once at its start)."""

    def wrap(f: Callable[..., Any]) -> Any:
        @functools.wraps(f)
        def run(*args: Any, **kwargs: Any) -> Any:
            work, weight = estimate(*args, **kwargs)
            with kernels_for(work, weight):
                return f(*args, **kwargs)

        return run

    return wrap


class LazyKernel:
    """Stands for a numba dispatcher until numba is imported (see the module docstring).

    Calling it, or asking it for any attribute but ``py_func``, imports numba and turns every stand-in into
    its dispatcher; the stand-in then forwards to that dispatcher.
    """

    __slots__ = ("__name__", "__qualname__", "__wrapped__", "_make", "_python", "_real", "py_func")

    def __init__(self, make: Callable[[Any], Any], py_func: Callable[..., Any],
                 python: Callable[..., Any] | None = None) -> None:
        self._make = make
        self._real: Any = None
        self.py_func = py_func
        self._python = py_func if python is None else python
        self.__wrapped__ = py_func
        self.__name__ = getattr(py_func, "__name__", "kernel")
        self.__qualname__ = getattr(py_func, "__qualname__", self.__name__)

    def real(self) -> Any:
        """numba's object (imports numba the first time; another thread waits until every module is done)."""
        if _numba is None:
            _load_numba()
        return self._real

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if _numba is None and _python_mode():
            return self._python(*args, **kwargs)
        return self.real()(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.real(), name)

    def __repr__(self) -> str:
        return f"<ilcnc lazy kernel {self.__qualname__}{' (loaded)' if self._real is not None else ''}>"


class _LazyTypes:
    """``numba.types`` for code that names numba types only when a kernel is compiled (an intrinsic's body)."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(_load_numba().types, name)


#: ``numba.types``, imported when first used (``from ilcnc._jit import numba_types as types``).
numba_types: Any = _LazyTypes()


def numba_loaded() -> bool:
    """numba has been imported by this process (a kernel ran, or someone imported it)."""
    return _numba is not None


def _lazy(make: Callable[[Any], Any], f: Callable[..., Any], python: Callable[..., Any] | None = None) -> Any:
    with _lock:
        if _numba is not None:
            return make(_numba)
        k = LazyKernel(make, f, python)
        _pending.append(k)
        return k


def njit(*args: Any, **kwargs: Any) -> Any:
    """:func:`numba.njit` without importing numba before the kernel first runs (also ``njit(f)``).

    Without numba the function stays plain Python (with ``py_func``, like numba's dispatchers).
    """
    if args and callable(args[0]) and not kwargs and len(args) == 1:
        return njit()(args[0])

    def wrap(f: Callable[..., Any]) -> Any:
        if not HAVE_NUMBA:
            f.py_func = f  # type: ignore[attr-defined]
            return f
        return _lazy(lambda nb: nb.njit(*args, **kwargs)(f), f)

    return wrap


def intrinsic(python: Callable[..., Any] | None = None) -> Callable[[Callable[..., Any]], Any]:
    """:func:`numba.extending.intrinsic`, made when numba is imported; ``python`` is what a call runs as Python
    (:func:`kernels_for`; an intrinsic's own function is its typing, not its code). Use as ``@intrinsic(twin)``."""

    def wrap(f: Callable[..., Any]) -> Any:
        return _lazy(lambda nb: _extending().intrinsic(f), f, python)

    return wrap


def _extending() -> Any:
    import numba.extending

    return numba.extending


def _load_numba() -> Any:
    """Import numba, make every stand-in into numba's object and put those where the stand-ins were."""
    global _numba
    with _lock:
        if _numba is not None:
            return _numba
        if not HAVE_NUMBA:  # pragma: no cover - a stand-in is only made when numba is there
            raise RuntimeError("numba is not installed")
        from ilcnc._lazy import defer_numpy_extras

        defer_numpy_extras()  # in case scipy.linalg is imported after all (issue 24: start-up)
        import numba

        _check_blas_without_scipy_linalg()

        _install_compile_listener(numba)
        _register_typeof(numba)
        swap = {id(k): k._make(numba) for k in _pending}
        for name, mod in list(sys.modules.items()):
            if mod is None or not (name == "ilcnc" or name.startswith("ilcnc.")):
                continue
            ns = getattr(mod, "__dict__", None)
            if not ns:
                continue
            for key, val in list(ns.items()):
                if type(val) is LazyKernel and id(val) in swap:
                    ns[key] = swap[id(val)]
                elif type(val) is _LazyTypes:
                    ns[key] = numba.types
        for k in _pending:
            k._real = swap[id(k)]
        _pending.clear()
        # last: a thread that sees numba loaded (without the lock) sees every module's namespace done
        _numba = numba
        return numba


def _check_blas_without_scipy_linalg() -> None:
    """numba's BLAS check without importing all of :mod:`scipy.linalg` (0.1-0.15 s; issue 24: start-up).

    numba checks at the import of ``numba.np.arraymath`` (on its first kernel) that
    ``scipy.linalg.cython_blas`` imports; ``import scipy.linalg.cython_blas`` runs ``scipy/linalg/__init__``
    first, which imports most of SciPy's linear algebra. The extension module alone loads in
    milliseconds: it is put in ``sys.modules`` for the check and taken out again, so a later
    ``import scipy.linalg.cython_blas`` (numba compiling a kernel that calls BLAS, or anyone) goes the normal
    way, under its package, and gets the same module (CPython keeps an extension module loaded once).
    Anything unexpected (no SciPy, another layout) leaves numba to do as it always does.
    """
    name = "scipy.linalg.cython_blas"
    if "scipy.linalg" in sys.modules or name in sys.modules or "numba.np.arraymath" in sys.modules:
        return
    try:
        scipy = importlib.util.find_spec("scipy")
        if scipy is None or scipy.origin is None:
            return
        import glob
        import os

        found = glob.glob(os.path.join(os.path.dirname(scipy.origin), "linalg", "cython_blas.*.so"))
        if len(found) != 1:
            return
        spec = importlib.util.spec_from_file_location(name, found[0])
        if spec is None or spec.loader is None:
            return
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
            import numba.np.arraymath  # noqa: F401 - its BLAS check runs now, against that module
        finally:
            if sys.modules.get(name) is module:
                del sys.modules[name]
    except Exception:  # pragma: no cover - numba does its own check later
        return


def _register_typeof(numba: Any) -> None:
    """A stand-in passed to a kernel as an argument (a kernel given another kernel) is typed as its dispatcher."""
    from numba.core.typing.typeof import typeof_impl

    @typeof_impl.register(LazyKernel)
    def _typeof_lazy(val: LazyKernel, c: Any) -> Any:
        return typeof_impl(val.real(), c)


# ---------------------------------------------------------------------------------------------
# What the first run says while it compiles
# ---------------------------------------------------------------------------------------------

_stats: dict[str, Any] = {"compiled": [], "seconds": 0.0}


def compile_stats() -> dict[str, Any]:
    """What this process compiled (no cache entry): ``compiled``, ``(kernel, seconds)`` of ilcnc's kernels in the
    order they were done (a kernel's seconds include what it called that had to be compiled first: other
    kernels, numba's own array and string functions), and ``seconds``, the wall time spent compiling."""
    return {"compiled": list(_stats["compiled"]), "seconds": float(_stats["seconds"])}


def compiling_now() -> str | None:
    """What is being compiled, short, for a progress bar ("compiling group_kernel, once"), or None."""
    with _plock:
        if _progress.depth == 0:
            return None
        return f"compiling {_progress.name.rsplit('.', 1)[-1]}, once"


class _Progress:
    """The notice line and, on a terminal, a progress line that is rewritten while kernels compile."""

    def __init__(self) -> None:
        self.depth = 0
        self.noticed = False
        self.t0 = 0.0
        self.name = ""
        self.shown = False
        self.ticker: threading.Thread | None = None
        self.started: list[float] = []

    def _tty(self) -> Any:
        # only when nothing redirects stderr (a rich live display prints its own elapsed time)
        err = sys.stderr
        if err is None or err is not sys.__stderr__:
            return None
        try:
            return err if err.isatty() else None
        except (AttributeError, ValueError):  # pragma: no cover - a closed or odd stream
            return None

    def start(self, name: str | None) -> None:
        with _plock:
            self.depth += 1
            self.started.append(time.perf_counter())
            if name is not None:
                self.name = name
            if self.depth > 1:
                return
            self.t0 = time.perf_counter()
            if name is None:
                self.name = "numba internals"
            if not self.noticed:
                self.noticed = True
                try:
                    sys.stderr.write(COMPILE_NOTICE + "\n")
                    sys.stderr.flush()
                except (AttributeError, ValueError, OSError):  # pragma: no cover - no usable stderr
                    return
            if self._tty() is not None and self.ticker is None:
                self.ticker = threading.Thread(target=self._tick, name="ilcnc-compile-progress", daemon=True)
                self.ticker.start()

    def end(self, name: str | None) -> None:
        with _plock:
            t0 = self.started.pop() if self.started else time.perf_counter()
            if name is not None:
                _stats["compiled"].append((name, time.perf_counter() - t0))
            self.depth = max(0, self.depth - 1)
            if self.depth == 0:
                _stats["seconds"] += time.perf_counter() - self.t0
                self._draw(clear=True)

    def status(self) -> str | None:
        with _plock:
            if self.depth == 0:
                return None
            return (f"compiling {self.name}, once: {len(_stats['compiled'])} kernels done,"
                    f" {_stats['seconds'] + time.perf_counter() - self.t0:.0f} s")

    def _draw(self, clear: bool = False) -> None:
        tty = self._tty()
        if tty is None:
            return
        try:
            if clear:
                if self.shown:
                    tty.write("\r\033[K")
                    self.shown = False
            else:
                tty.write(f"\r\033[Kilcnc: {self.status()}")
                self.shown = True
            tty.flush()
        except (ValueError, OSError):  # pragma: no cover - the terminal went away
            pass

    def _tick(self) -> None:
        while True:
            time.sleep(0.5)
            with _plock:
                if self.depth > 0:
                    self._draw()


_progress = _Progress()


def _install_compile_listener(numba: Any) -> None:
    """Follow numba's ``numba:compile`` events: numba raises them only when it compiles (a cache miss)."""
    try:
        from numba.core import event
    except ImportError:  # pragma: no cover - a numba without the event API: no notice
        return

    def name_of(ev: Any) -> str | None:
        """``module.function`` of an ilcnc kernel; None for numba's own (its array and string functions)."""
        disp = (ev.data or {}).get("dispatcher")
        f = getattr(disp, "py_func", None)
        mod = getattr(f, "__module__", "") or ""
        if not (mod == "ilcnc" or mod.startswith("ilcnc.")):
            return None
        return f"{mod.removeprefix('ilcnc.')}.{getattr(f, '__name__', '?')}"

    class _Listener(event.Listener):  # type: ignore[misc, name-defined]
        def on_start(self, ev: Any) -> None:
            _progress.start(name_of(ev))

        def on_end(self, ev: Any) -> None:
            _progress.end(name_of(ev))

    event.register("numba:compile", _Listener())


@njit(cache=True, nogil=True, inline="always")
def set_component(x0: float, x1: float, x2: float, axis: int, value: float) -> tuple[float, float, float]:  # pragma: no cover
    """``(x0, x1, x2)`` with component ``axis`` replaced: compiled loops keep a point in three scalars (registers);
    a small array would be a heap allocation per call."""
    if axis == 0:
        return value, x1, x2
    if axis == 1:
        return x0, value, x2
    return x0, x1, value
