"""Errors the virtual CNC adds to the drives' actual position: machine geometry and tool deflection.

The drives give the axis positions ``q(t)``; the tool tip is not quite there:

* **geometric** (seed 002): the machine's volumetric error at the axis
  positions, ``g(q)`` from the profile's ``geometry.map``
  (:mod:`ilcnc.vcnc.volumetric`);
* **cutting** (seed 004): the surface location error of the tool bent by the
  cutting force, ``−SLE(k)·n_wall`` while command k cuts, from the profile's
  ``tool`` and ``cutting`` sections and the stock (OMI) file
  (:mod:`ilcnc.vcnc.deflection`). ``n_wall`` is the unit normal in the XY plane
  from the path toward the wall; SLE > 0 (the tool bends away from the wall)
  leaves material.

The actual tool position is ``q + g(q) − SLE·n_wall``. Each source is on when
the profile names it (``geometry.map``; ``cutting.model: mechanistic``).

The radial depth of cut follows the commanded path (seed 004 eq. (4):
``a_e = X_OMI − (X_cmd − R)``): a stock file of points gives it for the
program that runs; a per-command file (``k,stock_mm``) or the profile's
constant gives it for the original program, and a corrected program's
commands add their move toward the wall.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import MapError, ProfileError
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import Program

__all__ = ["ErrorSources", "wall_normals"]


@dataclass(slots=True)
class ErrorSources:
    """The geometric and cutting error models of a profile, loaded once (files read, checked).

    Attributes
    ----------
    geometry : ErrorModel or None
        Volumetric error model (:mod:`ilcnc.vcnc.volumetric`), ``None`` when off.
    tool : deflection.Tool or None
        Tool with its tool-point receptance, ``None`` when the cutting error is off.
    cutting : deflection.Cutting or None
        Cutting coefficients and conditions.
    wall : str
        ``"left"`` or ``"right"`` of the travel direction.
    stock_path : Path or None
        The stock (OMI) file.
    constant_depth_mm : float or None
        Radial depth of every command when there is no stock file, mm.
    _depth_of : (Program, ndarray) or None
        The stock file's radial depths of the last drawing it was read for (the learning loop runs
        the same drawing every iteration).
    """

    geometry: Any = None
    tool: Any = None
    cutting: Any = None
    wall: str = "left"
    stock_path: Any = None
    constant_depth_mm: float | None = None
    _depth_of: tuple[Program, NDArray[np.float64]] | None = field(default=None, repr=False, compare=False)

    @property
    def enabled(self) -> bool:
        """True when at least one source is on."""
        return self.geometry is not None or self.cutting is not None

    @property
    def names(self) -> tuple[str, ...]:
        """The sources that are on, in the order they are added."""
        return tuple(n for n, m in (("geometric", self.geometry), ("cutting", self.cutting)) if m is not None)

    @classmethod
    def from_profile(cls, profile: MachineProfile) -> ErrorSources:
        """Load the sources a profile names.

        Raises
        ------
        MapError
            A map, FRF or stock file that cannot be used (``file:line: problem``).
        ProfileError
            Tool or cutting values the models refuse.
        """
        geometry = None
        g = profile.geometry
        if g.map is not None:
            from ilcnc.vcnc.volumetric import load_volumetric

            path = profile.resolve(g.map)
            if not path.is_file():
                raise MapError(path, None, f"volumetric map named by geometry.map of {_name(profile)} does not exist")
            geometry = load_volumetric(path, extrapolate="linear" if g.outside == "extrapolate" else False)
        c = profile.cutting
        if not c.enabled:
            return cls(geometry=geometry)
        from ilcnc.vcnc import deflection as dfl
        t = profile.tool
        frf_normal: Any
        frf_feed: Any = None
        if t.frf_csv is not None:
            path = profile.resolve(t.frf_csv)
            if not path.is_file():
                raise MapError(path, None, f"tool FRF named by tool.frf_csv of {_name(profile)} does not exist")
            frf_normal = dfl.read_frf(path)
        else:
            modes = t.modes or ()
            normal = tuple(dfl.Mode(m.natural_frequency_hz, m.damping_ratio, m.stiffness_n_um)
                           for m in modes if m.direction == "normal")
            feed = tuple(dfl.Mode(m.natural_frequency_hz, m.damping_ratio, m.stiffness_n_um)
                         for m in modes if m.direction == "feed")
            if not normal:
                raise ProfileError(profile.path, None, "tool.modes: the SLE needs at least one mode with direction normal"
                                                       " (perpendicular to the wall)")
            frf_normal = dfl.ModalFRF(normal)
            frf_feed = dfl.ModalFRF(feed) if feed else None
        tool = dfl.Tool(t.diameter_mm, t.teeth, frf_normal, frf_feed, helix_deg=t.helix_deg, runout_um=t.runout_um,
                        runout_angle_deg=t.runout_angle_deg)
        assert c.ktc_n_mm2 is not None and c.krc_n_mm2 is not None
        assert c.axial_depth_mm is not None and c.spindle_rpm is not None
        cutting = dfl.Cutting(c.ktc_n_mm2, c.krc_n_mm2, c.axial_depth_mm, c.spindle_rpm,
                              kte_n_mm=c.kte_n_mm or 0.0, kre_n_mm=c.kre_n_mm or 0.0, mode=c.milling)
        try:
            tool.validate()
            cutting.validate()
        except ValueError as exc:
            raise ProfileError(profile.path, None, str(exc)) from None
        stock = profile.resolve(c.stock) if c.stock is not None else None
        if stock is not None and not stock.is_file():
            raise MapError(stock, None, f"stock file named by cutting.stock of {_name(profile)} does not exist")
        return cls(geometry, tool, cutting, c.wall, stock, c.radial_depth_mm)

    # ------------------------------------------------------------------------------------------
    # per command
    # ------------------------------------------------------------------------------------------

    def radial_depth_mm(self, running: Program, original: Program) -> NDArray[np.float64]:
        """Radial depth of cut of every command of the running program, mm (NaN: not cutting).

        Parameters
        ----------
        running : Program
            The program that runs (a corrected one moves its commands toward or away from the wall).
        original : Program
            The drawing (same commands).
        """
        from ilcnc.vcnc import deflection as dfl
        if self._depth_of is not None and self._depth_of[0] is original:
            ae0 = self._depth_of[1]  # the stock file is read once per drawing, not once per run
        elif self.stock_path is not None:
            # a per-command file states the depth of the original; a points file is geometry
            ae0 = dfl.read_stock(self.stock_path, original, self.tool, wall=self.wall)  # type: ignore[arg-type]
            self._depth_of = (original, ae0)
        else:
            ae0 = np.full(original.n_commands, float(self.constant_depth_mm or 0.0))
        if running is original:
            return ae0
        n = wall_normals(original, self.wall)
        toward_wall = np.einsum("ij,ij->i", running.command_end_mm - original.command_end_mm, n)
        return ae0 + toward_wall

    def sle_mm(self, running: Program, original: Program) -> NDArray[np.float64]:
        """Surface location error of every command, mm (> 0: the tool bends away from the wall; 0 where not cutting)."""
        from ilcnc.vcnc import deflection as dfl
        ae = self.radial_depth_mm(running, original)
        cutting = np.isfinite(ae) & (ae > 0.0)
        ae_c = np.clip(np.where(cutting, ae, np.nan), None, self.tool.diameter_mm)
        fz = dfl.feed_per_tooth_mm(running.command_feed_mm_min, self.cutting.spindle_rpm, self.tool.teeth)
        if self.tool.helix_deg != 0.0 or self.tool.runout_um != 0.0:
            from ilcnc.vcnc.helix_sle import sle_helical_per_command_mm

            sle = sle_helical_per_command_mm(ae_c, fz, self.tool, self.cutting)
        else:
            sle = dfl.sle_per_command_mm(ae_c, fz, self.tool, self.cutting)
        return np.where(cutting & np.isfinite(sle), sle, 0.0)

    def surface_error_mm(self, running: Program, original: Program) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """Seed 004's eq. (4) per command, its sign corrected: the wall the tool leaves against the drawing's.

        ``E(k) = X_ref − (X_cmd − R + δ)`` in the wall's frame: with ``n`` the unit normal from the path toward
        the wall, ``u(k)`` the running program's end point minus the drawing's and ``δ = SLE(k)`` (> 0: the tool
        bends away from the wall, material is left), the wall lies ``u·n − SLE`` into the material from the
        drawing's, so ``E(k) = (SLE(k) − u(k)·n)·n`` (desired minus actual, mm). The learning's ``U += Γ·E``
        moves the tool toward the wall where it bends away.

        Returns
        -------
        e_mm : ndarray (K, 3)
            E(k), mm; 0 where the command does not cut.
        valid : ndarray (K,) bool
            The command cuts (a known radial depth > 0).
        """
        ae = self.radial_depth_mm(running, original)
        valid = np.isfinite(ae) & (ae > 0.0)
        sle = self.sle_mm(running, original)
        n = wall_normals(original, self.wall)
        u = running.command_end_mm - original.command_end_mm
        along = sle - np.einsum("ij,ij->i", u, n)
        return np.where(valid[:, None], along[:, None] * n, 0.0), valid

    # ------------------------------------------------------------------------------------------
    # per sample
    # ------------------------------------------------------------------------------------------

    def displacements_mm(
        self,
        actual_mm: NDArray[np.float64],
        sample_command: NDArray[np.integer],
        running: Program,
        original: Program,
        sample_line: NDArray[np.integer] | None = None,
    ) -> dict[str, NDArray[np.float64]]:
        """What each source adds to the actual position of every sample, mm.

        Parameters
        ----------
        actual_mm : ndarray (N, 3)
            Axis positions from the drives, mm.
        sample_command : ndarray (N,) int
            Command the reference runs at each sample (-1: not a G01 command).
        running, original : Program
            The program that runs and the drawing.
        sample_line : ndarray (N,) int, optional
            Source line of each sample (named when the tool leaves the map).

        Returns
        -------
        dict of str to ndarray (N, 3)
            ``geometric`` and / or ``cutting``, for the sources that are on.
        """
        out: dict[str, NDArray[np.float64]] = {}
        if self.geometry is not None:
            from ilcnc.vcnc.volumetric import OutsideMapError

            try:
                out["geometric"] = self.geometry.error_mm(actual_mm)
            except OutsideMapError as exc:
                line = int(sample_line[exc.index]) if sample_line is not None else None
                x, y, z = exc.point_mm
                raise MapError(running.path, line or None,
                               f"the tool reaches ({x:.3f}, {y:.3f}, {z:.3f}) mm, outside the volumetric map"
                               f" {exc.file or ''} ({exc.count} samples outside); extend the map or set"
                               " geometry.outside: extrapolate") from None
        if self.cutting is not None:
            sle = self.sle_mm(running, original)
            n = wall_normals(original, self.wall)
            k = np.asarray(sample_command, dtype=np.int64)
            d = np.zeros_like(actual_mm)
            on = k >= 0
            kk = k[on]
            # the SLE is known where the radial depth is, at the end points; along command k it goes linearly
            # from the end point before it (0 after a rapid or an air move) to its own, as the corrected end
            # points do: a stock step inside a command is spread over it, not put at its start
            idx = running.command_moves
            prev = np.zeros_like(sle)
            joined = idx[1:] == idx[:-1] + 1
            prev[1:] = np.where(joined, sle[:-1], 0.0)
            a = running.moves.start_mm[idx[kk], :2]
            b = running.moves.end_mm[idx[kk], :2]
            ab = b - a
            length2 = np.einsum("ij,ij->i", ab, ab)
            f = np.einsum("ij,ij->i", actual_mm[on, :2] - a, ab) / np.where(length2 > 0.0, length2, 1.0)
            f = np.where(length2 > 0.0, np.clip(f, 0.0, 1.0), 1.0)
            s = prev[kk] + f * (sle[kk] - prev[kk])
            d[on] = -s[:, None] * n[kk]  # the tool bends away from the wall
            out["cutting"] = d
        return out


def wall_normals(program: Program, wall: str) -> NDArray[np.float64]:
    """Unit normal in the XY plane from each command's path toward the wall, (K, 3).

    Parameters
    ----------
    program : Program
    wall : {"left", "right"}
        Side of the travel direction the wall is on.

    Returns
    -------
    ndarray (K, 3)
        ``(−t_y, t_x, 0)`` for a wall on the left of the XY travel direction ``t``;
        the opposite on the right; zero for a command with no XY travel.
    """
    mv = program.moves
    idx = program.command_moves
    d = mv.end_mm[idx, :2] - mv.start_mm[idx, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    safe = np.where(length > 1e-12, length, 1.0)
    n = np.zeros((idx.size, 3))
    n[:, 0] = -d[:, 1] / safe
    n[:, 1] = d[:, 0] / safe
    n[length <= 1e-12] = 0.0
    return n if wall == "left" else -n


def _name(profile: MachineProfile) -> str:
    return profile.path.name if profile.path is not None else "the profile"
