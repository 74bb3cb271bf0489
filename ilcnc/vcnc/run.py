"""One entry for a virtual-CNC run: whole (every sample kept) or streamed (chunk by chunk), decided here only.

:func:`run_virtual` runs a program on the profile's virtual CNC. A caller that needs the samples (a log to
write, a plot, per-move figures) asks for them with ``keep_samples=True`` and gets a
:class:`ilcnc.vcnc.simulate.SimulationResult`; otherwise the run goes chunk by chunk in bounded memory
wherever the profile allows (:func:`ilcnc.vcnc.stream.stream_unsupported`) and gives a
:class:`ilcnc.vcnc.stream.StreamedRun` with the same figures. Both answer :class:`RunFigures`: what every
command prints and every learning iteration records.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from ilcnc.contour.air import CuttingRule
from ilcnc.contour.figures import ErrorFigures
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import Program

__all__ = ["RunFigures", "run_virtual", "simulate_figures"]


@runtime_checkable
class RunFigures(Protocol):
    """The figures of a virtual-CNC run, whole or streamed (mm, s)."""

    stats: ErrorFigures  #: the cutting moves' contour error: ``max``, ``mean``, ``rms``
    air_stats: ErrorFigures  #: the air moves' figures
    shares: dict[str, dict[str, float]]  #: each error source's share
    timings_s: dict[str, float]  #: wall time per stage
    cutting: CuttingRule  #: how cutting and air moves were told apart
    worst_sample: int  #: sample of the cutting moves' largest error (-1: none)

    @property
    def cycle_time_s(self) -> float: ...

    @property
    def n_samples(self) -> int: ...

    @property
    def period_s(self) -> float: ...

    def worst(self, program: Program) -> dict[str, int]: ...

    def to_json(self, program: Program) -> dict[str, Any]: ...


def run_virtual(program: Program, profile: MachineProfile, *, against: Program | None = None, kind: str = "path",
                keep_samples: bool = False, sources: Any = None, gate_mm: float | None = None,
                progress: Callable[[str], None] | None = None, vertices: Any = None) -> RunFigures:
    """Run ``program`` on the virtual CNC of ``profile``.

    Parameters
    ----------
    program : Program
        What runs.
    profile : MachineProfile
        The machine.
    against : Program, optional
        The drawing the error is measured against (a corrected or refined program's original).
    kind : str
        The error estimate the caller will take from the run (only ``path`` is summed chunk by chunk).
    keep_samples : bool
        Keep every sample: a :class:`~ilcnc.vcnc.simulate.SimulationResult`. Otherwise streamed where the
        profile allows.
    sources : ErrorSources, optional
        The profile's error sources when already loaded (read from their files otherwise).
    gate_mm : float, optional
        ``E(k)`` farther than this is not measured (streamed runs; a whole run's signal is taken later).
    progress : callable, optional
        Called with a stage name.
    vertices : ilcnc.vcnc.rounding.VertexMax, optional
        Given: the cutting error near each end point of the judged path is added to it (:mod:`ilcnc.vcnc.rounding`).
    """
    from ilcnc._jit import kernels_for
    from ilcnc.vcnc.drives import DriveStream
    from ilcnc.vcnc.machine_errors import ErrorSources
    from ilcnc.vcnc.plan_base import nominal_samples
    from ilcnc.vcnc.simulate import simulate_program
    from ilcnc.vcnc.stream import simulate_streamed, stream_unsupported

    if sources is None:
        sources = ErrorSources.from_profile(profile)
    # a small run's kernels run as Python: importing numba would cost more than the run (ilcnc._jit.kernels_for);
    # a sample through the friction or cross-coupled loop costs ~3 of a linear drive's as Python
    moves = getattr(program, "moves", None)
    weight = 1 if DriveStream.unsupported(profile) is None else 3
    with kernels_for(0 if moves is None else nominal_samples(moves, profile), weight):
        if not keep_samples and stream_unsupported(profile, kind, sources=sources) is None:
            return simulate_streamed(program, profile, against=against, gate_mm=gate_mm, progress=progress,
                                     vertices=vertices)
        return simulate_program(program, profile, against=against, progress=progress, sources=sources,
                                vertices=vertices)


def simulate_figures(program: Program, profile: MachineProfile, *, against: Program | None = None,
                     progress: Callable[[str], None] | None = None, vertices: Any = None) -> RunFigures:
    """The figures of a run in the least memory (``ilcnc simulate`` without ``--log-out``, ``ilcnc check``); with
    ``vertices`` (a :class:`ilcnc.vcnc.rounding.VertexMax`) the error near each end point is added to it."""
    return run_virtual(program, profile, against=against, progress=progress, vertices=vertices)
