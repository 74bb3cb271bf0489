"""The expected outcomes of learning, as explicit result states (like ruckig's ``Result``).

Each is a string enum: its members compare equal to, and serialise (JSON, CSV, ``state.json``)
exactly as, the strings ilcnc wrote before, so files and ``--json`` output are unchanged; but a
misspelt state is an ``AttributeError`` where it is written, and a table that maps the states to
messages is checked to name every member (``tests/test_outcomes.py``).
"""

from __future__ import annotations

from enum import Enum

__all__ = ["CheckStatus", "DriveSource", "GuardVerdict", "LearnMode", "LearnStatus", "LiftedStatus", "ModelStepEnd",
           "PartStatus", "PathMode", "StrEnum"]


class StrEnum(str, Enum):
    """A string enum whose ``str()`` and ``format()`` are its value (:class:`enum.StrEnum` from Python 3.11)."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


class LearnStatus(StrEnum):
    """Where a learning run (virtual, or one measured step) stands."""

    LEARNING = "learning"  #: a state created, no measured step yet
    STEPPED = "stepped"  #: a measured step made: run the new program and log it
    CONVERGED = "converged"  #: the error is within the stop tolerance
    STOPPED = "stopped"  #: no further gain possible (stalled, nothing to correct)
    DIVERGED = "diverged"  #: the guard refused a step twice: the best iteration is the output
    MAX_ITERATIONS = "max_iterations"  #: the iteration budget is spent


class LearnMode(StrEnum):
    """What the learning learns from."""

    VIRTUAL = "virtual"  #: the virtual CNC of the profile
    LOG = "log"  #: a measured axis log
    POINTS = "points"  #: measured (probe, CMM) points


class PartStatus(StrEnum):
    """A batch part's result: a learning status, or one of the batch's own."""

    LEARNING = "learning"
    STEPPED = "stepped"
    CONVERGED = "converged"
    STOPPED = "stopped"
    DIVERGED = "diverged"
    MAX_ITERATIONS = "max_iterations"
    ERROR = "error"  #: the part could not be learned (its error is in the summary)
    REGRESSED = "regressed"  #: diverged and its best run is no better than the original

    @classmethod
    def of(cls, status: LearnStatus) -> PartStatus:
        """The part status of a learning status."""
        return cls(str(status))

    @property
    def failed(self) -> bool:
        """A status the batch exits 1 for."""
        return self in (PartStatus.ERROR, PartStatus.REGRESSED)


class LiftedStatus(StrEnum):
    """What the lifted check says of a learning gain on a program (seed 004)."""

    MONOTONE = "monotone"  #: ‖I − G Q Γ S‖₂ < 1: the error falls at every iteration
    ASYMPTOTIC = "asymptotic"  #: spectral radius ≤ 1: it falls in the end, may grow first
    DIVERGENT = "divergent"  #: spectral radius > 1


class ModelStepEnd(StrEnum):
    """Why the virtual-CNC steps after a measured step ended (``learning.model_steps``)."""

    STEPS = "steps"  #: all the steps asked for were made
    NO_GAIN = "no gain"  #: the next would not lower the predicted error
    LAW = "law"  #: the law keeps a history and takes no model step
    KIND = "kind"  #: the measurement's error estimate is not one the virtual CNC predicts


class GuardVerdict(StrEnum):
    """What the learning guard does with a run that made the error worse (:mod:`ilcnc.learning.guard`)."""

    HALVED = "halved"  #: not kept; the next iteration starts from the best one with the gain halved
    STOPPED = "stopped"  #: it grew again with the gain halved: learning stops, the best iteration is the output


class CheckStatus(StrEnum):
    """What ``ilcnc check``'s gate says about one program (its exit code: ``ilcnc check --help``)."""

    PASSED = "passed"  #: every threshold and baseline figure kept
    FAILED = "failed"  #: over a threshold, no cutting move, or regressed against the baseline
    UNREADABLE = "unreadable"  #: the program could not be read or run (an error line says why)


class DriveSource(StrEnum):
    """What a LinuxCNC configuration's HAL does with a joint's position command (``ilcnc linuxcnc profile``)."""

    SERVO_PID = "servo_pid"  #: a ``pid`` loop takes the command: its gains give the position loop
    STEPGEN = "stepgen"  #: a step generator in position mode: it reaches the command within one servo period
    LOOPBACK = "loopback"  #: the command is wired straight back as the feedback (a simulation)
    UNKNOWN = "unknown"  #: none of these (a Tcl HAL file, a drive on a bus): the drive is a default to measure


class PathMode(StrEnum):
    """The path control a stretch of a program runs in (``ilcnc linuxcnc prepare``)."""

    UNSET = "none"  #: no G61/G64 in the program: the control's start-up mode applies
    EXACT_STOP = "G61.1"  #: stop at every block end
    EXACT_PATH = "G61"  #: stop at every corner
    BOUNDED = "G64 P"  #: blend within the P tolerance
    UNBOUNDED = "G64"  #: blend as fast as the axes allow (no P, or P0)

    @classmethod
    def of_tolerance(cls, tol_mm: float) -> PathMode:
        """The mode of a move's ``MoveTable.blend_tol_mm`` (NaN unset, -1 G61.1, 0 G61, +inf G64, else G64 P)."""
        if tol_mm != tol_mm:  # NaN
            return cls.UNSET
        if tol_mm < 0:
            return cls.EXACT_STOP
        if tol_mm == 0:
            return cls.EXACT_PATH
        return cls.UNBOUNDED if tol_mm == float("inf") else cls.BOUNDED
