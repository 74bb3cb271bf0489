"""Which feed moves cut material and which are in the air.

A machinist judges a part by the contour error of the moves that cut it (the
form tolerance); a feed move above the stock (a jscut "rapid to initial
position" written as ``G1`` at Z1, an approach, a retract at feed) cuts
nothing, and its error shapes no surface. Every figure ilcnc reports gives
the cutting moves first and the air moves apart, the learning does not
correct air moves unless told to (``learning.correct_air``), and ``check``
gates on the cutting moves.

The rule (:func:`cutting_rule`), in order:

1. ``--cutting-below-z MM`` on the command line;
2. the profile's ``cutting.top_z_mm``;
3. work Z0, when some feed move of the program reaches Z <= 0: CAM systems put
   the work zero on the stock top, so a feed move that stays above it is in
   the air;
4. otherwise (the program's work zero is not the stock top: all of its feed
   moves lie above Z0, e.g. a relief carved from the table up) every feed
   move counts as cutting, and the rule says so.

A feed move is in the air when its lowest point (program coordinates: the
end point minus the work offset; a helix's lowest end) lies above the top by
more than the machine's resolution. Rapids are neither: they are never cut
and never in a figure. A cutting move that starts above the top (a plunge
from the clearance height) cuts only below it: a sample whose nearest point
on the drawing lies above the top counts with the air moves
(:func:`air_above_mm`), so the lag of the rapid before a plunge, gone before
the tool reaches the stock, is not a form error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import MOVE_RAPID, Program

__all__ = ["MOVE_AIR", "MOVE_CUT", "MOVE_NOT_FED", "CuttingRule", "air_above_mm", "air_command_mask", "air_commands",
           "cutting_rule", "cutting_samples", "move_classes", "profile_cutting_rule", "profile_move_classes",
           "rule_air_commands"]

#: Move classes (:func:`move_classes`): a rapid (no figure), a cutting feed move, a feed move in the air.
MOVE_NOT_FED = 0
MOVE_CUT = 1
MOVE_AIR = 2


@dataclass(frozen=True, slots=True)
class CuttingRule:
    """Where the material starts: feed moves whose lowest point is above ``top_z_mm`` are air moves.

    Attributes
    ----------
    top_z_mm : float or None
        Stock top in the program's coordinates, mm; ``None``: every feed move cuts.
    source : str
        Where the value came from: ``option`` (``--cutting-below-z``), ``profile``
        (``cutting.top_z_mm``), ``work_z0`` (the CAM convention) or ``none`` (every feed move cuts).
    """

    top_z_mm: float | None
    source: str

    def describe(self) -> str:
        """One line for the user: the rule applied."""
        if self.top_z_mm is None:
            return ("every feed move counts as cutting (no feed move reaches work Z0: set cutting.top_z_mm or"
                    " --cutting-below-z to the stock top)")
        where = {"option": "--cutting-below-z", "profile": "cutting.top_z_mm",
                 "work_z0": "work Z0, the stock top of CAM programs"}[self.source]
        return (f"feed moves above Z {self.top_z_mm:g} mm ({where}) are air moves, and so is the part of a"
                " plunge above it")

    def to_json(self) -> dict[str, object]:
        return {"top_z_mm": self.top_z_mm, "source": self.source}


def _lowest_z_mm(program: Program) -> NDArray[np.float64]:
    mv = program.moves
    z0 = mv.start_mm[:, 2] - mv.offset_mm[:, 2]
    z1 = mv.end_mm[:, 2] - mv.offset_mm[:, 2]
    return np.minimum(z0, z1)


def cutting_rule(program: Program, *, option_z_mm: float | None = None, profile_z_mm: float | None = None,
                 resolution_mm: float = 0.0) -> CuttingRule:
    """The rule that tells cutting from air moves for ``program`` (module docstring).

    Parameters
    ----------
    program : Program
        The drawing (the original program: a compensated one is judged by its rule).
    option_z_mm : float, optional
        ``--cutting-below-z``, mm in program coordinates.
    profile_z_mm : float, optional
        The profile's ``cutting.top_z_mm``, mm.
    resolution_mm : float
        The machine's resolution: a feed move at work Z0 written as 0.0005 still touches the top.
    """
    if option_z_mm is not None:
        return CuttingRule(float(option_z_mm), "option")
    if profile_z_mm is not None:
        return CuttingRule(float(profile_z_mm), "profile")
    mv = program.moves
    feed = mv.kind != MOVE_RAPID
    if feed.any() and float(np.min(_lowest_z_mm(program)[feed])) <= resolution_mm:
        return CuttingRule(0.0, "work_z0")
    return CuttingRule(None, "none")


def move_classes(program: Program, rule: CuttingRule, *, resolution_mm: float = 0.0) -> NDArray[np.int8]:
    """Class of every move of ``program``: :data:`MOVE_NOT_FED`, :data:`MOVE_CUT` or :data:`MOVE_AIR`, shape (M,)."""
    mv = program.moves
    cls = np.where(mv.kind == MOVE_RAPID, MOVE_NOT_FED, MOVE_CUT).astype(np.int8)
    if rule.top_z_mm is not None:
        air = (mv.kind != MOVE_RAPID) & (_lowest_z_mm(program) > rule.top_z_mm + resolution_mm)
        cls[air] = MOVE_AIR
    return cls


def air_above_mm(program: Program, rule: CuttingRule, classes: NDArray[np.int8], *, resolution_mm: float = 0.0
                 ) -> NDArray[np.float64]:
    """Per move, the Z (the path's coordinates, mm) above which a sample of a cutting move is in the air: the
    stock top plus the move's work offset and the resolution; +inf for air moves, rapids, and without a top."""
    mv = program.moves
    out = np.full(len(mv), np.inf)
    if rule.top_z_mm is not None:
        cut = classes == MOVE_CUT
        out[cut] = rule.top_z_mm + mv.offset_mm[cut, 2] + resolution_mm
    return out


def cutting_samples(move: NDArray[np.integer], classes: NDArray[np.int8], foot_z_mm: NDArray[np.float64],
                    above_mm: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Per sample: on a cutting move (``move``, -1: none) and not above the stock top (its nearest point on the
    drawing, ``foot_z_mm``, at most the move's ``above_mm``); the rule of the figures, in numpy."""
    mv = np.asarray(move)
    ok = mv >= 0
    m = np.where(ok, mv, 0)
    z = np.nan_to_num(np.asarray(foot_z_mm, dtype=np.float64), nan=np.inf)
    return ok & (classes[m] == MOVE_CUT) & (z <= above_mm[m])


def air_commands(program: Program, classes: NDArray[np.int8]) -> NDArray[np.bool_]:
    """Which G01 commands k are air moves, shape (N,)."""
    return classes[program.command_moves] == MOVE_AIR


def profile_cutting_rule(program: Program, profile: MachineProfile) -> CuttingRule:
    """:func:`cutting_rule` with the profile's ``cutting.top_z_mm`` and resolution (``--cutting-below-z`` reaches it
    as the profile's value: the CLI replaces that key)."""
    cut = profile.cutting
    given = cut.top_z_mm if cut.top_z_from != "option" else None
    option = cut.top_z_mm if cut.top_z_from == "option" else None
    return cutting_rule(program, option_z_mm=option, profile_z_mm=given, resolution_mm=profile.machine.resolution_mm)


def profile_move_classes(program: Program, profile: MachineProfile) -> tuple[CuttingRule, NDArray[np.int8]]:
    """The profile's rule for ``program`` and the class of every move under it."""
    rule = profile_cutting_rule(program, profile)
    return rule, move_classes(program, rule, resolution_mm=profile.machine.resolution_mm)


def air_command_mask(program: Program, profile: MachineProfile) -> NDArray[np.bool_]:
    """Commands whose end point is in the air under the profile's rule, shape (K,): air moves, and the
    retracts and approaches whose end lies above the stock top (correcting a point in the air shapes no cut)."""
    rule, classes = profile_move_classes(program, profile)
    return rule_air_commands(program, rule, classes, resolution_mm=profile.machine.resolution_mm)


def rule_air_commands(program: Program, rule: CuttingRule, classes: NDArray[np.int8], *, resolution_mm: float = 0.0
                      ) -> NDArray[np.bool_]:
    """:func:`air_command_mask` under a given rule and move classes (:func:`move_classes`), shape (K,)."""
    air = air_commands(program, classes)
    if rule.top_z_mm is not None:
        mv = program.moves
        cm = program.command_moves
        end_z = mv.end_mm[cm, 2] - mv.offset_mm[cm, 2]
        air |= end_z > rule.top_z_mm + resolution_mm
    return air
