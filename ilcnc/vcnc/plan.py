"""Feed planning: the reference trajectory r(t) a CNC interpolator would command.

Method: FIR-filter interpolation
--------------------------------
The path is first traversed by an *ideal interpolator* at piecewise-constant speed (each move, or the zones of a
move near its corners, at its own speed; arcs as arcs, sampled exactly). That position signal is then smoothed by
cascaded moving-average (FIR) filters on every axis:

* ``seven_phase``: two filters, lengths ``T1`` and ``T2``. A velocity step
  through them becomes a trapezoidal acceleration with constant-jerk ramps:
  the classical 7-phase jerk-limited profile (for a rest-to-rest move it is
  the time-optimal one once the move reaches V and A).
* ``cubic``: a third filter of the profile's ``jerk_time_constant_s`` makes
  the jerk continuous (piecewise linear), the "cubic acceleration profiles"
  of seed 004 (not the 7-phase profile; DESIGN.md lists this defect).
* ``constant_feed``: no filter: the ideal interpolator itself (no
  acceleration limits), as the seed 000 and 003 cases need.

Why filters instead of a hand-written look-ahead: a moving average of length ``T`` turns any velocity jump ``dv``
into an acceleration ``dv/T`` and any acceleration jump ``da`` into a jerk ``da/T``; so the acceleration and jerk of
every axis are bounded by construction, the feed is never forced to zero between short CAM segments (the filter
averages over many of them) and the whole plan is a few running sums per sample. Corners are rounded by the filters;
the speed through each junction is chosen so that the rounding stays within the corner tolerance (like LinuxCNC's
``G64 P``) and the acceleration within the axes' limits, both computed from every direction change within the
filters' span (:mod:`ilcnc.vcnc.plan_corners`): a corner alone is rounded by ``v·|Δu|·E[τ⁺]`` (``T/8 + t²/(24·T)``
for two filters, ``T`` the longer), a densely segmented curve shrinks as its arc, and a chain of small kinks that
alternate (a corrected line) by what the filters leave of them. Arcs shrink by ``v²(T1²+T2²)/(24R)``; their speed is
limited the same way, and by the centripetal acceleration ``v²/R``.

After filtering, every axis's velocity, acceleration and jerk are checked on the sampled reference (finite
differences); where a limit would be exceeded (e.g. a reversal, which doubles a velocity jump) the speed of the
moves around it is lowered and that group is planned again.

Rapids and feed moves form separate *groups* with their own time constants (rapids are much faster); the planner
comes to a stop between groups.

Path control
------------
The program's own path control mode (``MoveTable.blend_tol_mm``, set by G-code ``G61``/``G61.1``/``G64 [P]`` and
Klartext cycle 32) is applied per corner, as LinuxCNC's trajectory planner does (``tp.c``/``tc.c``, 2.9):

* the move *before* a corner decides whether it is blended or stopped at (LinuxCNC stores the mode in each segment
  when it is queued and checks the previous segment's ``term_cond`` at the junction). A move without a program
  setting (NaN) takes the profile's ``corner_tolerance_mm``;
* exact path (``G61``, tolerance 0): stop at the corner, but pass a tangent
  join at speed; exact stop (``G61.1``): stop at the end of every move;
* blending: the corner tolerance is the smaller of the two moves'
  tolerances (``tcFindBlendTolerance``; a move in an exact mode after the
  corner sets none). A tolerance the program sets is also bounded, as
  LinuxCNC bounds it, by a quarter of the shorter of the two moves; so
  ``G64`` without P (or ``P0``: +inf in the table) is "as fast as the axes
  allow, within a quarter of the moves' length": the filters' corner rounding
  at the speed the acceleration limits permit. The profile's tolerance is
  used as it is (no quarter bound), as before;
* arcs: LinuxCNC follows them exactly in every mode; here the filters shrink
  them, by at most the move's ``G64 P`` or, in the exact modes and without
  a bound, the profile's tolerance;
* ``G64 Q`` (LinuxCNC merges short collinear G1 blocks within Q) is ignored:
  commands are never merged.

Compared with LinuxCNC 2.9 (``configs/linuxcnc-sim``, 100 mm/s, 1000 mm/s²):
on jscut's ``jsdc.gcode`` with ``G64`` the planned path is 14 µm RMS (233 µm
at most) from LinuxCNC's and 1.0 % slower; with ``G64 P0.05`` 2.4 µm RMS
(26 µm at most), 3.5 % slower (measured 2026-12-01, after short moves stopped
running whole at their slower corner's speed); a square in ``G61`` is 0.1 µm from it. Where the
virtual CNC must move as LinuxCNC does (its corners and short moves decide the
error), ``planner.profile: linuxcnc`` plans with LinuxCNC's own rules instead
(:mod:`ilcnc.vcnc.plan_tp`).

Inverse time
------------
A move with ``MoveTable.block_time_s`` (``G93``) runs at the speed its
length and time give; a block of zero length is a stand-still of its time
(``60 / F`` s), whose junctions both take the corner between the moves
around it. LinuxCNC 2.9 does not stand still there: its planner drops
zero-length segments (measured on ``configs/linuxcnc-sim``: no pause).
The ideal interpolator's last tick is at the group's end, and a total time
within float noise (relative 1e-9) of a whole number of periods is that many
ticks, so one block per period gives one sample per block.

Dwells
------
A dwell (``MoveTable.dwell_s``: ``G4 P``, the bottom dwell of ``G82``/``G86``/``G89``, Klartext cycle 9) is
reached from a stop: the move before it ends a group (the filters bring the axes to rest), and the stand-still
before the next group is the in-position wait (``planner.in_position_s``, as between rapids and feed moves)
plus ``round(dwell_s / period)`` samples: a control stops, checks in-position, then dwells. A dwell before the
first move is that many samples at the start (the machine is at rest already: no in-position wait), a dwell
after the last move (``Program.trailing_dwell_s``) the in-position wait and its samples at the end. The samples
of a stand-still belong to the move before it (-1 before the first move), as LinuxCNC's log reads them
(:mod:`ilcnc.vcnc.plan_tp`). So cycle times (:func:`planned_duration_s`) include the dwells; a program without
one plans as before, sample for sample.

Performance
-----------
Per group, the ideal interpolator, the moving averages, the running sum back
to positions and the limit check run in one compiled pass (numba,
:func:`group_kernel`): blocks of 1024 samples go through the stages in a
buffer that stays in cache, and only the reference itself is written, straight
into the final position array (sized before planning from the speeds, with
slack for groups re-planned slower). The numpy path those kernels replace
(:func:`_plan_group_numpy`: about fifteen passes over (N, 3) arrays per group,
each a fresh allocation) is kept as the reference the kernel is tested
against, operation for operation the same arithmetic, so the numbers are the
same bit for bit; it also runs when numba is missing. On the 2-core
development machine the kernel plans 25-35 million samples per CPU-second,
9x the numpy path (``bench/simulate.py``); the 16-hour ``stellabee1`` (57.7 M
samples, planned with the profile's corner tolerance instead of its own ``G64``,
which makes it 7.5 h and 27 M samples) plans in 2-3 s, of which ~1 s is mapping
the 2.1 GB of fresh memory the reference occupies. The kernels are compiled once (numba cache, ~10 s).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc._jit import HAVE_NUMBA, compiled_for, njit
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.geometry import arc_sweep_rad, move_lengths_mm
from ilcnc.program.model import (
    BLEND_EXACT_PATH,
    BLEND_EXACT_STOP,
    BLEND_NO_BOUND,
    MOVE_ARC_CW,
    MOVE_RAPID,
    PLANE_AXES,
    MoveTable,
)
from ilcnc.vcnc.plan_base import EPS_MM, PlanLimits, check_run_length, dwell_samples, move_directions, nominal_speed_mm_s
from ilcnc.vcnc.plan_corners import junction_speeds, junction_tolerances, rounding_tables
from ilcnc.vcnc.plan_kernels import BLOCK_SAMPLES, arc_table, group_kernel, group_range, group_state
from ilcnc.vcnc.plan_zones import Pieces, slow_zones, zone_pieces

__all__ = [
    "Reference", "ReferenceChunk", "check_limits", "corner_zones_mm", "plan_chunks", "plan_moves", "plan_program",
    "planned_duration_s", "planned_move_times_s", "profile_moves", "vertex_tolerances_mm"
]

_EPS = EPS_MM
_HOLD_SAMPLES = 3
#: In-position wait between rapids and feed moves, s (CNCs check in-position after G0).
IN_POSITION_S = 0.1
#: Relative float noise of finite-difference jerk on positions of ~1e2 mm at a 1 ms period
#: (8·eps·|x|/Ts³ plus the cumulative sums of the filters); limits are checked beyond it.
_FD_NOISE = 1e-5
#: Rows the position array is given beyond its estimate (plus 1/64 of it) for groups re-planned slower.
_SLACK_ROWS = 65536
#: Relative slack on the number of interpolator ticks (float noise of a sum of millions of durations).
_TICK_SLACK = 1e-9
#: A junction whose turn alone would round the path by at most this fraction of its tolerance is a point on a
#: line, not a corner (:func:`_corner_limits`).
_OWN_TURN = 0.01


@dataclass(slots=True)
class Reference:
    """The planned reference trajectory, sampled at the servo period.

    Attributes
    ----------
    period_s : float
        Servo period, s.
    pos_mm : ndarray (N, 3)
        Reference position r(t) of X, Y, Z, mm (consistent frame of the program).
    move : ndarray (N,) int32
        Index of the move the reference is on (-1 while standing before the first move).
    command : ndarray (N,) int32
        G01 command index k active at each sample, -1 on other moves.
    line : ndarray (N,) int32
        Source line of the active move (0 when none).
    move_speed_mm_s : ndarray (M,)
        Speed the ideal interpolator used per move (the slowest of its zones), mm/s.
    """

    period_s: float
    pos_mm: NDArray[np.float64]
    move: NDArray[np.int32]
    command: NDArray[np.int32]
    line: NDArray[np.int32]
    move_speed_mm_s: NDArray[np.float64]

    @property
    def n_samples(self) -> int:
        return int(self.pos_mm.shape[0])

    @property
    def t_s(self) -> NDArray[np.float64]:
        """Sample times, s."""
        return np.arange(self.n_samples) * self.period_s

    @property
    def duration_s(self) -> float:
        """Planned cycle time, s."""
        return max(self.n_samples - 1, 0) * self.period_s


@dataclass(frozen=True, slots=True)
class _Geometry:
    """Per-move geometry computed once per plan: start and end tangents, arc sweeps."""

    t_in: NDArray[np.float64]
    t_out: NDArray[np.float64]
    sweep: NDArray[np.float64]


#: ``planner.path_control`` -> the ``blend_tol_mm`` of moves the program sets no path control for.
_PROFILE_PATH_CONTROL = {"g64": BLEND_NO_BOUND, "g61": BLEND_EXACT_PATH, "g61.1": BLEND_EXACT_STOP}


#: ``planner.profile`` values: ilcnc's filter planner in three shapes, and LinuxCNC 2.9's planner (:mod:`ilcnc.vcnc.plan_tp`).
PLANNER_PROFILES = ("seven_phase", "cubic", "constant_feed", "linuxcnc")


def _plan_linuxcnc(moves: MoveTable, limits: PlanLimits, period_s: float, corner_tolerance_mm: float,
                   trailing_dwell_s: float = 0.0) -> Reference:
    """:func:`ilcnc.vcnc.plan_tp.plan_linuxcnc` as a :class:`Reference`."""
    from ilcnc.vcnc.plan_tp import plan_linuxcnc

    pos, mv, speed = plan_linuxcnc(moves, limits, period_s, corner_tolerance_mm=corner_tolerance_mm,
                                   trailing_dwell_s=trailing_dwell_s)
    on = mv >= 0
    safe = np.maximum(mv, 0)
    return Reference(period_s, pos, mv, np.where(on, moves.command[safe], -1).astype(np.int32),
                     np.where(on, moves.line[safe], 0).astype(np.int32), speed)


def plan_program(program: object, profile: MachineProfile, *, mode: str | None = None) -> Reference:
    """Plan a :class:`~ilcnc.program.model.Program` with a machine profile.

    Moves whose program sets no path control take the profile's ``planner.path_control``: ``tolerance``
    (``corner_tolerance_mm``) or the mode of ``G64`` without P, ``G61``, ``G61.1`` as if programmed.
    """
    return plan_moves(
        profile_moves(program, profile),
        PlanLimits.from_profile(profile),
        period_s=profile.machine.servo_period_s,
        mode=mode or profile.planner.profile,
        corner_tolerance_mm=profile.planner.corner_tolerance_mm,
        jerk_time_constant_s=profile.planner.jerk_time_constant_s,
        in_position_s=profile.planner.in_position_s,
        trailing_dwell_s=_trailing_dwell_s(program),
    )


def _trailing_dwell_s(program: object) -> float:
    """The program's dwell after its last move, s (:attr:`ilcnc.program.model.Program.trailing_dwell_s`)."""
    return float(getattr(program, "trailing_dwell_s", 0.0))


def plan_moves(
    moves: MoveTable,
    limits: PlanLimits,
    *,
    period_s: float,
    mode: str = "seven_phase",
    corner_tolerance_mm: float = 0.01,
    jerk_time_constant_s: float = 0.01,
    in_position_s: float = IN_POSITION_S,
    max_passes: int = 12,
    trailing_dwell_s: float = 0.0,
) -> Reference:
    """Plan the reference trajectory of a move table.

    Parameters
    ----------
    moves : MoveTable
        The program's moves.
    limits : PlanLimits
        Axis limits (mm, s).
    period_s : float
        Servo period, s.
    mode : {"seven_phase", "cubic", "constant_feed", "linuxcnc"}
        Profile kind (see the module docstring; ``linuxcnc``: :mod:`ilcnc.vcnc.plan_tp`, which takes no jerk limit,
        filter or in-position wait).
    corner_tolerance_mm : float
        Largest distance the planned path may cut a corner or shrink an arc, mm.
    jerk_time_constant_s : float
        Third filter length of the ``cubic`` profile, s.
    in_position_s : float
        Stand-still between a rapid group and a feed group (in-position check), s.
    max_passes : int
        Re-planning passes allowed to remove limit violations per group.
    trailing_dwell_s : float
        Dwell after the last move, s (``Program.trailing_dwell_s``; the dwells before moves are ``moves.dwell_s``):
        module docstring, "Dwells".
    """
    return _plan(moves, limits, period_s, mode, corner_tolerance_mm, jerk_time_constant_s, in_position_s, max_passes,
                 kernel=HAVE_NUMBA, trailing_dwell_s=trailing_dwell_s)


def _plan(moves: MoveTable, limits: PlanLimits, period_s: float, mode: str, corner_tolerance_mm: float,
          jerk_time_constant_s: float, in_position_s: float, max_passes: int, *, kernel: bool,
          trailing_dwell_s: float = 0.0) -> Reference:
    """:func:`plan_moves`; ``kernel=False`` takes the numpy path (the reference the compiled kernel is checked against).

    Every group is written straight into the reference's position array, sized from the speeds before
    any re-planning plus some slack (a group re-planned slower grows; past the slack the array is
    copied into a larger one), so the largest array of the plan is normally written once and never
    copied. The move, command and line columns are expanded from run lengths (the interpolator visits
    the moves in order).
    """
    if mode not in PLANNER_PROFILES:
        raise ValueError(f"unknown planner profile {mode!r}")
    if mode == "linuxcnc":
        return _plan_linuxcnc(moves, limits, period_s, corner_tolerance_mm, trailing_dwell_s)
    m = len(moves)
    if m == 0:
        speed = nominal_speed_mm_s(moves, move_lengths_mm(moves), limits)
        return Reference(period_s, np.zeros((0, 3)), np.zeros(0, np.int32), np.zeros(0, np.int32),
                         np.zeros(0, np.int32), speed)
    length, speed, geo, setups = _group_setups(moves, limits, period_s, mode, corner_tolerance_mm,
                                               jerk_time_constant_s)
    # stand still between groups: an in-position check after rapids (and before them) as CNCs
    # do, so the drives settle before the next group; it also keeps the finite differences of one
    # group's end and the next one's start apart; no stand-still after the last group. A dwell adds its
    # samples to the stand-still where it sits (_stand_stills)
    lead, stills = _stand_stills(moves, setups, max(_HOLD_SAMPLES, math.ceil(in_position_s / period_s)), period_s,
                                 trailing_dwell_s)
    est = 1 + lead + sum(g.first_size for g in setups) + sum(stills)
    # slack for groups re-planned slower (pages never written are never mapped: it costs no memory)
    buf = np.empty((est + est // 64 + _SLACK_ROWS, 3))
    buf[0] = moves.start_mm[0]
    run_move: list[NDArray[np.int64]] = [np.array([-1], dtype=np.int64)]
    run_count: list[NDArray[np.int64]] = [np.full(1, 1 + lead, dtype=np.int64)]
    buf[1:1 + lead] = buf[0]
    final_speed = speed.copy()
    at = 1 + lead
    for gi, g in enumerate(setups):
        plan_group = _plan_group_kernel if kernel and compiled_for(g.first_size) else _plan_group_numpy
        buf, n_out, moves_g, counts_g, used = plan_group(moves, geo, g, length, limits, period_s, mode, max_passes,
                                                         buf, at)
        final_speed[g.idx] = used
        run_move.append(moves_g)
        run_count.append(counts_g)
        at += n_out
        hold = stills[gi]
        if hold:
            buf = _reserve(buf, at + hold)
            buf[at:at + hold] = buf[at - 1]
            run_move.append(moves_g[-1:])
            run_count.append(np.array([hold], dtype=np.int64))
            at += hold
    pos = buf[:at]
    rm = np.concatenate(run_move)
    rc = np.concatenate(run_count)
    on = rm >= 0
    cols = (rm.astype(np.int32), np.where(on, moves.command[np.maximum(rm, 0)], -1).astype(np.int32),
            np.where(on, moves.line[np.maximum(rm, 0)], 0).astype(np.int32))
    if kernel:
        mv, cmd, line = (np.empty(at, dtype=np.int32) for _ in range(3))
        _expand_runs(rc, *cols, mv, cmd, line)
    else:
        mv, cmd, line = (np.repeat(c, rc) for c in cols)
    return Reference(period_s, pos, mv, cmd, line, final_speed)


@dataclass(slots=True)
class ReferenceChunk:
    """Consecutive samples of a planned reference (:func:`plan_chunks`).

    Attributes
    ----------
    first_sample : int
        Index of the chunk's first sample in the whole reference (sample 0 at t = 0).
    period_s : float
        Servo period, s.
    pos_mm, move, command, line
        The columns of :class:`Reference` for these samples.
    """

    first_sample: int
    period_s: float
    pos_mm: NDArray[np.float64]
    move: NDArray[np.int32]
    command: NDArray[np.int32]
    line: NDArray[np.int32]

    @property
    def n_samples(self) -> int:
        return int(self.pos_mm.shape[0])


#: Samples per chunk of :func:`plan_chunks` by default (~40 MB): its arrays (<= 6 MB) are re-used from the heap,
#: where 2 M samples (48 MB arrays) were mapped and zeroed fresh for each chunk (issue 24; docs/learning.md).
DEFAULT_CHUNK_SAMPLES = 262_144


def plan_chunks(program: object, profile: MachineProfile, *, chunk_samples: int = DEFAULT_CHUNK_SAMPLES,
                mode: str | None = None) -> Iterator[ReferenceChunk]:
    """Plan a program like :func:`plan_program`, handing the reference out in chunks of ``chunk_samples``.

    The samples are those of :func:`plan_program`, bit for bit, but the whole reference is never held:
    a 45-hour program has 162 M samples (5.8 GB of positions alone). A group of moves longer than a
    chunk is planned twice: its passes first run without writing anything (they check the limits and
    re-plan slower where needed), then the final pass runs again range by range, carrying its filter
    state from one range to the next (:func:`group_range`). Without numba the numpy path plans each
    group whole. ``planner.profile: linuxcnc`` plans the whole program at once (its corners and look-ahead
    are sequential; stellabee1's 3.4 M samples in 1.5 s) and hands that reference out in chunks.
    """
    chunk = max(int(chunk_samples), BLOCK_SAMPLES)
    chunk -= chunk % BLOCK_SAMPLES
    moves, pieces = _profile_pieces(program, profile, chunk, mode)
    period_s = profile.machine.servo_period_s
    buf_pos = np.empty((chunk, 3))
    buf_mv = np.empty(chunk, dtype=np.int32)
    fill = 0
    first = 0
    for pos, mv in pieces:
        at = 0
        while at < pos.shape[0]:
            take = min(chunk - fill, pos.shape[0] - at)
            buf_pos[fill:fill + take] = pos[at:at + take]
            buf_mv[fill:fill + take] = mv[at:at + take]
            fill += take
            at += take
            if fill == chunk:
                yield _chunk(moves, first, period_s, buf_pos, buf_mv, fill)
                first += fill
                fill = 0
    if fill:
        yield _chunk(moves, first, period_s, buf_pos, buf_mv, fill)


def _profile_pieces(program: object, profile: MachineProfile, chunk: int, mode: str | None
                    ) -> tuple[MoveTable, Iterator[tuple[NDArray[np.float64], NDArray[np.int32]]]]:
    """The moves :func:`plan_chunks` plans and the pieces (positions, moves) of their reference, in order."""
    moves = profile_moves(program, profile)
    mode = mode or profile.planner.profile
    if mode not in PLANNER_PROFILES:
        raise ValueError(f"unknown planner profile {mode!r}")
    if mode == "linuxcnc":
        # planned whole (its look-ahead and corners are sequential), handed out as one piece
        ref = _plan_linuxcnc(moves, PlanLimits.from_profile(profile), profile.machine.servo_period_s,
                             profile.planner.corner_tolerance_mm, _trailing_dwell_s(program))
        return moves, iter([(ref.pos_mm, ref.move)])
    pieces = _plan_pieces(moves, PlanLimits.from_profile(profile), profile.machine.servo_period_s, mode,
                          profile.planner.corner_tolerance_mm, profile.planner.jerk_time_constant_s,
                          profile.planner.in_position_s, 12, chunk, _trailing_dwell_s(program))
    return moves, pieces


def planned_duration_s(program: object, profile: MachineProfile) -> float:
    """Planned cycle time of a program, s: :func:`plan_program`'s ``duration_s`` without holding its samples."""
    return planned_move_times_s(program, profile)[1]


def planned_move_times_s(program: object, profile: MachineProfile) -> tuple[NDArray[np.float64], float]:
    """Each move's planned time (M,) and the cycle time, s, counted from :func:`plan_chunks`' pieces as they are
    planned (no chunk is assembled, no sample held; 2 M-sample pieces: it only counts)."""
    moves, pieces = _profile_pieces(program, profile, 1953 * BLOCK_SAMPLES, None)
    counts, n = np.zeros(len(moves), np.int64), 0
    for pos, mv in pieces:
        n += pos.shape[0]
        counts += np.bincount(mv[mv >= 0], minlength=len(moves))[:len(moves)]
    return counts * profile.machine.servo_period_s, max(n - 1, 0) * profile.machine.servo_period_s


def _chunk(moves: MoveTable, first: int, period_s: float, pos: NDArray[np.float64], mv: NDArray[np.int32],
           n: int) -> ReferenceChunk:
    m = mv[:n].copy()
    on = m >= 0
    safe = np.maximum(m, 0)
    return ReferenceChunk(first, period_s, pos[:n].copy(), m,
                          np.where(on, moves.command[safe], -1).astype(np.int32),
                          np.where(on, moves.line[safe], 0).astype(np.int32))


def profile_moves(program: object, profile: MachineProfile) -> MoveTable:
    """The program's moves with the profile's ``planner.path_control`` where the program sets none (refused
    first when its motion would take longer than a virtual run may: :func:`check_run_length`)."""
    moves = program.moves  # type: ignore[attr-defined]
    check_run_length(program, moves, profile)
    default = _PROFILE_PATH_CONTROL.get(profile.planner.path_control)
    if default is not None:
        blend = moves.blend_tol_mm
        moves = dataclasses.replace(moves, blend_tol_mm=np.where(np.isnan(blend), default, blend))
    return moves


def corner_zones_mm(program: object, profile: MachineProfile) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Length of the slow zone the planner gives each move at its start and at its end, mm (first pass).

    The ideal interpolator runs a zone of ``v_corner * span`` before and after a corner at the corner
    speed (:func:`ilcnc.vcnc.plan_zones.zone_pieces`); the filters then round the corner within it. A point inserted on a move
    farther from the corner than that zone (and, where the program sets the tolerance, farther than four
    tolerances: the quarter-move bound) leaves the plan as it was: the zone stays inside the piece next
    to the corner, and the new junction is straight, so it has no zone. Re-planning passes that lower
    speeds where a limit was hit can still move zones: :mod:`ilcnc.learning.refine` checks the refined plan.
    (0, 0) for every move under ``planner.profile: linuxcnc``, which has no such zones.
    """
    moves = profile_moves(program, profile)
    m = len(moves)
    z_in, z_out = np.zeros(m), np.zeros(m)
    if m == 0 or profile.planner.profile == "linuxcnc":
        return z_in, z_out
    pl = profile.planner
    _length, _speed, _geo, setups = _group_setups(moves, PlanLimits.from_profile(profile),
                                                  profile.machine.servo_period_s, pl.profile, pl.corner_tolerance_mm,
                                                  pl.jerk_time_constant_s)
    for g in setups:
        _v_in, _v_out, z_in[g.idx], z_out[g.idx] = slow_zones(g.v, g.vj, g.span_s)
    return z_in, z_out


def vertex_tolerances_mm(program: object, profile: MachineProfile) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The corner tolerance the planner rounds each end point of the program's moves within, mm, (M + 1,).

    Entry ``e`` is the end of move ``e - 1`` (the start of move ``e``): the junction rule of the plan
    (:func:`ilcnc.vcnc.plan_corners.junction_tolerances` on the collinear chains), 0 where the axes stop, NaN where
    two moves of one group do not meet (a group's ends, zero-length moves). The second array is the same without
    LinuxCNC's quarter-move bound on a programmed tolerance.
    """
    moves = profile_moves(program, profile)
    m = len(moves)
    tol, free = np.full(m + 1, np.nan), np.full(m + 1, np.nan)
    length = move_lengths_mm(moves)
    hold_s = _stand_still_s(moves, length)
    active = (length > _EPS) | (hold_s > 0.0)
    geo = _Geometry(*move_directions(moves), arc_sweep_rad(moves))
    default = profile.planner.corner_tolerance_mm
    for g0, g1 in _groups(moves.kind, active, moves.dwell_s):
        idx = np.arange(g0, g1)
        idx = idx[active[idx]]
        if idx.size < 2:
            continue
        hold = hold_s[idx]
        seg_len = np.where(hold > 0.0, np.inf, length[idx])
        before, after = _chain_lengths(seg_len, _straight_joins(moves, geo, idx, hold))
        t, stop = junction_tolerances(moves.blend_tol_mm[idx], default, seg_len, before, after)
        t_free, _stop = junction_tolerances(moves.blend_tol_mm[idx], default, np.full(idx.size, np.inf))
        tol[idx[:-1] + 1] = np.where(stop, 0.0, t)
        free[idx[:-1] + 1] = np.where(stop, 0.0, t_free)
    return tol, free


def _group_setups(moves: MoveTable, limits: PlanLimits, period_s: float, mode: str, corner_tolerance_mm: float,
                  jerk_time_constant_s: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], _Geometry, list[_GroupSetup]]:
    """Move lengths, nominal speeds, geometry and the setup of every group of a move table (first pass)."""
    length = move_lengths_mm(moves)
    speed = nominal_speed_mm_s(moves, length, limits)
    hold_s = _stand_still_s(moves, length)
    active = (length > _EPS) | (hold_s > 0.0)
    geo = _Geometry(*move_directions(moves), arc_sweep_rad(moves))
    setups = []
    for g0, g1 in _groups(moves.kind, active, moves.dwell_s):
        idx = np.arange(g0, g1)
        idx = idx[active[idx]]
        if idx.size:
            setups.append(_group_setup(moves, geo, idx, length, speed, hold_s, limits, period_s, mode,
                                       corner_tolerance_mm, jerk_time_constant_s))
    return length, speed, geo, setups


def _runs_to_samples(run_move: NDArray[np.int64], run_count: NDArray[np.int64]) -> NDArray[np.int32]:
    return np.repeat(run_move.astype(np.int32), run_count)


def _plan_pieces(moves: MoveTable, limits: PlanLimits, period_s: float, mode: str, corner_tolerance_mm: float,
                 jerk_time_constant_s: float, in_position_s: float, max_passes: int, chunk: int,
                 trailing_dwell_s: float = 0.0) -> Iterator[tuple[NDArray[np.float64], NDArray[np.int32]]]:
    """The samples of :func:`_plan` as consecutive pieces ``(pos_mm, move)`` of at most about ``chunk`` rows
    (a group shorter than a chunk comes whole)."""
    m = len(moves)
    if m == 0:
        return
    length, _speed, geo, setups = _group_setups(moves, limits, period_s, mode, corner_tolerance_mm,
                                                jerk_time_constant_s)
    lead, stills = _stand_stills(moves, setups, max(_HOLD_SAMPLES, math.ceil(in_position_s / period_s)), period_s,
                                 trailing_dwell_s)
    yield np.repeat(moves.start_mm[0][None, :], 1 + lead, axis=0), np.full(1 + lead, -1, dtype=np.int32)
    for gi, g in enumerate(setups):
        compiled = compiled_for(g.first_size)  # a small group in a Python run: the numpy path (ilcnc._jit)
        if compiled and g.first_size > chunk:
            last_row, last_move = yield from _group_in_ranges(moves, geo, g, length, limits, period_s, mode,
                                                              max_passes, chunk)
        else:
            plan_group = _plan_group_kernel if compiled else _plan_group_numpy
            buf, n_out, moves_g, counts_g, _used = plan_group(moves, geo, g, length, limits, period_s, mode,
                                                              max_passes, np.empty((g.first_size + 16, 3)), 0)
            last_row, last_move = buf[n_out - 1].copy(), int(moves_g[-1])
            yield buf[:n_out], _runs_to_samples(moves_g, counts_g)
        if stills[gi]:  # the stand-still after the group (see _plan)
            yield np.repeat(last_row[None, :], stills[gi], axis=0), np.full(stills[gi], last_move, dtype=np.int32)


@dataclass(slots=True)
class _GroupPass:
    """A group's last re-planning pass (:func:`_replan_group`): the kernel's inputs and what the pass found."""

    gs: NDArray[np.float64]
    ge: NDArray[np.float64]
    arcs: tuple[NDArray[Any], ...]
    start: NDArray[np.float64]
    lens: NDArray[np.int64]
    extra: int
    pieces: Pieces
    n: int
    t_end: NDArray[np.float64]
    total: float
    counts: NDArray[np.int64]
    scale: NDArray[np.float64]
    thr_a: NDArray[np.float64]
    thr_j: NDArray[np.float64]

    def move_runs(self, idx: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Run lengths of the move column: the start sample and the filter delay are on the first move, the
        filters' tail on the move of the last ideal sample; the start sample itself is not returned."""
        counts = self.counts.copy()
        delay = self.extra // 2
        last = int(np.flatnonzero(counts)[-1])
        counts[0] += delay
        counts[last] += self.extra - delay
        return idx[: last + 1].astype(np.int64), counts[: last + 1]


def _replan_group(moves: MoveTable, geo: _Geometry, g: _GroupSetup, length: NDArray[np.float64], limits: PlanLimits,
                  period_s: float, mode: str, max_passes: int,
                  rows_for: Callable[[int], NDArray[np.float64]]) -> _GroupPass:
    """Run a group through the compiled kernel (:func:`group_kernel`) until no axis limit is violated.

    Each pass writes its ``n_out`` rows into ``rows_for(n_out)`` (an empty array: check only, write nothing)
    and, where a limit is exceeded, lowers the speed of every move inside the filter window of a violating
    sample (sample s of the ideal signal is on group move searchsorted(cum, s - 1, "right"); sample 0 is the
    start) by 20 % for the next pass.
    """
    idx, v, vj, lengths = g.idx, g.v, g.vj, g.lengths
    gs = np.ascontiguousarray(moves.start_mm[idx])
    ge = np.ascontiguousarray(moves.end_mm[idx])
    arcs = arc_table(moves, idx, geo.sweep)
    start = np.ascontiguousarray(moves.start_mm[idx[0]], dtype=np.float64)
    lens = np.array(lengths, dtype=np.int64)
    check = mode != "constant_feed"
    thr_a = np.asarray(limits.acceleration_mm_s2 * (1 + _FD_NOISE), dtype=np.float64)
    thr_j = np.asarray(limits.jerk_mm_s3 * (1 + _FD_NOISE), dtype=np.float64)
    extra = int(lens.sum() - lens.shape[0])
    scale = np.ones(idx.shape[0])
    pieces = g.first
    p2, p3 = float(period_s**2), float(period_s**3)
    for _ in range(max_passes):
        _plen, pspd, owner, offs, dur, mlen = pieces
        n, t_end, total = _ideal_samples(dur, period_s)
        counts = np.zeros(idx.shape[0], dtype=np.int64)
        bad = group_kernel(t_end, dur, pspd, owner, offs, mlen, n, float(period_s), total, gs, ge, *arcs, start, lens,
                            rows_for(n + extra), counts, check, thr_a, thr_j, p2, p3)
        if not check or bad.size == 0:
            break
        cum = np.cumsum(counts)
        lo_s, hi_s = _violation_window(bad, extra + 3, n + 1)
        lo_g, hi_g = (np.where(x > 0, np.searchsorted(cum, x - 1, side="right"), 0) for x in (lo_s, hi_s))
        scale[_slower_moves(lo_g, hi_g, idx.shape[0], g.chain)] *= 0.8
        pieces = zone_pieces(length[idx], v * scale, vj, g.span_s, g.hold, g.chain)
    return _GroupPass(gs, ge, arcs, start, lens, extra, pieces, n, t_end, total, counts, scale, thr_a, thr_j)


def _group_in_ranges(moves: MoveTable, geo: _Geometry, g: _GroupSetup, length: NDArray[np.float64],
                     limits: PlanLimits, period_s: float, mode: str, max_passes: int, chunk: int
                     ) -> Generator[tuple[NDArray[np.float64], NDArray[np.int32]], None, tuple[NDArray[np.float64], int]]:
    """A group longer than a chunk: :func:`_plan_group_kernel`'s passes without writing, then the final
    pass again range by range (``chunk`` rows, a multiple of ``BLOCK_SAMPLES``). Returns the group's last row
    and move (the stand-still after it)."""
    no_rows = np.empty((0, 3))
    gp = _replan_group(moves, geo, g, length, limits, period_s, mode, max_passes, lambda _n: no_rows)
    _plen, pspd, owner, offs, dur, mlen = gp.pieces
    run_move, run_count = gp.move_runs(g.idx)
    cum_end = np.cumsum(run_count)
    n_out = gp.n + gp.extra
    st = group_state(gp.start, gp.lens)
    scratch = np.zeros(g.idx.shape[0], dtype=np.int64)
    rows = np.empty((chunk, 3))
    bad = np.empty(16, dtype=np.int64)
    p2, p3 = float(period_s**2), float(period_s**3)
    for k0 in range(0, n_out, chunk):
        k1 = min(k0 + chunk, n_out)
        group_range(k0, k1, st, gp.t_end, dur, pspd, owner, offs, mlen, gp.n, float(period_s), gp.total, gp.gs, gp.ge,
                     *gp.arcs, gp.start, gp.lens, rows, True, scratch, False, gp.thr_a, gp.thr_j, p2, p3, bad, 0)
        # the move of output samples k0..k1-1: runs cut at the range
        r0 = int(np.searchsorted(cum_end, k0, side="right"))
        r1 = int(np.searchsorted(cum_end, k1 - 1, side="right"))
        cnt = run_count[r0:r1 + 1].copy()
        cnt[0] = min(int(cum_end[r0]), k1) - k0
        if r1 > r0:
            cnt[-1] = k1 - int(cum_end[r1 - 1])
        yield rows[: k1 - k0], _runs_to_samples(run_move[r0:r1 + 1], cnt)
    return rows[(n_out - 1) % chunk].copy(), int(run_move[-1])


@njit(cache=True, nogil=True)
def _expand_runs(count, mv_of, cmd_of, line_of, mv, cmd, line):  # pragma: no cover - compiled
    """``np.repeat`` of three run tables at once (numpy's repeat copies element by element, three times)."""
    k = 0
    for r in range(count.shape[0]):
        e = k + count[r]
        mv[k:e] = mv_of[r]
        cmd[k:e] = cmd_of[r]
        line[k:e] = line_of[r]
        k = e


def _reserve(buf: NDArray[np.float64], size: int) -> NDArray[np.float64]:
    """``buf`` with room for ``size`` rows (a larger copy when it has fewer)."""
    if size <= buf.shape[0]:
        return buf
    grown = np.empty((max(size, buf.shape[0] + buf.shape[0] // 4), 3))
    grown[:buf.shape[0]] = buf
    return grown


def _stand_stills(moves: MoveTable, setups: list[_GroupSetup], hold: int, period_s: float, trailing_dwell_s: float
                  ) -> tuple[int, list[int]]:
    """Samples the reference stands still before the first group and after each group (module docstring, "Dwells").

    After a group: ``hold`` (the in-position wait) before the next group, plus the dwells between the two
    (``moves.dwell_s`` of the moves after the first move of this group up to the first move of the next,
    :func:`ilcnc.vcnc.plan_base.dwell_samples`); after the last group nothing, or ``hold`` plus the dwells
    after it and ``trailing_dwell_s`` when they last a sample or more. Before the first group: its dwells alone
    (the machine is at rest). Without dwells: (0, [hold, ..., hold, 0]) as before dwells were modelled.
    """
    n = len(setups)
    if not np.any(moves.dwell_s > 0.0) and not dwell_samples(trailing_dwell_s, period_s):
        return 0, [hold] * (n - 1) + [0] * min(n, 1)
    cum = np.concatenate(([0.0], np.cumsum(moves.dwell_s)))
    firsts = [int(g.idx[0]) + 1 for g in setups]  # the dwells up to a group's first move are before it
    bounds = np.array([0, *firsts, len(moves)])
    spans = np.diff(cum[bounds])
    spans[-1] += trailing_dwell_s
    wait = dwell_samples(spans, period_s)
    if n == 0:
        return int(wait.sum()), []
    stills = [hold + int(w) for w in wait[1:n]] + [hold + int(wait[n]) if wait[n] else 0]
    return int(wait[0]), stills


def _groups(kind: NDArray[np.int8], active: NDArray[np.bool_], dwell_s: NDArray[np.float64] | None = None
            ) -> list[tuple[int, int]]:
    """Runs of moves planned together: rapids apart from feed moves, and a move after a dwell (``dwell_s > 0``)
    starts a run (the machine stops between)."""
    rapid = kind == MOVE_RAPID
    cut = rapid[1:] != rapid[:-1]
    if dwell_s is not None:
        cut |= dwell_s[1:] > 0.0
    edges = np.flatnonzero(cut) + 1
    bounds = np.concatenate(([0], edges, [kind.shape[0]]))
    return [(int(a), int(b)) for a, b in itertools.pairwise(bounds) if b > a]


def _stand_still_s(moves: MoveTable, length: NDArray[np.float64]) -> NDArray[np.float64]:
    """Stand-still of every move, s: the programmed time of a zero-length inverse-time (G93) block, else 0."""
    bt = moves.block_time_s
    with np.errstate(invalid="ignore"):
        still = (length <= _EPS) & np.isfinite(bt) & (bt > 0.0) & (moves.kind != MOVE_RAPID)
    return np.where(still, bt, 0.0)


def _filter_lengths(mode: str, vmax_axis: NDArray[np.float64], limits: PlanLimits, period_s: float,
                    jerk_time_constant_s: float) -> tuple[int, ...]:
    """Moving-average lengths (samples) for a group whose axes reach ``vmax_axis`` (mm/s)."""
    if mode == "constant_feed":
        return ()
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.nanmax(np.where(np.isfinite(limits.acceleration_mm_s2), vmax_axis / limits.acceleration_mm_s2, 0.0))
    n1 = max(1, math.ceil(t1 / period_s - 1e-9))
    acc_used = vmax_axis / (n1 * period_s)
    with np.errstate(divide="ignore", invalid="ignore"):
        t2 = np.nanmax(np.where(np.isfinite(limits.jerk_mm_s3), acc_used / limits.jerk_mm_s3, 0.0))
    n2 = max(1, math.ceil(t2 / period_s - 1e-9))
    lengths = [n1, n2]
    if mode == "cubic":
        lengths.append(max(1, math.ceil(jerk_time_constant_s / period_s - 1e-9)))
    return tuple(n for n in lengths if n > 1)


def _smooth_increments(d: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    """Moving average of ``n`` samples over per-tick increments (length grows by ``n - 1``).

    Filtering increments instead of positions keeps every cumulative sum at
    the scale of a position (not of a position times the sample count), so the
    third differences stay at float noise (~1e-5 of a jerk limit at 1 ms).
    """
    if n <= 1:
        return d
    c = np.cumsum(np.concatenate([d, np.zeros((n - 1, *d.shape[1:]))]), axis=0)
    out = c.copy()
    out[n:] -= c[:-n]
    return out / n


def _sample_ideal(moves: MoveTable, geo: _Geometry, idx: NDArray[np.int64], pieces: Pieces, period_s: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Positions of the ideal interpolator at every servo tick of a group, and the move index there."""
    plen, pspd, owner, offs, dur, mlen = pieces
    n, t_end, total = _ideal_samples(dur, period_s)
    t = np.minimum(np.arange(1, n + 1) * period_s, total)
    t[-1] = total
    k = np.minimum(np.searchsorted(t_end, t - 1e-12), plen.shape[0] - 1)
    s_move = offs[k] + (t - (t_end[k] - dur[k])) * pspd[k]  # arc length within the move
    frac = np.clip(s_move / mlen[owner[k]], 0.0, 1.0)
    mv = idx[owner[k]]
    return _position_on_moves(moves, mv, frac, geo.sweep), mv


def _position_on_moves(moves: MoveTable, mv: NDArray[np.int64], frac: NDArray[np.float64],
                       sweep_all: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Point at fraction ``frac`` (by length) along move ``mv`` (lines and arcs)."""
    s = moves.start_mm[mv]
    e = moves.end_mm[mv]
    pos = s + (e - s) * frac[:, None]
    is_arc = moves.kind[mv] >= MOVE_ARC_CW
    if is_arc.any():
        if sweep_all is None:
            sweep_all = arc_sweep_rad(moves)
        for plane, (a1, a2, _lin) in PLANE_AXES.items():
            sel = np.flatnonzero(is_arc & (moves.plane[mv] == plane))
            if sel.size == 0:
                continue
            m_sel = mv[sel]
            c = moves.center_mm[m_sel]
            st = s[sel]
            en = e[sel]
            r = np.hypot(st[:, a1] - c[:, a1], st[:, a2] - c[:, a2])
            # a spiral where the end misses the circle through the start (within the control's tolerance):
            # the radius changes in proportion to the angle, as LinuxCNC runs it
            r = r + (np.hypot(en[:, a1] - c[:, a1], en[:, a2] - c[:, a2]) - r) * frac[sel]
            t0 = np.arctan2(st[:, a2] - c[:, a2], st[:, a1] - c[:, a1])
            sign = np.where(moves.kind[m_sel] == MOVE_ARC_CW, -1.0, 1.0)
            ang = t0 + sign * sweep_all[m_sel] * frac[sel]
            pos[sel, a1] = c[:, a1] + r * np.cos(ang)
            pos[sel, a2] = c[:, a2] + r * np.sin(ang)
            # the linear axis of a helix is already interpolated by frac
    return pos


#: How far, at most, the point between two straight moves may lie from the line through their far ends for
#: the two to be one line, mm: 0.1 µm, a tenth of a 1 µm machine resolution. Refinement writes the points it
#: inserts on a line exactly on it where the decimal grid allows, else within 0.05 µm of it
#: (:data:`ilcnc.program.insert.POINT_TOLERANCE_MM`); a learned correction moves a point by a resolution step.
_COLLINEAR_MM = 1e-4


def _straight_joins(moves: MoveTable, geo: _Geometry, idx: NDArray[np.int64], hold: NDArray[np.float64]
                    ) -> NDArray[np.bool_]:
    """Per junction of a group's moves (n - 1): two straight moves (no arc, no stand-still) joined without a
    turn, so that they are one line."""
    if idx.shape[0] < 2:
        return np.zeros(0, dtype=np.bool_)
    du = np.linalg.norm(geo.t_in[idx[1:]] - geo.t_out[idx[:-1]], axis=1)
    seg = np.linalg.norm(moves.end_mm[idx] - moves.start_mm[idx], axis=1)
    la, lb = seg[:-1], seg[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        offset = du * np.where(la + lb > 0, la * lb / (la + lb), 0.0)  # the point's distance from the line
    arc = moves.kind[idx] >= MOVE_ARC_CW
    still = hold > 0.0
    return (offset <= _COLLINEAR_MM) & ~arc[:-1] & ~arc[1:] & ~still[:-1] & ~still[1:]


def _chain_ids(join: NDArray[np.bool_]) -> NDArray[np.int64] | None:
    """Chain id of each move: a new chain starts where the junction before it is not a join (None: no join)."""
    if not join.any():
        return None
    return np.concatenate(([0], np.cumsum(~join)))


def _chain_lengths(length: NDArray[np.float64], join: NDArray[np.bool_]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per junction (n - 1): the length of the chain of collinear straight moves ending before it and of the
    one starting after it, mm (a move's own length where its neighbours are not collinear with it)."""
    chain = _chain_ids(join)
    if chain is None:
        return length[:-1], length[1:]
    total = np.bincount(chain, weights=length)
    return total[chain[:-1]], total[chain[1:]]


def _corner_limits(moves: MoveTable, idx: NDArray[np.int64], length: NDArray[np.float64],
                   t_in: NDArray[np.float64], t_out: NDArray[np.float64], limits: PlanLimits, default_tol_mm: float,
                   lengths: tuple[int, ...], period_s: float, v_nom: NDArray[np.float64],
                   still: NDArray[np.bool_], join: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Speed limits at each junction inside a group (between idx[i] and idx[i+1]) and per move (arcs).

    The corner tolerances come from the moves' path control (``moves.blend_tol_mm``) and
    ``default_tol_mm``, the profile's tolerance, which also bounds the shrinking of arcs in the exact
    and unbounded modes; ``still`` marks the group's stand-still moves (zero-length inverse-time
    blocks), which take the tangents of the moves around them; ``join`` the junctions that join two
    straight moves into one line (:func:`_straight_joins`).

    Returns
    -------
    v_junction : ndarray (len(idx) - 1,)
        Largest speed through each junction, mm/s.
    v_move : ndarray (len(idx),)
        Largest speed on each move from its own curvature, mm/s.
    """
    filt_s = tuple(k * period_s for k in lengths)
    t1 = max(filt_s) if filt_s else 0.0
    var_t2 = sum(t * t for t in filt_s) / 12.0  # variance of the summed uniform kernels, s^2
    acc_min = float(np.min(limits.acceleration_mm_s2))
    jerk_min = float(np.min(limits.jerk_mm_s3))
    n = idx.shape[0]
    blend_g = moves.blend_tol_mm[idx]
    v_move = np.full(n, np.inf)
    # arcs: centripetal acceleration and jerk, and shrinkage by the filters v^2 var / (2 R), bounded by the
    # move's tolerance (the profile's in the exact modes and without a bound: LinuxCNC follows arcs exactly)
    is_arc = moves.kind[idx] >= MOVE_ARC_CW
    if is_arc.any():
        mi = idx[is_arc]
        r = np.empty(mi.shape[0])
        for plane, (a1, a2, _lin) in PLANE_AXES.items():
            sel = moves.plane[mi] == plane
            if sel.any():
                s, c = moves.start_mm[mi[sel]], moves.center_mm[mi[sel]]
                r[sel] = np.hypot(s[:, a1] - c[:, a1], s[:, a2] - c[:, a2])
        r = np.maximum(r, _EPS)
        lim = np.sqrt(acc_min * r)
        lim = np.minimum(lim, np.cbrt(jerk_min * r * r))
        if var_t2 > 0:
            t_arc = blend_g[is_arc]
            with np.errstate(invalid="ignore"):
                t_arc = np.where((t_arc > 0) & np.isfinite(t_arc), t_arc, default_tol_mm)
            if np.any(t_arc > 0):
                lim = np.where(t_arc > 0, np.minimum(lim, np.sqrt(2.0 * t_arc * r / var_t2)), lim)
        v_move[is_arc] = lim
    if n < 2:
        return np.zeros(0), v_move
    u1 = t_out[idx[:-1]]
    u2 = t_in[idx[1:]]
    seg_len = length[idx]
    if still.any():
        # a stand-still block has no direction: both its junctions see the corner between the moves around it
        # (the end tangent of the last move before it, the start tangent of the first after it), and its zero
        # length bounds no tolerance
        k = np.arange(n)
        before = np.maximum.accumulate(np.where(still, -1, k))
        after = np.minimum.accumulate(np.where(still, n, k)[::-1])[::-1]
        u_out = np.where((before >= 0)[:, None], t_out[idx[np.maximum(before, 0)]], 0.0)
        u_in = np.where((after < n)[:, None], t_in[idx[np.minimum(after, n - 1)]], 0.0)
        u1, u2 = u_out[:-1], u_in[1:]
        seg_len = np.where(still, np.inf, seg_len)
    du = np.linalg.norm(u2 - u1, axis=1)
    # a straight line split into collinear moves plans as the line (refinement inserts such points): the
    # lengths that bound a corner's tolerance and tell a curve from a corner are those of the collinear
    # chains meeting there, not of the pieces
    before_len, after_len = _chain_lengths(seg_len, join)
    tol_j, stop = junction_tolerances(blend_g, default_tol_mm, seg_len, before_len, after_len)
    vj = np.full(n - 1, np.inf)
    if t1 > 0:
        # the filters' rounding and acceleration at each junction, from the direction changes within their span
        # (ilcnc.vcnc.plan_corners); an exact path stops where the direction changes, G61.1 at every junction
        blend = (tol_j > 0) & ~stop
        if blend.any():
            alone = still[:-1] | still[1:]
            tables = rounding_tables(lengths, period_s)
            v_pair = np.minimum(v_nom[:-1], v_nom[1:])
            # a point on a straight line (refinement inserts such points, on the line to within the nm its
            # decimals allow) is no corner: it takes no speed of its own, as when the line was one move, and
            # its turn adds next to nothing to the sums. A turn is a corner where, alone, it would round the
            # path by more than 1 % of the tolerance at the moves' speed
            corner = ~join & (v_pair * du * tables[0][0] > _OWN_TURN * tol_j)
            vj = junction_speeds(np.cumsum(length[idx])[:-1], u2 - u1, np.where(blend, tol_j, 0.0),
                                 np.where(corner, v_pair, np.inf), limits.acceleration_mm_s2, alone, tables)
        vj = np.where(blend, vj, np.where((du > 1e-9) | stop, 0.0, np.inf))
    return vj, v_move


@dataclass(slots=True)
class _GroupSetup:
    """What a group's passes share: its moves, speeds before re-planning, junction speeds, filters."""

    idx: NDArray[np.int64]
    v: NDArray[np.float64]
    vj: NDArray[np.float64]
    hold: NDArray[np.float64]
    lengths: tuple[int, ...]
    span_s: float
    first: Pieces
    first_size: int
    chain: NDArray[np.int64] | None = None  # collinear chain of each move (None: every move its own)


def _group_setup(moves: MoveTable, geo: _Geometry, idx: NDArray[np.int64], length: NDArray[np.float64],
                 speed: NDArray[np.float64], hold_s: NDArray[np.float64], limits: PlanLimits, period_s: float,
                 mode: str, default_tol_mm: float, jerk_tc_s: float) -> _GroupSetup:
    """Speeds, junction limits and filters of one group (moves ``idx``, all rapids or all feeds).

    ``hold_s`` is the stand-still of every move (:func:`_stand_still_s`), s; ``default_tol_mm`` the
    profile's corner tolerance (moves without path control in the program).
    """
    t_in, t_out = geo.t_in, geo.t_out
    v = speed[idx].copy()
    hold = hold_s[idx]
    u_abs = np.maximum(np.abs(t_in[idx]), np.abs(t_out[idx]))
    vmax_axis = np.max(v[:, None] * u_abs, axis=0)
    lengths = _filter_lengths(mode, vmax_axis, limits, period_s, jerk_tc_s)
    filt_s = tuple(n * period_s for n in lengths)
    join = _straight_joins(moves, geo, idx, hold)
    vj, v_move = _corner_limits(moves, idx, length, t_in, t_out, limits, default_tol_mm, lengths, period_s, v,
                                 hold > 0.0, join)
    v = np.minimum(v, v_move)
    span_s = sum(filt_s)
    chain = _chain_ids(join)
    first = zone_pieces(length[idx], v * np.ones(idx.shape[0]), vj, span_s, hold, chain)
    size = _ideal_samples(first[4], period_s)[0] + sum(n - 1 for n in lengths)
    return _GroupSetup(idx, v, vj, hold, lengths, span_s, first, size, chain)


def _ideal_samples(dur: NDArray[np.float64], period_s: float) -> tuple[int, NDArray[np.float64], float]:
    """Ticks of the ideal interpolator over pieces of durations ``dur``, their end times, the total time.

    The last tick is at the total time (:func:`_sample_ideal`); a total within ``_TICK_SLACK`` of a whole
    number of periods (relative: the float noise of summing many durations, e.g. inverse-time blocks of one
    period each) is that number of ticks, not one more a fraction of a period later (a repeated last sample).
    """
    t_end = np.cumsum(dur)
    total = float(t_end[-1])
    ticks = total / period_s
    return max(1, math.ceil(ticks - _TICK_SLACK * max(1.0, ticks))), t_end, total


def _violation_window(bad: NDArray[np.int64], total: int, n_sig: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """First and last sample of the ideal signal inside the filter window before each violating sample."""
    return np.clip(bad - total, 0, n_sig - 1), np.clip(bad + 1, 0, n_sig - 1)


def _slower_moves(lo_g: NDArray[np.int64], hi_g: NDArray[np.int64], n_moves: int,
                  chain: NDArray[np.int64] | None = None) -> NDArray[np.bool_]:
    """Group moves between ``lo_g`` and ``hi_g`` (group move indices, inclusive) of any window, with every
    move of a collinear ``chain`` one of them is in (a straight line is slowed whole, however it is split)."""
    mark = np.zeros(n_moves + 1, dtype=np.int64)
    np.add.at(mark, lo_g, 1)
    np.add.at(mark, hi_g + 1, -1)
    sel = np.cumsum(mark)[:-1] > 0
    if chain is not None and sel.any():
        sel = (np.bincount(chain, weights=sel.astype(np.float64)) > 0)[chain]
    return sel


def _plan_group_numpy(moves: MoveTable, geo: _Geometry, g: _GroupSetup, length: NDArray[np.float64],
                      limits: PlanLimits, period_s: float, mode: str, max_passes: int, buf: NDArray[np.float64],
                      at: int) -> tuple[NDArray[np.float64], int, NDArray[np.int64], NDArray[np.int64],
                                        NDArray[np.float64]]:
    """Plan one group from rest to rest with whole-array numpy passes; rows go to ``buf[at:]``.

    Returns the (possibly grown) buffer, the rows written, the group's moves with their sample counts
    (run lengths of the move column) and the speeds used.
    """
    idx, v, vj, lengths = g.idx, g.v, g.vj, g.lengths
    scale = np.ones(idx.shape[0])
    pieces = g.first
    for _ in range(max_passes):
        ideal, mv = _sample_ideal(moves, geo, idx, pieces, period_s)
        start = moves.start_mm[idx[0]]
        sig = np.vstack([start[None, :], ideal])
        mv_sig = np.concatenate([[idx[0]], mv])
        inc = np.diff(sig, axis=0)
        for n in lengths:
            inc = _smooth_increments(inc, n)
        out = np.vstack([start[None, :], start + np.cumsum(inc, axis=0)])
        delay = sum(n - 1 for n in lengths) // 2
        mv_out = np.concatenate([np.full(delay, mv_sig[0]), mv_sig, np.full(out.shape[0] - mv_sig.shape[0] - delay,
                                                                           mv_sig[-1])])
        if mode == "constant_feed":
            break
        bad = _violations(out, limits, period_s)
        if bad.size == 0:
            break
        # lower the speed of every move inside the filter window of a violating sample
        total = sum(n - 1 for n in lengths) + 3
        lo_s, hi_s = _violation_window(bad, total, mv_sig.shape[0])
        scale[_slower_moves(np.searchsorted(idx, mv_sig[lo_s]), np.searchsorted(idx, mv_sig[hi_s]), idx.shape[0],
                            g.chain)] *= 0.8
        pieces = zone_pieces(length[idx], v * scale, vj, g.span_s, g.hold, g.chain)
    n_out = out.shape[0] - 1
    buf = _reserve(buf, at + n_out)
    buf[at:at + n_out] = out[1:]
    mvo = mv_out[1:]
    edges = np.flatnonzero(mvo[1:] != mvo[:-1]) + 1
    starts = np.concatenate(([0], edges))
    counts = np.diff(np.concatenate((starts, [mvo.shape[0]])))
    return buf, n_out, mvo[starts].astype(np.int64), counts.astype(np.int64), v * scale


def _plan_group_kernel(moves: MoveTable, geo: _Geometry, g: _GroupSetup, length: NDArray[np.float64],
                       limits: PlanLimits, period_s: float, mode: str, max_passes: int, buf: NDArray[np.float64],
                       at: int) -> tuple[NDArray[np.float64], int, NDArray[np.int64], NDArray[np.int64],
                                         NDArray[np.float64]]:
    """:func:`_plan_group_numpy` in one compiled pass per re-planning pass (:func:`group_kernel`).

    Same arithmetic in the same order, so the same numbers; the kernel streams each sample through the
    interpolator, the filters, the running sum and the limit check instead of a dozen whole-array passes.
    Each pass writes straight into ``buf`` from row ``at`` (grown when a slower pass needs more rows).
    """
    held = [buf]

    def rows_for(n_out: int) -> NDArray[np.float64]:
        held[0] = _reserve(held[0], at + n_out)
        return held[0][at:at + n_out]

    gp = _replan_group(moves, geo, g, length, limits, period_s, mode, max_passes, rows_for)
    run_move, run_count = gp.move_runs(g.idx)
    return held[0], gp.n + gp.extra, run_move, run_count, g.v * gp.scale


def _violations(pos: NDArray[np.float64], limits: PlanLimits, period_s: float) -> NDArray[np.int64]:
    """Sample indices where an axis's acceleration or jerk exceeds its limit (beyond the float noise of third differences)."""
    if pos.shape[0] < 4:
        return np.zeros(0, dtype=np.int64)
    acc = np.diff(pos, n=2, axis=0) / period_s**2
    jerk = np.diff(pos, n=3, axis=0) / period_s**3
    bad_a = np.any(np.abs(acc) > limits.acceleration_mm_s2 * (1 + _FD_NOISE), axis=1)
    bad_j = np.any(np.abs(jerk) > limits.jerk_mm_s3 * (1 + _FD_NOISE), axis=1)
    return np.unique(np.concatenate([np.flatnonzero(bad_a) + 1, np.flatnonzero(bad_j) + 2]))


def check_limits(ref: Reference, limits: PlanLimits) -> dict[str, NDArray[np.float64]]:
    """Peak |velocity|, |acceleration|, |jerk| of each axis of a reference (mm/s, mm/s², mm/s³)."""
    p = ref.pos_mm
    ts = ref.period_s
    out = {}
    for name, order in (("velocity", 1), ("acceleration", 2), ("jerk", 3)):
        if p.shape[0] > order:
            out[name] = np.max(np.abs(np.diff(p, n=order, axis=0)), axis=0) / ts**order
        else:
            out[name] = np.zeros(3)
    return out
