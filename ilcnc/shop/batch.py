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

On a Dask cluster (``scheduler=``) a worker may be another machine with none of the client's files: each
part is sent as contents (:class:`ShippedPart`: the program's bytes, the profile's text and the files it
names, the part's learning state if one exists), learned in a private folder of the worker
(:func:`learn_shipped`), and its output, state files and result come back (:class:`ReturnedPart`); the client
writes them where it asked, as the local run writes them (:func:`write_returned`). A part whose worker was
lost is run again by Dask; its ``attempts`` count the workers that held it.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import io
import os
import reprlib
import shutil
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ilcnc._threads import limit_process, thread_limit_scope, threads_per_part
from ilcnc.errors import IlcncError, InputError, StateError, UsageError
from ilcnc.fileio import inside, read_bytes, remove_stale_temporaries, unsynced_writes, write_atomic
from ilcnc.outcomes import PartStatus
from ilcnc.shop.state import STATE_FILE, LearnState, state_lock

__all__ = ["BatchJob", "PartResult", "ReturnedPart", "ShippedPart", "folder_programs", "jobs_from_path", "learn_shipped",
           "retried", "run_batch", "ship_part", "summary_csv", "write_returned"]


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
    #: times the part was started: 1, plus one for each Dask worker that was lost while it held the part (Dask ran
    #: it again on another); always 1 on local workers
    attempts: int = 1

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


# ------------------------------------------------------------------ a part as contents, for a Dask worker

#: Profile keys that name a file (relative to the profile file): a part sent to a Dask worker carries their contents.
#: tests/test_batch.py checks this list against the schema's keys described as "relative to the profile file".
_PROFILE_FILE_KEYS = ("geometry.map", "tool.frf_csv", "cutting.stock")
#: Times Dask runs a part again whose task raised (a worker's disk full, say); a lost worker is Dask's own rule
#: (``distributed.scheduler.allowed-failures``, 3 by default: a part that took down more workers is given up).
_RETRIES = 1
#: Threads of the client that write the parts' results back (they wait on the disk's fsync, not on a core).
_WRITERS = 4
#: Versions a worker must share with the client: the outputs are byte for byte those of the same versions only.
_VERSIONED = ("ilcnc", "numpy", "scipy", "numba", "llvmlite")


@dataclass(frozen=True, slots=True)
class ShippedPart:
    """One part as contents, for a worker that has none of the client's files.

    ``job`` keeps the client's paths (the names in messages and results). ``profile_files`` are the files the
    profile names, as written in it, with their bytes; ``state`` the part's learning state folder (file name,
    bytes) and ``program_state`` the one beside the program (``PROG.state``: a program that is an earlier output
    is recognised by it), None where the client has none. ``shared_folder``: program and output in one folder.
    """

    job: BatchJob
    versions: tuple[str, ...]
    program: bytes
    profile: bytes
    profile_files: tuple[tuple[str, bytes], ...] = ()
    state: tuple[tuple[str, bytes], ...] | None = None
    program_state: tuple[tuple[str, bytes], ...] | None = None
    shared_folder: bool = False


@dataclass(frozen=True, slots=True)
class ReturnedPart:
    """What a worker sends back: the result (the client's paths in it), the output program's bytes (None: none
    written), the state files the run wrote or changed, and the names of every file of the state folder after
    the run (None: the run made no state folder)."""

    result: PartResult
    output: bytes | None = None
    state_files: tuple[tuple[str, bytes], ...] = ()
    state_names: tuple[str, ...] | None = None


@functools.lru_cache(maxsize=1)
def _versions() -> tuple[str, ...]:
    from importlib.metadata import PackageNotFoundError, version

    out = []
    for name in _VERSIONED:
        try:
            out.append(f"{name} {version(name)}")
        except PackageNotFoundError:
            out.append(f"{name} (not installed)")
    return tuple(out)


def _part_error(job: BatchJob, message: str) -> PartResult:
    return PartResult(program=job.program, profile=job.profile, status=PartStatus.ERROR, error=message)


def _folder_files(folder: Path) -> tuple[bool, tuple[tuple[str, bytes], ...] | None]:
    """A learning state folder's files by name (None: no folder); False first where it holds anything but files
    (the client learns such a part itself, as the local run would)."""
    if not folder.exists():
        return True, None
    if not folder.is_dir() or folder.is_symlink():
        return False, None
    entries = sorted(folder.iterdir())
    if any(not p.is_file() or p.is_symlink() for p in entries):
        return False, None
    return True, tuple((p.name, read_bytes(p)) for p in entries)


def _up_levels(name: str) -> int:
    """Leading ``..`` of a relative file name, normalised (``maps/../../x.csv``: 1)."""
    parts = Path(os.path.normpath(name)).parts
    return next((i for i, p in enumerate(parts) if p != ".."), len(parts))


#: What a profile sends with its parts (its files by name as written in it, with their bytes), or why it cannot go
#: (a refusal's message; None: the client cannot read or check it), by (profile path, profile bytes).
ProfileFiles = dict[tuple[str, bytes], "tuple[tuple[str, bytes], ...] | str | None"]


def _profile_files(path: str) -> tuple[tuple[str, bytes], ...] | str | None:
    """What the profile at ``path`` sends with its parts (see :data:`ProfileFiles`)."""
    from ilcnc.profile.load import load_profile

    try:
        profile = load_profile(path)
        files = []
        for key in _PROFILE_FILE_KEYS:
            section, name = key.split(".")
            value = getattr(getattr(profile, section), name)
            if value is None:
                continue
            if Path(value).expanduser().is_absolute():
                return InputError(Path(path), None, f"{key}: {value} is an absolute path, which a Dask worker does not"
                                  " have: name it relative to the profile (the file is sent with the part)").format()
            files.append((str(value), read_bytes(profile.resolve(value))))
    except (IlcncError, OSError):
        return None
    return tuple(files)


def ship_part(job: BatchJob, profiles: ProfileFiles | None = None) -> ShippedPart | PartResult | None:
    """The part as contents (:class:`ShippedPart`), read on the client.

    Returns a refusal (:class:`PartResult`, status ``error``) for a profile naming a file by an absolute path
    (a worker has no such file), and None where the client cannot read or check an input: the client learns
    that part itself, which refuses it with the local run's message (or finds it does not need the file).
    As ``ilcnc learn`` does first, what killed writers left of this part's output and state is removed here.
    ``profiles``: a batch's cache of what each profile sends (a profile is loaded once, not once per part:
    ~40 ms each, 8 s of a 200-part batch before the first part could start).
    """
    out, state = Path(job.out), Path(job.state)
    if state.is_dir():
        remove_stale_temporaries(state)
    remove_stale_temporaries(out.parent if str(out.parent) else Path("."), out.name)
    cache: ProfileFiles = {} if profiles is None else profiles
    try:
        program = read_bytes(job.program)
        profile_text = read_bytes(job.profile)
        key = (job.profile, profile_text)
        if key not in cache:
            cache[key] = _profile_files(job.profile)
        files = cache[key]
        ok_state, state_files = _folder_files(state)
        prog = Path(job.program)
        ok_beside, beside = _folder_files(prog.with_name(prog.name + ".state"))
    except (IlcncError, OSError):
        return None
    if isinstance(files, str):
        return _part_error(job, files)
    if files is None or not (ok_state and ok_beside):
        return None
    shared = prog.parent.resolve() == out.parent.resolve()
    return ShippedPart(job, _versions(), program, profile_text, files, state_files, beside, shared)


def _scratch_folder() -> str | None:
    """The Dask worker's own scratch folder (Dask removes a killed worker's when the next worker starts)."""
    try:
        from distributed import get_worker

        return str(get_worker().local_directory)
    except (ImportError, ValueError, AttributeError):  # not in a worker: the system's temporary folder
        return None


def _unpack(folder: Path, files: tuple[tuple[str, bytes], ...] | None) -> None:
    if files is None:
        return
    folder.mkdir()
    for name, data in files:
        (folder / name).write_bytes(data)


def _renamer(pairs: list[tuple[str, str]]) -> Callable[[str | None], str | None]:
    """Text with the worker's paths replaced by the client's (longest first: a folder is a prefix of its files)."""
    ordered = sorted(pairs, key=lambda p: -len(p[0]))

    def rename(text: str | None) -> str | None:
        if text is None:
            return None
        for worker, client in ordered:
            text = text.replace(worker, client)
        return text

    return rename


def learn_shipped(part: ShippedPart, threads: int | None = None) -> ReturnedPart:
    """Learn a shipped part in a private folder of this worker; return its output, state files and result.

    The task writes nothing outside that folder (removed at the end), so Dask may run it again on another
    worker when this one is lost. Messages and results name the client's paths, and the state records the
    client's output path, so the client writes what the local run writes.
    """
    job = part.job
    mine = _versions()
    if part.versions != mine:
        diff = ", ".join(f"{m} here, {c} on the client" for m, c in zip(mine, part.versions, strict=False) if m != c)
        return ReturnedPart(_part_error(job, f"{job.program}: this Dask worker runs other versions ({diff}): install"
                                        " the client's versions on every worker (outputs are byte for byte those of"
                                        " the same versions only)"))
    root = Path(tempfile.mkdtemp(prefix="ilcnc-part-", dir=_scratch_folder()))
    try:
        prog_c, prof_c, out_c, state_c = Path(job.program), Path(job.profile), Path(job.out), Path(job.state)
        pdir = root / "program"
        odir = pdir if part.shared_folder else root / "out"
        # the profile deep enough that its '../' names stay inside the private folder
        cdir = root.joinpath("profile", *["up"] * max((_up_levels(n) for n, _ in part.profile_files), default=0))
        for d in (pdir, odir, cdir):
            d.mkdir(parents=True, exist_ok=True)
        wprog, wprof, wout, wstate = pdir / prog_c.name, cdir / prof_c.name, odir / out_c.name, odir / state_c.name
        wprog.write_bytes(part.program)
        wprof.write_bytes(part.profile)
        for name, data in part.profile_files:
            dest = Path(os.path.normpath(cdir / name))
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(data)
        _unpack(wstate, part.state)
        _unpack(pdir / (prog_c.name + ".state"), part.program_state)

        def prefix(d: Path) -> str:
            return "" if str(d) == "." else f"{d}/"

        rename = _renamer([(str(wprog), str(prog_c)), (str(wprof), str(prof_c)), (str(wout), str(out_c)),
                           (str(wstate), str(state_c)), (f"{cdir}/", prefix(prof_c.parent)),
                           (f"{odir}/", prefix(out_c.parent)), (f"{pdir}/", prefix(prog_c.parent)),
                           (str(root), "(the worker's folder)")])
        with unsynced_writes():  # the folder is thrown away: the client writes (and syncs) what it keeps
            res = _learn_one_dask(BatchJob(str(wprog), str(wprof), str(wout), str(wstate), job.iterations), threads)
        res.program, res.profile, res.error = job.program, job.profile, rename(res.error)
        res.output = str(out_c) if res.output is not None else None
        if (wstate / STATE_FILE).is_file():
            try:
                st: LearnState | None = LearnState.load(wstate)
            except IlcncError:  # a damaged state: the run refused it with the local run's message already
                st = None
            named = [e for e in st.iterations if e.output == str(wout)] if st is not None else []
            for e in named:
                e.output = str(out_c)  # what the local run records: the output where the client asked for it
            if st is not None and named:
                with unsynced_writes():
                    st.save()
        shipped = dict(part.state or ())
        names, back = None, []
        if wstate.is_dir():
            entries = sorted(wstate.iterdir())
            names = tuple(p.name for p in entries)
            for p in entries:
                data = p.read_bytes()
                if shipped.get(p.name) != data:
                    back.append((p.name, data))
        return ReturnedPart(res, wout.read_bytes() if wout.is_file() else None, tuple(back), names)
    finally:
        shutil.rmtree(root, ignore_errors=True)


def write_returned(part: ShippedPart, back: ReturnedPart) -> PartResult:
    """Write what a worker returned where the client asked, as the local run writes it: the state's files, then
    ``state.json`` (the commit point), then the output, each atomically with the user's umask.

    The state is locked meanwhile; a state another ``ilcnc learn`` changed while the part was on the cluster is
    left alone and the part reported as an error.
    """
    job = part.job
    state = Path(job.state)
    try:
        with state_lock(state):
            index = state / STATE_FILE
            now = read_bytes(index) if index.is_file() else None
            if now != dict(part.state or ()).get(STATE_FILE):
                raise StateError(state, None, "changed while the part was learned on the cluster (another ilcnc learn?):"
                                 " nothing of this run was written; learn the part again")
            if back.state_names is not None:
                state.mkdir(exist_ok=True)
                files = dict(back.state_files)
                for name, data in files.items():
                    if name != STATE_FILE:
                        write_atomic(state / name, data)
                for name, _ in part.state or ():
                    if name not in back.state_names:  # files the run removed (a killed run's leftovers)
                        (state / name).unlink(missing_ok=True)
                if STATE_FILE in files:
                    write_atomic(index, files[STATE_FILE])
            if back.output is not None:
                write_atomic(job.out, back.output, protect=(job.program, job.profile))
    except IlcncError as exc:
        return _part_error(job, exc.format())
    except OSError as exc:  # the client's disk full, a folder not writable: this part's error, as in the local run
        return _part_error(job, f"{exc.filename or job.out}: cannot write: {exc.strerror or exc}")
    return back.result


def _cluster_error(job: BatchJob, exc: BaseException) -> str:
    """The one-line error of a part the cluster gave up (workers lost, a worker without ilcnc, ...)."""
    if type(exc).__name__ == "KilledWorker":
        return (f"{job.program}: Dask gave this part up after the workers that ran it were lost (allowed-failures): does"
                " it need more memory than a worker has?")
    text = " ".join(str(exc).split())[:200]
    return f"{job.program}: the Dask cluster could not run this part: {type(exc).__name__}: {text}"


def _run_dask(jobs: list[BatchJob], scheduler: str | Any, results: list[PartResult | None],
              on_result: Callable[[PartResult], None] | None, threads: int | None = None) -> None:
    import concurrent.futures as cf

    try:
        from distributed import Client, as_completed
    except ImportError:
        raise InputError(None, None, "--scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
    own = isinstance(scheduler, str)
    if own:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise UsageError("--scheduler", f"cannot reach a Dask scheduler at {scheduler}: {exc}") from None
    else:
        client = scheduler

    def done(i: int, r: PartResult) -> None:
        results[i] = r
        if on_result:
            on_result(r)

    try:
        shipped: dict[int, ShippedPart] = {}
        here: list[int] = []
        profiles: ProfileFiles = {}
        for i, job in enumerate(jobs):
            sh = ship_part(job, profiles)
            if isinstance(sh, ShippedPart):
                shipped[i] = sh
            elif sh is None:
                here.append(i)
            else:
                done(i, sh)
        order = sorted(shipped)
        futs = client.map(learn_shipped, [shipped[i] for i in order], threads=threads, pure=False, retries=_RETRIES)
        index = {f.key: i for f, i in zip(futs, order, strict=True)}
        for i in here:  # inputs the client cannot read: refused here with the local run's message while the cluster works
            done(i, learn_one(jobs[i]))
        given_up: set[int] = set()
        # the client writes each part's files (~9 fsyncs, ~60 ms a small part): in threads, which wait on the disk
        # together (one thread after the other capped two workers' throughput at one's)
        with cf.ThreadPoolExecutor(max_workers=_WRITERS, thread_name_prefix="ilcnc-write") as writers:
            writing: dict[cf.Future[PartResult], int] = {}

            def written(wait: bool) -> None:
                finished = list(cf.as_completed(writing)) if wait else [w for w in writing if w.done()]
                for w in finished:
                    done(writing.pop(w), w.result())

            for f in as_completed(futs):
                i = index[f.key]
                try:
                    back = f.result()
                except Exception as exc:
                    if type(exc).__name__ == "KilledWorker":
                        given_up.add(i)
                    done(i, _part_error(jobs[i], _cluster_error(jobs[i], exc)))
                else:
                    writing[writers.submit(write_returned, shipped[i], back)] = i
                written(False)
            written(True)
        for key, n in _extra_attempts(client, list(index)).items():
            i = index[key]
            # a part Dask gave up was never finished: its attempts are the workers lost while they held it
            results[i].attempts = max(1, n + (0 if i in given_up else 1))  # type: ignore[union-attr]
    finally:
        if own:
            client.close()


def _extra_attempts(client: Any, keys: list[Any]) -> dict[Any, int]:
    """Per task, the runs that did not give its result: each worker lost while it held the task (``suspicious``)
    and each run that raised and was retried. Empty where the scheduler does not answer."""

    def count(dask_scheduler: Any, keys: list[Any], retries: int) -> dict[Any, int]:  # runs on the scheduler
        out = {}
        for k in keys:
            ts = dask_scheduler.tasks.get(k)
            if ts is not None:
                out[k] = int(ts.suspicious) + max(0, retries - int(ts.retries))
        return out

    try:
        return dict(client.run_on_scheduler(count, keys=keys, retries=_RETRIES))
    except Exception:  # a scheduler that refuses code from clients: the counts are unknown, not wrong
        return {}


def summary_csv(results: Iterable[PartResult]) -> str:
    """The summary table as CSV text."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    # the figures are the cutting moves' (ilcnc.contour.air); columns after "error" were added later (kept at the end
    # so that scripts reading the first ten keep working)
    w.writerow(["program", "profile", "status", "g01_commands", "iterations", "rms_before_mm", "rms_after_mm", "clipped",
                "output", "error", "max_before_mm", "max_after_mm", "air_max_after_mm", "cycle_before_s", "cycle_after_s",
                "attempts"])

    def num(x: float | None, fmt: str = ".6f") -> str:
        return "" if x is None else format(x, fmt)

    for r in results:
        ce, mx, cy = r.contour_error_mm, r.max_error_mm, r.cycle_time_s
        w.writerow([r.program, r.profile, r.status, r.g01_commands, r.iterations, num(ce["before"]), num(ce["after"]),
                    r.clipped, r.output or "", r.error or "", num(mx["before"]), num(mx["after"]), num(mx["air_after"]),
                    num(cy["before"], ".3f"), num(cy["after"], ".3f"), r.attempts])
    return buf.getvalue()


def retried(results: Iterable[PartResult]) -> list[PartResult]:
    """The parts that were started more than once (their Dask worker was lost, or their task raised)."""
    return [r for r in results if r.attempts > 1]


def write_summary(out_dir: str | Path, results: list[PartResult]) -> Path:
    """Write ``summary.csv`` into the output folder (atomically)."""
    return write_atomic(Path(out_dir) / "summary.csv", summary_csv(results))
