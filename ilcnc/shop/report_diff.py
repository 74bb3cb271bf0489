"""The visual diff of a learning run: what the rewritten program changed, drawn over the original path.

:func:`correction_figures` draws three PNGs from the program the run learned
(the original, or the refined program), the rewritten program and the error
per command ``E(k)``:

* ``corrections.png`` -- the whole part in its main plane: the original path
  (cutting moves solid, feed moves in the air dashed, rapids dotted), the
  rewritten path with its change from the original magnified, and each
  corrected end point's correction as an arrow magnified by the same factor
  (printed in the title and the legend). In a dense program (thousands of
  commands) the arrows are decimated: the part is cut into a grid of
  :data:`ARROW_GRID` x :data:`ARROW_GRID` cells and each cell keeps its
  largest correction; the figure says how many arrows of how many it drew.
  The zoom's window is drawn as a rectangle.
* ``corrections-zoom.png`` -- a window around the worst cutting command (the
  largest ``|E(k)|`` of the first measured iteration on a cutting command;
  without errors, the largest correction), with every arrow of the window,
  the error ``E(k)`` as a second arrow, both with one factor of their own,
  and the program line number written at the arrows.
* ``corrections-along-path.png`` -- the correction length and ``|E(k)|`` per
  command along the feed path length (the readable view of a 10,000-command
  program), corners (a direction change above :data:`CORNER_DEG`) marked
  below the axis, air commands drawn apart.

matplotlib is imported only when drawing (the Agg canvas, as
:mod:`ilcnc.shop.report`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ilcnc.contour.air import MOVE_AIR, MOVE_CUT
from ilcnc.contour.path import PathGeometry
from ilcnc.errors import InputError
from ilcnc.program.model import MOVE_LINE, MOVE_RAPID, Program
from ilcnc.shop.report import auto_magnify, axis_extent, figure_png, format_factor, new_figure, plane_axes
from ilcnc.units import AXIS_LETTERS

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = ["ARROW_GRID", "CORNER_DEG", "CORRECTION_FILES", "CorrectionFigures", "correction_figures"]

#: The overview keeps the largest correction of each cell of a grid this many cells wide and high.
ARROW_GRID = 60

#: A command end where the path turns by more than this (degrees) counts as a corner.
CORNER_DEG = 30.0

#: The files :func:`correction_figures` provides, in the order a report lists them.
CORRECTION_FILES = ("corrections.png", "corrections-zoom.png", "corrections-along-path.png")

_ARC_POINTS = 16  # an arc is drawn as 16 chords: at the plotted scale the chord error is below a line width
_ZOOM_NEIGHBOURS = 6  # the zoom window holds the worst command's end and about this many neighbours each side
_ZOOM_LABELS = 30  # line numbers written in the zoom (the largest corrections)
_MOVED_MM = 1e-9  # an end point moved when it changed by more than this (float noise of reading a number is 0)


@dataclass(frozen=True, slots=True, kw_only=True)
class CorrectionFigures:
    """The visual diff of a run.

    Attributes
    ----------
    overview_png, along_path_png : bytes
        ``corrections.png`` and ``corrections-along-path.png``.
    zoom_png : bytes or None
        ``corrections-zoom.png``; None when no command cuts.
    magnify : float
        Factor of the arrows and the rewritten path in the overview.
    zoom_magnify : float
        Factor of the arrows in the zoom.
    arrows_drawn, arrows_total : int
        Correction arrows in the overview, and corrected end points in all.
    worst_k : int or None
        The command the zoom centres on.
    worst_by : str
        ``error`` (its ``|E(k)|`` of the first iteration is the largest) or ``correction``.
    zoom_half_mm : float
        Half the side of the zoom window, mm.
    corners : int
        Corners marked along the path.
    """

    overview_png: bytes
    zoom_png: bytes | None
    along_path_png: bytes
    magnify: float
    zoom_magnify: float
    arrows_drawn: int
    arrows_total: int
    worst_k: int | None
    worst_by: str
    zoom_half_mm: float
    corners: int

    def files(self) -> list[tuple[str, bytes]]:
        """(file name, PNG) of each figure drawn, in :data:`CORRECTION_FILES` order."""
        out = [(CORRECTION_FILES[0], self.overview_png)]
        if self.zoom_png is not None:
            out.append((CORRECTION_FILES[1], self.zoom_png))
        out.append((CORRECTION_FILES[2], self.along_path_png))
        return out


@dataclass(frozen=True, slots=True)
class _Polys:
    """Per move, its points (a line: 2, an arc: 17) in the original and in the rewritten program, mm."""

    orig: list[NDArray[np.float64]]
    new: list[NDArray[np.float64]]


def _move_points(learning: Program, output: Program) -> _Polys:
    a = PathGeometry.from_moves(learning.moves, include_rapids=True)
    b = PathGeometry.from_moves(output.moves, include_rapids=True)
    kind = learning.moves.kind
    n_pts = np.where((kind == MOVE_LINE) | (kind == MOVE_RAPID), 2, _ARC_POINTS + 1)
    seg = np.repeat(np.arange(len(kind)), n_pts)
    first = np.concatenate(([0], np.cumsum(n_pts)[:-1]))
    frac = (np.arange(seg.size) - np.repeat(first, n_pts)) / np.repeat(n_pts - 1, n_pts)
    pa, pb = a.point_at(seg, frac), b.point_at(seg, frac)
    cuts = np.cumsum(n_pts)[:-1]
    return _Polys(np.split(pa, cuts), np.split(pb, cuts))


def _draw_path(ax: Axes, polys: _Polys, classes: NDArray[np.int8], axes: tuple[int, int], magnify: float,
               *, legend: bool) -> None:
    """The original path by move class and the rewritten one with its change magnified."""
    from matplotlib.collections import LineCollection

    a0, a1 = axes
    styles = ((MOVE_CUT, dict(colors="0.15", linewidths=0.9, linestyles="solid"), "original: cutting moves"),
              (MOVE_AIR, dict(colors="0.45", linewidths=0.8, linestyles=(0, (4, 2))),
               "original: feed moves in the air (dashed)"),
              (None, dict(colors="0.7", linewidths=0.6, linestyles=(0, (1, 2))), "rapids (dotted)"))
    for cls, style, label in styles:
        idx = np.flatnonzero(classes == cls) if cls is not None else np.flatnonzero(
            (classes != MOVE_CUT) & (classes != MOVE_AIR))
        if idx.size:
            ax.add_collection(LineCollection([polys.orig[i][:, [a0, a1]] for i in idx], label=label if legend else None,
                                             **style))  # type: ignore[arg-type]
    feed = np.flatnonzero((classes == MOVE_CUT) | (classes == MOVE_AIR))
    if feed.size:
        segs = []
        for i in feed:
            o = polys.orig[i][:, [a0, a1]]
            segs.append(o + magnify * (polys.new[i][:, [a0, a1]] - o))
        ax.add_collection(LineCollection(segs, colors="C3", linewidths=0.7, alpha=0.8,
                                         label=f"rewritten, change ×{format_factor(magnify)}" if legend else None))


def _grid_largest(xy: NDArray[np.float64], size: NDArray[np.float64], lo: NDArray[np.float64], span: float,
                  cells: int) -> NDArray[np.int64]:
    """Indices of the largest ``size`` in each of ``cells`` x ``cells`` square cells of side ``span / cells``."""
    if xy.shape[0] == 0:
        return np.zeros(0, np.int64)
    width = max(span, 1e-9) / cells
    cell = np.floor((xy - lo) / width).astype(np.int64)
    key = cell[:, 0] * (cells + 2) + cell[:, 1]
    order = np.lexsort((-size, key))  # by cell, largest first
    first = np.ones(order.size, bool)
    first[1:] = key[order][1:] != key[order][:-1]
    return np.sort(order[first])


def _corners(path: PathGeometry, learning: Program) -> NDArray[np.bool_]:
    """Per command: the path turns by more than :data:`CORNER_DEG` at its end (into the next feed move)."""
    cm = learning.command_moves
    n = len(path)
    nxt = np.minimum(cm + 1, n - 1)
    t_in = path.tangent_at(cm, np.ones(cm.size))
    t_out = path.tangent_at(nxt, np.zeros(cm.size))
    cos = np.clip(np.einsum("ij,ij->i", t_in, t_out), -1.0, 1.0)
    fed = (cm + 1 < n) & (learning.moves.kind[nxt] != MOVE_RAPID)
    return fed & (cos < math.cos(math.radians(CORNER_DEG)))


def _norm(v: NDArray[np.float64] | None, valid: NDArray[np.bool_] | None) -> NDArray[np.float64] | None:
    if v is None:
        return None
    n = np.sqrt(np.sum(np.asarray(v, float) ** 2, axis=1))
    return n if valid is None else np.where(valid, n, np.nan)


def correction_figures(*, program_name: str, learning: Program, output: Program, move_class: NDArray[np.int8],
                       air_command: NDArray[np.bool_], output_iteration: int,
                       error_first_mm: NDArray[np.float64] | None = None, error_first_valid: NDArray[np.bool_] | None = None,
                       first_iteration: int = 0, error_best_mm: NDArray[np.float64] | None = None,
                       error_best_valid: NDArray[np.bool_] | None = None, best_iteration: int | None = None
                       ) -> CorrectionFigures:
    """Draw the visual diff of ``output`` against ``learning`` (module docstring).

    Parameters
    ----------
    program_name : str
        Name used in the titles.
    learning : Program
        The program the run learned (its commands are the index ``k``).
    output : Program
        The rewritten program: the same moves with corrected end points.
    move_class : ndarray (M,) int8
        Class of each move of ``learning`` (:func:`ilcnc.contour.air.move_classes`).
    air_command : ndarray (K,) bool
        Commands in the air (:func:`ilcnc.contour.air.air_commands` and ends above the stock top).
    output_iteration : int
        The iteration whose program ``output`` is (titles).
    error_first_mm, error_best_mm : ndarray (K, 3), optional
        ``E(k)`` of the first measured iteration and of the best one, mm.
    error_first_valid, error_best_valid : ndarray (K,) bool, optional
        Which rows of those are measured.
    first_iteration, best_iteration : int
        Their iteration numbers (labels).

    Raises
    ------
    InputError
        ``output`` does not have the moves of ``learning`` (not a rewrite of it).
    """
    if len(output.moves) != len(learning.moves) or output.n_commands != learning.n_commands:
        raise InputError(output.path, None, f"has {len(output.moves)} moves and {output.n_commands} commands, the"
                         f" program it rewrites {len(learning.moves)} and {learning.n_commands}: not a rewrite of it")
    import matplotlib

    with matplotlib.rc_context({"agg.path.chunksize": 20_000}):
        return _figures(program_name, learning, output, move_class, air_command, output_iteration,
                        _norm(error_first_mm, error_first_valid), first_iteration, error_first_mm,
                        _norm(error_best_mm, error_best_valid), best_iteration)


def _figures(program_name: str, learning: Program, output: Program, classes: NDArray[np.int8],
             air_command: NDArray[np.bool_], out_it: int, e_first: NDArray[np.float64] | None, first_it: int,
             e_first_vec: NDArray[np.float64] | None, e_best: NDArray[np.float64] | None, best_it: int | None
             ) -> CorrectionFigures:
    path = PathGeometry.from_moves(learning.moves, include_rapids=True)
    polys = _move_points(learning, output)
    feed = (classes == MOVE_CUT) | (classes == MOVE_AIR)
    feed_pts = np.vstack([polys.orig[i] for i in np.flatnonzero(feed)]) if feed.any() else np.zeros((0, 3))
    ext = axis_extent(feed_pts)
    axes = plane_axes(ext)
    a0, a1 = axes
    extent = float(max(ext[a0], ext[a1])) if ext.size else 0.0
    lo = np.nanmin(feed_pts[:, [a0, a1]], axis=0) if feed_pts.size else np.zeros(2)

    old = learning.command_end_mm
    u = output.command_end_mm - old
    u_len = np.sqrt(np.sum(u**2, axis=1))
    u_plane = np.sqrt(u[:, a0] ** 2 + u[:, a1] ** 2)
    moved = u_len > _MOVED_MM
    cut_cmd = ~np.asarray(air_command, bool)
    magnify = auto_magnify(extent, float(u_plane[moved].max())) if moved.any() else 1.0

    # the worst cutting command: the first run's largest |E(k)|, else the largest correction
    worst_k: int | None = None
    worst_by = "error"
    if e_first is not None and np.isfinite(np.where(cut_cmd, e_first, np.nan)).any():
        worst_k = int(np.nanargmax(np.where(cut_cmd, e_first, np.nan)))
    elif (moved & cut_cmd).any():
        worst_k, worst_by = int(np.argmax(np.where(cut_cmd, u_len, -1.0))), "correction"
    half = 0.0
    if worst_k is not None:
        c = old[worst_k, [a0, a1]]
        near = np.arange(max(0, worst_k - _ZOOM_NEIGHBOURS), min(len(old), worst_k + _ZOOM_NEIGHBOURS + 1))
        d = np.abs(old[near][:, [a0, a1]] - c).max(axis=1)
        half = float(np.clip(np.nanmax(d) * 1.1, 0.5, max(0.5, 0.25 * extent)))

    # overview
    fig = new_figure(8.5, 8.0)
    ax = fig.add_subplot()
    _draw_path(ax, polys, classes, axes, magnify, legend=True)
    arrow_pool = np.flatnonzero(moved)
    pick = arrow_pool[_grid_largest(old[arrow_pool][:, [a0, a1]], u_plane[arrow_pool], lo, extent, ARROW_GRID)]
    for sel, colour, label in ((pick[cut_cmd[pick]], "C3", "correction of a cutting command"),
                               (pick[~cut_cmd[pick]], "C1", "correction of an air command")):
        if sel.size:
            ax.quiver(old[sel, a0], old[sel, a1], magnify * u[sel, a0], magnify * u[sel, a1], color=colour,
                      angles="xy", scale_units="xy", scale=1.0, width=0.003, headwidth=4,
                      label=f"{label} ×{format_factor(magnify)}")
    if worst_k is not None:
        from matplotlib.patches import Rectangle

        c = old[worst_k, [a0, a1]]
        ax.add_patch(Rectangle((c[0] - half, c[1] - half), 2 * half, 2 * half, fill=False, ec="C0", lw=1.2,
                               label=f"zoom: line {int(learning.command_line[worst_k])}"))
    ax.autoscale_view()
    ax.set_aspect("equal", adjustable="datalim")
    _labels(ax, axes)
    dec = (f"{pick.size} of {arrow_pool.size} corrected end points drawn (the largest of each 1/{ARROW_GRID} cell)"
           if pick.size < arrow_pool.size else f"{arrow_pool.size} corrected end points")
    ax.set_title(f"{program_name}: iteration {out_it} against the original, corrections ×{format_factor(magnify)}"
                 f"\n{dec}; largest {1000.0 * float(u_len.max(initial=0.0)):.2f} µm", fontsize="medium")
    fig.legend(loc="outside lower center", ncols=2, fontsize="small")
    overview = figure_png(fig)

    zoom_png, zoom_mag = None, 1.0
    if worst_k is not None:
        zoom_png, zoom_mag = _zoom(program_name, learning, polys, classes, axes, worst_k, worst_by, half, u, u_plane,
                                   moved, cut_cmd, e_first, e_first_vec, first_it, out_it)
    corners = _corners(path, learning)
    along = _along_path(program_name, learning, path, classes, u_len, cut_cmd, corners, e_first, first_it, e_best,
                        best_it, out_it, worst_k)
    return CorrectionFigures(overview_png=overview, zoom_png=zoom_png, along_path_png=along, magnify=magnify,
                             zoom_magnify=zoom_mag, arrows_drawn=int(pick.size), arrows_total=int(arrow_pool.size),
                             worst_k=worst_k, worst_by=worst_by, zoom_half_mm=half, corners=int(corners.sum()))


def _labels(ax: Axes, axes: tuple[int, int]) -> None:
    ax.set_xlabel(f"{AXIS_LETTERS[axes[0]]} / mm")
    ax.set_ylabel(f"{AXIS_LETTERS[axes[1]]} / mm")
    ax.grid(True, lw=0.4, alpha=0.5)


def _zoom(program_name: str, learning: Program, polys: _Polys, classes: NDArray[np.int8], axes: tuple[int, int],
          k: int, worst_by: str, half: float, u: NDArray[np.float64], u_plane: NDArray[np.float64],
          moved: NDArray[np.bool_], cut_cmd: NDArray[np.bool_], e_first: NDArray[np.float64] | None,
          e_vec: NDArray[np.float64] | None, first_it: int, out_it: int) -> tuple[bytes, float]:
    a0, a1 = axes
    old = learning.command_end_mm
    c = old[k, [a0, a1]]
    inside = np.all(np.abs(old[:, [a0, a1]] - c) <= half, axis=1)
    sel = np.flatnonzero(inside & moved)
    biggest = float(u_plane[sel].max()) if sel.size else 0.0
    if e_vec is not None:
        ev = np.where(np.isfinite(e_vec), e_vec, 0.0)
        e_plane = np.sqrt(ev[:, a0] ** 2 + ev[:, a1] ** 2)
        biggest = max(biggest, float(e_plane[inside].max(initial=0.0)))
    mag = auto_magnify(2.0 * half, biggest, share=0.15)  # the largest arrow about 15 % of the window

    fig = new_figure(8.0, 8.0)
    ax = fig.add_subplot()
    near = [i for i in range(len(polys.orig))
            if np.any(np.all(np.abs(polys.orig[i][:, [a0, a1]] - c) <= 1.5 * half, axis=1))]
    sub = _Polys([polys.orig[i] for i in near], [polys.new[i] for i in near])
    _draw_path(ax, sub, classes[near], axes, mag, legend=True)
    if e_vec is not None:
        es = np.flatnonzero(inside & np.isfinite(e_vec).all(axis=1))
        if es.size:
            ax.quiver(old[es, a0], old[es, a1], mag * e_vec[es, a0], mag * e_vec[es, a1], color="C0", angles="xy",
                      scale_units="xy", scale=1.0, width=0.004, alpha=0.7,
                      label=f"error E(k) of iteration {first_it} ×{format_factor(mag)}")
    for part, colour, label in ((sel[cut_cmd[sel]], "C3", "correction of a cutting command"),
                                (sel[~cut_cmd[sel]], "C1", "correction of an air command")):
        if part.size:
            ax.quiver(old[part, a0], old[part, a1], mag * u[part, a0], mag * u[part, a1], color=colour, angles="xy",
                      scale_units="xy", scale=1.0, width=0.005, label=f"{label} ×{format_factor(mag)}")
    lines = learning.command_line
    lab = _spaced_labels(old[:, [a0, a1]], np.where(moved, u_plane, -1.0), np.flatnonzero(inside), k, 0.12 * half)
    for i in lab:
        ax.annotate(f"N{int(lines[i])}", (old[i, a0], old[i, a1]), xytext=(4, 4), textcoords="offset points",
                    fontsize="x-small", color="C3" if i != k else "C0", fontweight="bold" if i == k else "normal")
    ax.plot([c[0]], [c[1]], "o", ms=12, mfc="none", mec="C0", mew=1.5)
    ax.set_xlim(c[0] - half, c[0] + half)
    ax.set_ylim(c[1] - half, c[1] + half)
    ax.set_aspect("equal")
    _labels(ax, axes)
    why = (f"largest |E(k)| of iteration {first_it} on a cutting command: {1000.0 * float(e_first[k]):.2f} µm"
           if worst_by == "error" and e_first is not None else
           f"largest correction of a cutting command: {1000.0 * float(np.linalg.norm(u[k])):.2f} µm")
    ax.set_title(f"{program_name}: the worst cutting spot, line {int(lines[k])} (N = program line)\n{why}\n"
                 f"window ±{half:.3g} mm, arrows and rewritten path (iteration {out_it}) ×{format_factor(mag)}",
                 fontsize="small")
    fig.legend(loc="outside lower center", ncols=2, fontsize="small")
    return figure_png(fig), mag


def _spaced_labels(xy: NDArray[np.float64], size: NDArray[np.float64], cand: NDArray[np.int64], k: int,
                   gap_mm: float) -> list[int]:
    """Commands to write a line number at: ``k`` first, then the largest ``size`` whose end point lies at least
    ``gap_mm`` from every one chosen, at most :data:`_ZOOM_LABELS` (labels of neighbours would overlap)."""
    chosen = [k]
    for i in cand[np.argsort(-size[cand], kind="stable")]:
        if len(chosen) >= _ZOOM_LABELS:
            break
        if np.all(np.abs(xy[chosen] - xy[i]).max(axis=1) >= gap_mm):
            chosen.append(int(i))
    return chosen


def _along_path(program_name: str, learning: Program, path: PathGeometry, classes: NDArray[np.int8],
                u_len: NDArray[np.float64], cut_cmd: NDArray[np.bool_], corners: NDArray[np.bool_],
                e_first: NDArray[np.float64] | None, first_it: int, e_best: NDArray[np.float64] | None,
                best_it: int | None, out_it: int, worst_k: int | None) -> bytes:
    feed_len = np.diff(path.cum_length_mm) * ((classes == MOVE_CUT) | (classes == MOVE_AIR))
    s = np.cumsum(feed_len)[learning.command_moves]
    fig = new_figure(10.0, 5.0)
    ax = fig.add_subplot()

    def line(y: NDArray[np.float64], colour: str, label: str, lw: float = 0.8) -> None:
        yy = np.where(cut_cmd, 1000.0 * y, np.nan)
        ax.plot(s, yy, color=colour, lw=lw, label=label)
        ax.plot(s[~cut_cmd], 1000.0 * y[~cut_cmd], "x", ms=3, color=colour, alpha=0.5)

    if e_first is not None:
        line(e_first, "C0", f"|E(k)| iteration {first_it}")
    if e_best is not None and best_it is not None and best_it != first_it:
        line(e_best, "C2", f"|E(k)| iteration {best_it}")
    line(u_len, "C3", f"correction length, iteration {out_it}", lw=1.0)
    ax.plot([], [], "x", color="0.4", label="air commands (×, not joined)")
    ax.plot(s[corners], np.zeros(int(corners.sum())), "|", ms=10, color="0.3", transform=ax.get_xaxis_transform(),
            label=f"corners (turn > {CORNER_DEG:g}°)")
    if worst_k is not None:
        ax.axvline(s[worst_k], color="C0", lw=0.6, ls=":")
        ax.annotate(f"N{int(learning.command_line[worst_k])}", (s[worst_k], 0.97), xycoords=("data", "axes fraction"),
                    fontsize="x-small", color="C0", ha="left", va="top")
    ax.set_xlabel("feed path length at the command's end / mm")
    ax.set_ylabel("µm")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.set_title(f"{program_name}: correction and error per command along the path ({learning.n_commands} commands)",
                 fontsize="medium")
    fig.legend(loc="outside right upper", fontsize="small")
    return figure_png(fig)
