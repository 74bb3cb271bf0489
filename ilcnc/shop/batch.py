"""Learning many parts: a folder or a manifest of programs × profiles, on local workers or a Dask cluster.

A job shop learns hundreds of part programs, each on the profile of the
machine it runs on. :func:`run_batch` learns every part on the virtual CNC
(:func:`ilcnc.shop.workflow.learn_part`), each in its own process, and returns one
:class:`PartResult` per part whatever happens to the others: a part whose
program cannot be read is reported with its one-line error and the rest go
on. The outputs depend only on the inputs, so the local pool and a Dask
cluster write byte-identical files.

Manifest (YAML)::

    profiles: [configs/example-mill.yaml]     # default profile(s) of every part
    iterations: 5                             # optional
    parts:
      - program: parts/bracket.nc
      - program: parts/cover.h
        profiles: [configs/mill-a.yaml, configs/mill-b.yaml]   # program × profile pairs

Paths are relative to the manifest's folder.
"""

from __future__ import annotations

import contextlib
import csv
import io
import reprlib
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ilcnc._threads import limit_process, thread_limit_scope, threads_per_part
from ilcnc.errors import IlcncError, InputError
from ilcnc.fileio import inside, read_bytes, write_atomic
from ilcnc.outcomes import PartStatus

__all__ = ["BatchJob", "PartResult", "folder_programs", "jobs_from_path", "run_batch", "summary_csv"]


@dataclass(frozen=True, slots=True)
class BatchJob:
    """One part to learn: a program on a profile, with where its output goes."""

    program: str
    profile: str
    out: str
    state: str
    iterations: int | None = None


@dataclass(slots=True, kw_only=True)
class PartResult:
    """What learning one part gave (DESIGN.md's ``batch`` object, one entry)."""

    program: str
    profile: str
    status: PartStatus
    g01_commands: int = 0
    iterations: int = 0
    contour_error_mm: dict[str, float | None] = field(default_factory=lambda: {"before": None, "after": None})
    clipped: int = 0
    error: str | None = None
    output: str | None = None
    #: the cutting moves' max before / after and the air moves' max after, mm; cycle time before / after, s
    max_error_mm: dict[str, float | None] = field(default_factory=lambda: {"before": None, "after": None, "air_after": None})
    cycle_time_s: dict[str, float | None] = field(default_factory=lambda: {"before": None, "after": None})

    @property
    def failed(self) -> bool:
        """The part could not be learned (bad input), or learning made it worse than the original."""
        return PartStatus(self.status).failed

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


_PROGRAM_SUFFIXES = (".nc", ".ngc", ".tap", ".gcode", ".gc", ".cnc", ".h")


def _job(program: Path, profile: Path, out_dir: Path, iterations: int | None, tag: bool) -> BatchJob:
    stem = program.stem + (f".{profile.stem}" if tag else "")
    out = out_dir / f"{stem}.ilc{program.suffix}"
    # the state is named after the output, as learn's default (OUT.state): part.h and part.nc in one folder
    # learn into part.ilc.h.state and part.ilc.nc.state (issue 25 item 16: they shared part.state)
    return BatchJob(str(program), str(profile), str(out), str(out.with_name(out.name + ".state")), iterations)


#: Most iterations a manifest may ask for (as ``--iterations``).
MAX_ITERATIONS = 1000


def _short(value: object, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters (a message names a value, it does not print a file). The repr
    itself is bounded (``reprlib``): a YAML alias bomb nests lists a billion elements deep in a few lines."""
    rp = reprlib.Repr()
    rp.maxlevel, rp.maxlist, rp.maxdict, rp.maxstring, rp.maxother = 3, 6, 6, limit, limit
    r = rp.repr(value)
    return r if len(r) <= limit else r[: limit - 5] + " ...)"


def _profile_list(src: Path, key: str, value: object) -> list[str]:
    """A manifest's profile entry as a list of file names: one name, or a list of names."""
    if value is None:
        return []
    if isinstance(value, (str, Path)):
        return [str(value)]
    if isinstance(value, list) and all(isinstance(v, (str, Path)) for v in value):
        return [str(v) for v in value]
    raise InputError(src, None, f"{key}: must be a profile file name or a list of them, got {_short(value)}")


def folder_programs(folder: str | Path) -> list[Path]:
    """The part programs of a folder: its files with a program suffix (``.nc .ngc .tap .gcode .gc .cnc .h``),
    sorted by name (``ilcnc batch`` and ``ilcnc check`` take a folder by this rule).

    Raises
    ------
    InputError
        The folder holds none.
    """
    src = Path(folder)
    progs = sorted(p for p in src.iterdir() if p.is_file() and p.suffix.lower() in _PROGRAM_SUFFIXES)
    if not progs:
        raise InputError(src, None, f"no part programs ({', '.join(_PROGRAM_SUFFIXES)}) in this folder")
    return progs


def jobs_from_path(source: str | Path, profile: str | Path | None, out_dir: str | Path, *,
                   iterations: int | None = None, allow_outside: bool = False) -> list[BatchJob]:
    """The jobs of a folder (every program file in it, sorted) or of a manifest.

    A manifest's program paths are relative to its folder and must stay inside it (a manifest mailed in
    from elsewhere names no file of this machine) unless ``allow_outside``.

    Raises
    ------
    InputError
        A manifest that cannot be read, a part without a program or profile, a program outside the
        manifest's folder, two parts writing the same output, or an empty folder.
    """
    import yaml

    src = Path(source)
    out = Path(out_dir)
    if src.is_dir():
        if profile is None:
            raise InputError(src, None, "a folder of programs needs --profile")
        progs = folder_programs(src)
        jobs = [_job(p, Path(profile), out, iterations, False) for p in progs]
    else:
        text = read_bytes(src).decode("utf-8", errors="replace")
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            raise InputError(src, mark.line + 1 if mark else None, f"not a YAML manifest: {exc}") from None
        if not isinstance(data, dict) or not isinstance(data.get("parts"), list) or not data["parts"]:
            raise InputError(src, None, "a manifest needs a 'parts' list of {program: ..., profiles: [...]}")
        base = src.parent
        default_profiles = _profile_list(src, "profiles", data.get("profiles", [profile] if profile is not None else []))
        its = data.get("iterations", iterations)
        if its is not None and (isinstance(its, bool) or not isinstance(its, int) or not 1 <= its <= MAX_ITERATIONS):
            raise InputError(src, None, f"iterations: must be a whole number from 1 to {MAX_ITERATIONS}, got {_short(its)}")
        pairs: list[tuple[Path, Path]] = []
        for i, part in enumerate(data["parts"], start=1):
            if not isinstance(part, dict) or "program" not in part:
                raise InputError(src, None, f"part {i} has no 'program'")
            if not isinstance(part["program"], str):
                raise InputError(src, None, f"part {i}: program must be a file name, got {_short(part['program'])}")
            key = "profiles" if "profiles" in part else "profile"
            profs = _profile_list(src, f"part {i}: {key}", part.get(key, default_profiles))
            if not profs:
                raise InputError(src, None, f"part {i} ({part['program']}) has no profile and no default profile")
            prog = base / str(part["program"])
            if not allow_outside and not inside(prog, base):
                raise InputError(src, None, f"part {i}: program {_short(part['program'])} is outside the manifest's"
                                 f" folder {base.resolve()}: move it there, or give --allow-outside")
            for pr in profs:
                pp = Path(pr) if Path(pr).is_absolute() or pr == profile else base / pr
                pairs.append((prog, pp))
        multi = len({p for _, p in pairs}) > 1
        jobs = [_job(p, pr, out, its, multi) for p, pr in pairs]
    seen: dict[str, str] = {}
    for j in jobs:
        if j.out in seen:
            raise InputError(src, None, f"{j.program} and {seen[j.out]} would both write {j.out}")
        seen[j.out] = j.program
    return jobs


def learn_one(job: BatchJob) -> PartResult:
    """Learn one part; every error becomes the part's status (never raised)."""
    from ilcnc.shop.workflow import LearnRequest, learn_part

    try:
        oc = learn_part(LearnRequest(Path(job.program), Path(job.profile), Path(job.out), iterations=job.iterations,
                                     state=Path(job.state)))
    except IlcncError as exc:
        msg = exc.format()
        return PartResult(program=job.program, profile=job.profile, status=PartStatus.ERROR, error=msg)
    except Exception as exc:
        return PartResult(program=job.program, profile=job.profile, status=PartStatus.ERROR,
                          error=f"{job.program}: internal error: {exc!r}")
    its = oc.iterations
    before = its[0]["contour_error_mm"]["rms"] if its and its[0]["contour_error_mm"] else None
    kept = [it for it in its if it.get("kept") and it["contour_error_mm"]]
    after = min(it["contour_error_mm"]["rms"] for it in kept) if kept else None
    best = min(kept, key=lambda it: it["contour_error_mm"]["rms"]) if kept else None
    maxes = {"before": its[0]["contour_error_mm"]["max"] if before is not None else None,
             "after": best["contour_error_mm"]["max"] if best else None,
             "air_after": (best.get("air_error_mm") or {}).get("max") if best else None}
    cycle = {"before": its[0].get("cycle_time_s") if its else None, "after": best.get("cycle_time_s") if best else None}
    status = PartStatus.of(oc.status)
    if status == PartStatus.DIVERGED and before is not None and after is not None and after >= before:
        status = PartStatus.REGRESSED
    from ilcnc.program import read_program

    n = read_program(job.program).n_commands
    return PartResult(program=job.program, profile=job.profile, status=status, g01_commands=n,
                      iterations=len(its) - 1, contour_error_mm={"before": before, "after": after},
                      clipped=len(oc.clips), error=None, output=str(oc.output) if oc.output else None,
                      max_error_mm=maxes, cycle_time_s=cycle)


def run_batch(
    jobs: list[BatchJob],
    *,
    workers: int = 1,
    scheduler: str | Any | None = None,
    on_result: Callable[[PartResult], None] | None = None,
    threads: int | None = None,
) -> list[PartResult]:
    """Learn every job; results in the order of ``jobs``.

    Parameters
    ----------
    jobs : list of BatchJob
    workers : int
        Local worker processes (1: in this process).
    scheduler : str or distributed.Client, optional
        Address of a Dask distributed scheduler (``tcp://host:8786``) or a
        client: the parts run on that cluster instead.
    on_result : callable, optional
        Called with each part's result as it finishes (progress output).
    threads : int, optional
        Threads of each part (its drive and contour stages, BLAS). Default:
        with ``workers=1`` every core (one part at a time, each as fast as
        it can be); with more workers ``max(1, cores // workers)`` in each
        worker process (:mod:`ilcnc._threads`), so that the processes do not
        fight over the cores; on Dask ``max(1, cores // threads of the
        worker)`` for ilcnc's own pools (Dask's workers run BLAS on one
        thread already). The thread count does not change any result.

    Notes
    -----
    ``workers=1`` runs in this process with all the threads: on a machine of
    ``c`` cores a part's threaded stages already use more than one core, so
    the throughput of ``workers=c`` is less than ``c`` times that of
    ``workers=1`` even when the pool itself costs nothing.
    """
    if not jobs:
        return []
    if Path(jobs[0].out).parent and not Path(jobs[0].out).parent.is_dir():
        Path(jobs[0].out).parent.mkdir(parents=True, exist_ok=True)
    results: list[PartResult | None] = [None] * len(jobs)
    if scheduler is not None:
        _run_dask(jobs, scheduler, results, on_result, threads)
    elif workers <= 1:
        with _limited_here(threads):
            for i, j in enumerate(jobs):
                results[i] = learn_one(j)
                if on_result:
                    on_result(results[i])  # type: ignore[arg-type]
    else:
        import concurrent.futures as cf

        with _process_pool(workers, threads) as pool:
            futs = {pool.submit(learn_one, j): i for i, j in enumerate(jobs)}
            for f in cf.as_completed(futs):
                i = futs[f]
                results[i] = f.result()
                if on_result:
                    on_result(results[i])  # type: ignore[arg-type]
    return [r for r in results if r is not None]


def _limited_here(threads: int | None) -> contextlib.AbstractContextManager[object]:
    """This process's parts on ``threads`` threads (ilcnc's pools and BLAS) inside the block; None: unchanged."""
    if threads is None:
        return contextlib.nullcontext()
    stack = contextlib.ExitStack()
    stack.enter_context(thread_limit_scope(threads))
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return stack
    stack.enter_context(threadpool_limits(limits=threads))
    return stack


def _init_worker(threads: int) -> None:
    """Initializer of a local worker process: every pool of the process on ``threads`` threads."""
    limit_process(threads)


def _process_pool(workers: int, threads: int | None = None) -> Any:
    """The local pool of ``workers`` processes (spawned), each limited to ``threads`` (default cores // workers)."""
    import concurrent.futures as cf
    import multiprocessing as mp

    n = threads if threads is not None else threads_per_part(workers)
    ctx = mp.get_context("spawn")  # numba and threads do not survive fork
    return cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker, initargs=(n,))


def _dask_task_threads(threads: int | None = None) -> int:
    """Threads of one part in a Dask task: ``threads``, else cores of the worker // its task threads."""
    if threads is not None:
        return threads
    try:
        from distributed import get_worker

        w = get_worker()
        slots = getattr(getattr(w, "state", None), "nthreads", None) or getattr(w, "nthreads", 1)
    except (ImportError, ValueError):  # not in a Dask worker
        slots = 1
    return threads_per_part(int(slots))


def _learn_one_dask(job: BatchJob, threads: int | None = None) -> PartResult:
    """:func:`learn_one` in a Dask task, its pools limited for the calling thread only (the worker's
    other threads run other parts; its BLAS is on one thread already: Dask's ``OMP_NUM_THREADS=1``)."""
    with thread_limit_scope(_dask_task_threads(threads)):
        return learn_one(job)


def _run_dask(jobs: list[BatchJob], scheduler: str | Any, results: list[PartResult | None],
              on_result: Callable[[PartResult], None] | None, threads: int | None = None) -> None:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise InputError(None, None, "--scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
    own = isinstance(scheduler, str)
    client = Client(scheduler) if own else scheduler
    try:
        futs = client.map(_learn_one_dask, jobs, threads=threads, pure=False)
        index = {f.key: i for i, f in enumerate(futs)}
        for f in as_completed(futs):
            i = index[f.key]
            results[i] = f.result()
            if on_result:
                on_result(results[i])  # type: ignore[arg-type]
    finally:
        if own:
            client.close()


def summary_csv(results: Iterable[PartResult]) -> str:
    """The summary table as CSV text."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    # the figures are the cutting moves' (ilcnc.contour.air); columns after "error" were added later (kept at the end
    # so that scripts reading the first ten keep working)
    w.writerow(["program", "profile", "status", "g01_commands", "iterations", "rms_before_mm", "rms_after_mm", "clipped",
                "output", "error", "max_before_mm", "max_after_mm", "air_max_after_mm", "cycle_before_s", "cycle_after_s"])

    def num(x: float | None, fmt: str = ".6f") -> str:
        return "" if x is None else format(x, fmt)

    for r in results:
        ce, mx, cy = r.contour_error_mm, r.max_error_mm, r.cycle_time_s
        w.writerow([r.program, r.profile, r.status, r.g01_commands, r.iterations, num(ce["before"]), num(ce["after"]),
                    r.clipped, r.output or "", r.error or "", num(mx["before"]), num(mx["after"]), num(mx["air_after"]),
                    num(cy["before"], ".3f"), num(cy["after"], ".3f")])
    return buf.getvalue()


def write_summary(out_dir: str | Path, results: list[PartResult]) -> Path:
    """Write ``summary.csv`` into the output folder (atomically)."""
    return write_atomic(Path(out_dir) / "summary.csv", summary_csv(results))
