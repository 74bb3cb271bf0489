"""The virtual CNC run chunk by chunk: a long program's learning iteration in bounded memory.

:func:`ilcnc.vcnc.simulate.simulate_program` holds every sample of a run: the
reference (36 B per sample), the actual positions (24 B) and the contour error
(88 B). A 1-million-line program is 162 M samples at a 1 ms servo period, about
25 GB. A learning iteration needs none of it afterwards: only the error
statistics and ``E(k)`` per command. :func:`simulate_streamed` plans the
reference chunk by chunk (:func:`ilcnc.vcnc.plan.plan_chunks`), runs the drives on
each chunk with their state carried on (:class:`ilcnc.vcnc.drives.DriveStream`),
measures its contour error (sample by sample, so exact per chunk) and adds it
to the running statistics (:class:`ilcnc.vcnc.simulate.FeedStats`) and ``E(k)``
sums (:class:`ilcnc.vcnc.command_error.PathWeightedSums`), then drops the chunk.
Memory: one chunk (~150 B per sample, 40 MB at the default 262,144 samples), the
references of the next one or two planned ahead in a thread (36 B per sample each: :func:`_ahead`), plus
the program's tables. The figures are those of the whole run bit for bit (the
tests check it), so the learning loop takes this path whenever it can
(:func:`stream_unsupported`): the ``path`` error estimate, linear drives, no
geometric or cutting errors, no gain schedule.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ilcnc.contour.air import CuttingRule
from ilcnc.contour.figures import ErrorFigures
from ilcnc.errors import InputError
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import Program
from ilcnc.vcnc.command_error import CommandSignal, PathWeightedSums, finish_signal
from ilcnc.vcnc.plan import DEFAULT_CHUNK_SAMPLES, plan_chunks

__all__ = ["StreamedRun", "simulate_streamed", "stream_unsupported"]


@dataclass(slots=True, kw_only=True)
class StreamedRun:
    """What a chunked virtual-CNC run keeps: the figures a learning iteration records.

    Attributes
    ----------
    stats : dict
        ``max``, ``mean``, ``rms`` contour error over the cutting moves' samples, mm (as :class:`SimulationResult`).
    worst_sample : int
        Sample of the largest contour error of the cutting moves (-1 when there is none).
    worst_at : dict
        Command index ``k`` and source ``line`` of that sample.
    n_samples : int
        Samples of the run.
    period_s : float
        Servo period, s.
    signal : CommandSignal
        ``E(k)`` of the run (the ``path`` estimate) against the original drawing.
    chunks : int
        Chunks the run was planned in.
    timings_s : dict
        Wall time of each stage summed over the chunks, s: ``plan``, ``drives``, ``contour``, ``stats``, ``error``.
    air_stats : dict
        The air moves' figures, mm.
    cutting : CuttingRule
        The rule that told them apart (:mod:`ilcnc.contour.air`).
    """

    stats: ErrorFigures
    worst_sample: int
    worst_at: dict[str, int]
    n_samples: int
    period_s: float
    signal: CommandSignal
    chunks: int
    timings_s: dict[str, float] = field(default_factory=dict)
    shares: dict[str, dict[str, float]] = field(default_factory=dict)
    air_stats: ErrorFigures = field(default_factory=ErrorFigures)
    cutting: CuttingRule = field(default_factory=lambda: CuttingRule(None, "none"))

    @property
    def cycle_time_s(self) -> float:
        return max(self.n_samples - 1, 0) * self.period_s

    def worst(self, program: Program) -> dict[str, int]:
        """Command index and source line of the worst sample (``program`` as :meth:`SimulationResult.worst`)."""
        return dict(self.worst_at)

    def to_json(self, program: Program) -> dict[str, Any]:
        """The object of :meth:`ilcnc.vcnc.simulate.SimulationResult.to_json`."""
        from ilcnc.vcnc.simulate import run_json

        return run_json(self, program)


def stream_unsupported(profile: MachineProfile, kind: str, *, sources: Any = None,
                       gain_schedule: Any = None) -> str | None:
    """Why a run of this profile cannot go chunk by chunk (None: it can)."""
    from ilcnc.vcnc.drives import DriveStream

    if kind != "path":
        return f"the error estimate {kind!r} needs the whole run (only 'path' is accumulated chunk by chunk)"
    if sources is not None and getattr(sources, "enabled", False):
        return "geometric or cutting errors are on"
    if gain_schedule:
        return "a gain schedule is given"
    return DriveStream.unsupported(profile)


_DONE = object()


def _ahead(chunks: Iterator[Any]) -> Iterator[Any]:
    """``chunks`` planned one chunk ahead in a thread while the caller runs the drives and the contour error of
    the one before (the planner's kernels release the GIL: Gates_combined_R12.nc, 4 chunks, plans 0.41 s of
    its 0.8 s beside them). The same chunks in the same order (each is its own copy); an error of the
    planner is raised here. Not when the kernels run as Python (they hold the GIL) or one thread is allowed.
    """
    from ilcnc._jit import python_kernels
    from ilcnc._threads import thread_limit

    if python_kernels() or thread_limit() < 2:
        yield from chunks
        return
    box: queue.Queue[Any] = queue.Queue(maxsize=1)
    stop = threading.Event()

    def put(item: Any) -> bool:
        while not stop.is_set():  # the caller may stop taking (an error of its own): then give up
            try:
                box.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def plan() -> None:
        try:
            for ch in chunks:
                if not put(ch):
                    return
            put(_DONE)
        except BaseException as exc:  # handed to the caller, raised there
            put(exc)

    worker = threading.Thread(target=plan, name="ilcnc-plan-ahead", daemon=True)
    worker.start()
    try:
        while True:
            item = box.get()
            if item is _DONE:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join()


def simulate_streamed(
    program: Program,
    profile: MachineProfile,
    *,
    against: Program | None = None,
    gate_mm: float | None = None,
    chunk_samples: int = DEFAULT_CHUNK_SAMPLES,
    progress: Callable[[str], None] | None = None,
    vertices: Any = None,
) -> StreamedRun:
    """Run a program on the virtual CNC chunk by chunk; keep the statistics and ``E(k)``.

    Parameters
    ----------
    program : Program
        What the machine runs.
    profile : MachineProfile
        Limits, planner and drive models (linear drives: :func:`stream_unsupported`).
    against : Program, optional
        The original drawing the error is measured against (a compensated program's original).
    gate_mm : float, optional
        An ``E(k)`` longer than this is not a measurement (see :func:`ilcnc.vcnc.command_error.command_signal_from_run`).
    chunk_samples : int
        Samples per chunk (rounded down to the planner's block of 1024).
    progress : callable, optional
        Called with ``"plan"`` once at the start.
    vertices : ilcnc.vcnc.rounding.VertexMax, optional
        Given: each chunk's cutting samples' largest error near each end point of the judged path is added to it.

    Raises
    ------
    InputError
        As :func:`ilcnc.vcnc.simulate.simulate_program`.
    ValueError
        The profile cannot run chunk by chunk (:func:`stream_unsupported`).
    """
    from ilcnc.contour.air import air_above_mm, cutting_samples, profile_move_classes
    from ilcnc.contour.path import PathGeometry
    from ilcnc.contour.search import contour_error
    from ilcnc.vcnc.drives import DriveStream
    from ilcnc.vcnc.simulate import FeedStats, against_slack_mm, check_against, check_travel, moves_on_target

    why = stream_unsupported(profile, "path")
    if why:
        raise ValueError(why)
    program.require_modelled()
    target = against if against is not None else program
    move_map = check_against(program, against)
    check_travel(program, profile)
    if progress:
        progress("plan")
    # the path with its rapids: a feed sample still on the line of the rapid before it is in the air, not off
    # the cut (its E(k) counts for no command: command_error.PathWeightedSums)
    path = PathGeometry.from_moves(target.moves, include_rapids=True)
    rule, classes = profile_move_classes(target, profile)
    above = air_above_mm(target, rule, classes, resolution_mm=profile.machine.resolution_mm)
    slack: Any = profile.planner.corner_tolerance_mm
    if against is not None:
        slack = slack + against_slack_mm(program, target, move_map)
    timings = {"plan": 0.0, "drives": 0.0, "contour": 0.0, "stats": 0.0, "error": 0.0}
    sums = PathWeightedSums(path)
    feed_stats = FeedStats()
    drives: DriveStream | None = None
    worst_at = {"k": -1, "line": 0}
    period = profile.machine.servo_period_s
    n = chunks = 0
    chunk_iter = _ahead(plan_chunks(program, profile, chunk_samples=chunk_samples))
    while True:
        t0 = time.perf_counter()
        ch = next(chunk_iter, None)
        timings["plan"] += time.perf_counter() - t0
        if ch is None:
            break
        chunks += 1
        t0 = time.perf_counter()
        if drives is None:
            drives = DriveStream(profile, ch.pos_mm[0])
        act = drives.step(ch.pos_mm)
        t1 = time.perf_counter()
        on_target = moves_on_target(ch.move, move_map)
        err = contour_error(path, act, on_target, reference_mm=ch.pos_mm, reference_slack_mm=slack)
        t2 = time.perf_counter()
        before = feed_stats.worst_sample
        feed = feed_stats.add(on_target, classes, err.dist_mm, ch.first_sample, foot_z_mm=err.foot_mm[:, 2],
                              above_mm=above)
        if feed_stats.worst_sample != before:
            j = feed_stats.worst_sample - ch.first_sample
            seg = int(err.seg[j]) if err.seg[j] >= 0 else int(on_target[j])
            worst_at = {"k": int(target.moves.command[seg]), "line": int(target.moves.line[seg])}
        if vertices is not None:
            vertices.add(err.dist_mm, err.u, err.seg, cutting_samples(on_target, classes, err.foot_mm[:, 2], above))
        t3 = time.perf_counter()
        sums.add(err, period, on_feed=feed, first_sample=ch.first_sample)
        t4 = time.perf_counter()
        timings["drives"] += t1 - t0
        timings["contour"] += t2 - t1
        timings["stats"] += t3 - t2
        timings["error"] += t4 - t3
        n += ch.n_samples
        del act, err, feed, ch
    if n == 0:
        raise InputError(program.path, None, "the program has no motion to simulate")
    stats, worst = feed_stats.result()
    e, t = sums.result()
    gate = gate_mm if gate_mm is not None else np.inf
    e[np.linalg.norm(np.nan_to_num(e, nan=np.inf), axis=1) > gate] = np.nan
    return StreamedRun(stats=stats, worst_sample=worst, worst_at=worst_at if worst >= 0 else {"k": -1, "line": 0},
                       n_samples=n, period_s=period, signal=finish_signal(e, t, "path"), chunks=chunks,
                       timings_s=timings, shares={}, air_stats=feed_stats.air_result(), cutting=rule)
