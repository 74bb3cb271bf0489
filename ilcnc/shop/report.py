"""Report of a learning run: plots (PNG), summary tables (CSV, Markdown) and the per-command diff.

:func:`write_report` writes into one output directory:

* ``path-iterNNN.png`` -- per run with actual positions: the programmed path
  and the actual path, its deviation from the path magnified (the same factor
  for every run, shown in the title as "deviation ×N");
* ``error-iterNNN.png`` -- per run with error samples: the contour error (and
  the signed in-plane error, when given) in µm along the programmed path;
* ``error-along-path.png`` -- the contour error of every run overlaid;
* ``error-vs-iteration.png`` -- max, mean and RMS contour error (µm, log axis)
  per iteration, iterations that were not kept drawn as hollow markers;
* ``summary.csv`` / ``summary.md`` -- the statistics per iteration, status and
  message, and the reduction from iteration 0 to the best kept iteration;
* ``commands.csv`` -- the G01 end points that the output program changes (or
  that were clipped), old, new and the correction.

Every file is written atomically (:func:`ilcnc.fileio.write_atomic`).

Large runs
----------
A run may have ten million samples. No plot line gets more than
:data:`MAX_PLOT_POINTS` points: the samples are cut into bins of consecutive
samples and each bin keeps at most two -- for the error plots the smallest
and the largest error of the bin (an envelope, so narrow peaks survive), for
the path plots the bin's first sample and the one with the largest error. The
sample with the largest error of the whole run is therefore always drawn. The
arrays are scanned in chunks, so the extra memory stays small (a boolean per
sample plus a few MB). A line is broken where samples were left out because
they are not on a feed move or are not finite, never drawn across a rapid.

matplotlib is imported only when a report is written, with the non-interactive
Agg canvas (no GUI backend, no global ``pyplot`` state).
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError
from ilcnc.fileio import write_atomic
from ilcnc.units import AXIS_LETTERS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["MAX_PLOT_POINTS", "REPORT_FILES", "CommandDiff", "ReportRun", "auto_magnify", "axis_extent", "figure_png",
           "format_factor", "is_report_file", "new_figure", "plane_axes", "write_report"]

MAX_PLOT_POINTS = 200_000
"""Largest number of points of one plotted line."""

CHANGE_TOL_MM = 1e-9
"""An end-point coordinate counts as changed when it moved by more than this (mm)."""

_CHUNK = 1 << 20
_DPI = 110
_AXES = AXIS_LETTERS


@dataclass(slots=True)
class ReportRun:
    """One learning iteration's run.

    Attributes
    ----------
    iteration : int
        Iteration number; 0 is the uncompensated program.
    kept : bool
        The iteration was kept (its error did not grow).
    stats_mm : dict of str to float
        ``"max"``, ``"mean"``, ``"rms"`` contour error, mm (missing keys count as NaN).
    clipped : int
        Number of corrections clipped to the correction bound in this iteration.
    gain_scale : float
        1.0, or 0.5 after the guard halved the learning gain.
    actual_mm : ndarray of shape (N, 3) or None
        Actual positions of the run, mm (``None`` for a measured step without log samples).
    contour_mm : ndarray of shape (N,) or None
        Contour error distance per sample, mm (NaN off the path).
    signed_mm : ndarray of shape (N,) or None
        Signed in-plane contour error per sample, mm.
    path_pos_mm : ndarray of shape (N,) or None
        Arc length along the programmed path of each sample's foot point, mm.
    feed_mask : ndarray of shape (N,), bool, or None
        Samples on feed moves; only these are plotted. ``None``: all samples.
    foot_mm : ndarray of shape (N, 3) or None
        Foot point on the programmed path of each sample, mm (NaN off the
        path). With it the path plot magnifies the deviation
        ``actual - foot``; without it the actual path is drawn at true scale.
    """

    iteration: int
    kept: bool
    stats_mm: dict[str, float]
    clipped: int
    gain_scale: float
    actual_mm: np.ndarray | None
    contour_mm: np.ndarray | None
    signed_mm: np.ndarray | None
    path_pos_mm: np.ndarray | None
    feed_mask: np.ndarray | None
    foot_mm: np.ndarray | None = None


@dataclass(slots=True)
class CommandDiff:
    """Per-command diff of the final (best) program.

    Attributes
    ----------
    k : ndarray of shape (K,), int
        Command index.
    line : ndarray of shape (K,), int
        Source line of the command (1-based).
    old_mm : ndarray of shape (K, 3)
        Programmed end point, mm.
    new_mm : ndarray of shape (K, 3)
        End point in the output program, mm.
    clipped : ndarray of shape (K,), bool
        The correction was clipped to the correction bound in any iteration.
    """

    k: np.ndarray
    line: np.ndarray
    old_mm: np.ndarray
    new_mm: np.ndarray
    clipped: np.ndarray


# --------------------------------------------------------------------------- helpers


def _chunks(n: int, size: int = _CHUNK) -> Iterator[slice]:
    for s in range(0, n, size):
        yield slice(s, min(n, s + size))


def _stat(run: ReportRun, key: str) -> float:
    try:
        return float(run.stats_mm.get(key, math.nan))
    except (TypeError, ValueError):
        return math.nan


def format_factor(m: float) -> str:
    """A magnification as printed on a plot: ``20`` or ``2.5``."""
    return f"{m:.0f}" if m == round(m) and m < 1e15 else f"{m:g}"


def _n_samples(run: ReportRun) -> int | None:
    """Number of samples of a run (``None`` when it has no sample arrays); checks the shapes."""
    n: int | None = None
    for name in ("actual_mm", "foot_mm", "contour_mm", "signed_mm", "path_pos_mm", "feed_mask"):
        a = getattr(run, name)
        if a is None:
            continue
        shape = np.shape(a)
        rows = name in ("actual_mm", "foot_mm")
        if (rows and (len(shape) != 2 or shape[1] != 3)) or (not rows and len(shape) != 1):
            want = "(N, 3)" if rows else "(N,)"
            raise ValueError(f"iteration {run.iteration}: {name} has shape {shape}, expected {want}")
        if n is None:
            n = shape[0]
        elif shape[0] != n:
            raise ValueError(f"iteration {run.iteration}: {name} has {shape[0]} samples, expected {n}")
    return n


def _valid_mask(n: int, feed_mask: np.ndarray | None, rows: tuple[np.ndarray, ...] = (),
                cols: tuple[np.ndarray, ...] = ()) -> NDArray[np.bool_]:
    """Feed samples whose given (N, 3) rows and (N,) columns are all finite."""
    valid = np.ones(n, dtype=bool) if feed_mask is None else np.array(feed_mask, dtype=bool)
    for s in _chunks(n):
        v = valid[s]
        for a in rows:
            v &= np.isfinite(a[s]).all(axis=1)
        for a in cols:
            v &= np.isfinite(a[s])
    return valid


def _select(valid: NDArray[np.bool_], err: np.ndarray | None, max_points: int, *,
            envelope: bool) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Indices of the samples to plot, and where the line must break.

    The samples are cut into bins of ``step`` consecutive samples, with
    ``ceil(n / step) <= max_points / 2``. Each bin keeps its valid samples of
    smallest and largest ``err`` (``envelope``), or its first valid sample and
    the valid sample of largest ``err`` (non-finite errors never win).

    Returns
    -------
    idx : ndarray of shape (P,), int64
        Increasing sample indices, ``P <= max_points``.
    brk : ndarray of shape (P,), bool
        True where an invalid sample lies between the previous index and this one.
    """
    n = int(valid.size)
    step = max(1, math.ceil(n / max(1, max_points // 2)))
    block = step * max(1, _CHUNK // step)
    out_idx: list[np.ndarray] = []
    out_inv: list[np.ndarray] = []
    carry = 0
    for s0 in range(0, n, block):
        s1 = min(n, s0 + block)
        v = valid[s0:s1]
        m = s1 - s0
        nb = -(-m // step)
        pad = nb * step - m
        vb = np.pad(v, (0, pad)).reshape(nb, step)
        has = vb.any(axis=1)
        base = np.arange(nb, dtype=np.int64) * step
        picks: list[np.ndarray] = []
        if err is not None:
            e = np.asarray(err[s0:s1], dtype=float)
            ok = v & np.isfinite(e)
            hi = np.pad(np.where(ok, e, -np.inf), (0, pad), constant_values=-np.inf).reshape(nb, step)
            picks.append(hi.argmax(axis=1))
            if envelope:
                lo = np.pad(np.where(ok, e, np.inf), (0, pad), constant_values=np.inf).reshape(nb, step)
                picks.append(lo.argmin(axis=1))
        if err is None or not envelope:
            picks.append(vb.argmax(axis=1))  # first valid sample of the bin
        sel = (np.stack(picks, axis=1) + base[:, None])[has].ravel()
        sel = np.unique(sel)
        sel = sel[v[sel]]  # a bin whose valid errors are all NaN picked an arbitrary sample
        inv = np.cumsum(~v, dtype=np.int64)
        out_idx.append(sel + s0)
        out_inv.append(inv[sel] + carry)
        carry += int(inv[-1]) if m else 0
    if not out_idx:
        return np.zeros(0, np.int64), np.zeros(0, bool)
    idx = np.concatenate(out_idx)
    inv_count = np.concatenate(out_inv)
    brk = np.zeros(idx.size, dtype=bool)
    brk[1:] = np.diff(inv_count) > 0
    return idx, brk


def _broken(values: np.ndarray, brk: NDArray[np.bool_]) -> np.ndarray:
    """``values`` (float) with a NaN row inserted before every break."""
    values = np.asarray(values, dtype=float)
    where = np.flatnonzero(brk)
    return np.insert(values, where, np.nan, axis=0) if where.size else values


def _decimate_polyline(path: np.ndarray, max_points: int) -> np.ndarray:
    """Every n-th vertex of a NaN-separated polyline, keeping the NaN rows, their neighbours and the last vertex."""
    m = path.shape[0]
    if m <= max_points:
        return path
    step = math.ceil(m / max(1, max_points // 2))
    keep = np.zeros(m, dtype=bool)
    keep[::step] = True
    keep[-1] = True
    gap = ~np.isfinite(path).all(axis=1)
    keep |= gap
    keep[:-1] |= gap[1:]
    keep[1:] |= gap[:-1]
    return path[keep]


def axis_extent(a: np.ndarray) -> np.ndarray:
    """Per-column nan-aware max - min of an (M, d) array (0 for all-NaN columns)."""
    if a.size == 0:
        return np.zeros(a.shape[1] if a.ndim == 2 else 0)
    with np.errstate(invalid="ignore"):
        hi = np.fmax.reduce(a, axis=0)
        lo = np.fmin.reduce(a, axis=0)
    ext = hi - lo
    return np.where(np.isfinite(ext), ext, 0.0)


def plane_axes(ext: np.ndarray) -> tuple[int, int]:
    """XY, unless the part is flat in X or Y compared with Z: then the two axes of largest extent."""
    if ext.size < 3 or min(ext[0], ext[1]) >= 0.1 * ext[2]:
        return 0, 1
    order = sorted(range(3), key=lambda a: -ext[a])
    a0, a1 = sorted(order[:2])
    return a0, a1


def auto_magnify(extent_mm: float, max_err_mm: float, share: float = 0.05) -> float:
    """A 1-2-5 factor that makes the largest error about ``share`` of the extent (5 %; never below 1)."""
    if not (math.isfinite(extent_mm) and math.isfinite(max_err_mm)) or extent_mm <= 0 or max_err_mm <= 0:
        return 1.0
    raw = share * extent_mm / max_err_mm
    if raw <= 1.0:
        return 1.0
    exp = math.floor(math.log10(raw))
    base = raw / 10.0**exp
    nice = 5 if base >= 5 else 2 if base >= 2 else 1
    return float(nice * 10**exp)


def new_figure(width: float = 9.0, height: float = 5.5) -> Figure:
    """A matplotlib figure on the Agg canvas (no GUI, no pyplot state), size in inches, constrained layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def figure_png(fig: Figure) -> bytes:
    """The figure as PNG bytes; the first axes' title is also the PNG's ``Title`` text (file browsers show it)."""
    buf = io.BytesIO()
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    fig.savefig(buf, format="png", dpi=_DPI, metadata={"Title": titles[0]} if titles else None)
    return buf.getvalue()


def _stats_text(run: ReportRun) -> str:
    return "max / mean / RMS contour error " + " / ".join(
        f"{1000.0 * _stat(run, k):.2f}" if math.isfinite(_stat(run, k)) else "–" for k in ("max", "mean", "rms")
    ) + " µm"


def _run_label(run: ReportRun) -> str:
    return f"iteration {run.iteration}" + ("" if run.kept else " (not kept)")


# --------------------------------------------------------------------------- plots


def _plot_path(run: ReportRun, n: int, path_2d: np.ndarray, axes: tuple[int, int], magnify: float,
               program_name: str, max_points: int) -> bytes:
    actual = run.actual_mm
    assert actual is not None
    foot = run.foot_mm
    rows = (actual,) if foot is None else (actual, foot)
    valid = _valid_mask(n, run.feed_mask, rows=rows)
    idx, brk = _select(valid, run.contour_mm, max_points, envelope=False)
    a0, a1 = axes
    act = np.asarray(actual[idx][:, [a0, a1]], dtype=float)
    mag = 1.0
    if foot is not None:
        f = np.asarray(foot[idx][:, [a0, a1]], dtype=float)
        mag = magnify
        act = f + mag * (act - f)
    xy = _broken(act, brk)

    fig = new_figure(8.0, 7.5)
    ax = fig.add_subplot()
    ax.plot(path_2d[:, 0], path_2d[:, 1], color="0.25", lw=0.9, label="programmed path")
    scale = f"deviation ×{format_factor(mag)}" if foot is not None else "true scale (no foot points)"
    ax.plot(xy[:, 0], xy[:, 1], color="C3", lw=0.8, label=f"actual, {scale}")
    if run.contour_mm is not None and idx.size:
        e = np.asarray(run.contour_mm[idx], dtype=float)
        if np.isfinite(e).any():
            w = int(np.nanargmax(e))
            ax.plot([act[w, 0]], [act[w, 1]], "o", ms=9, mfc="none", mec="C3", mew=1.5,
                    label=f"largest error {1000.0 * e[w]:.2f} µm")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"{_AXES[a0]} / mm")
    ax.set_ylabel(f"{_AXES[a1]} / mm")
    ax.grid(True, lw=0.4, alpha=0.5)
    fig.legend(loc="outside lower center", ncols=3, fontsize="small")
    ax.set_title(f"{program_name} – {_run_label(run)}: {scale}\n{_stats_text(run)}", fontsize="medium")
    return figure_png(fig)


def _error_line(run: ReportRun, n: int, max_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(x mm, contour µm, signed µm or None) of a run's feed samples, decimated, NaN at breaks."""
    contour, pos = run.contour_mm, run.path_pos_mm
    assert contour is not None and pos is not None
    valid = _valid_mask(n, run.feed_mask, cols=(contour, pos))
    idx, brk = _select(valid, contour, max_points, envelope=True)
    x = _broken(pos[idx], brk)
    y = _broken(1000.0 * np.asarray(contour[idx], dtype=float), brk)
    s = None if run.signed_mm is None else _broken(1000.0 * np.asarray(run.signed_mm[idx], dtype=float), brk)
    return x, y, s


def _plot_error(run: ReportRun, line: tuple[np.ndarray, np.ndarray, np.ndarray | None], program_name: str) -> bytes:
    x, y, s = line
    fig = new_figure()
    ax = fig.add_subplot()
    if s is not None:
        ax.plot(x, s, color="C0", lw=0.6, alpha=0.6, label="signed in-plane error (+ = left of path)")
    ax.plot(x, y, color="C3", lw=0.8, label="contour error")
    ax.axhline(0.0, color="0.3", lw=0.5)
    ax.set_xlabel("position along the programmed path / mm")
    ax.set_ylabel("error / µm")
    ax.grid(True, lw=0.4, alpha=0.5)
    fig.legend(loc="outside lower center", ncols=2, fontsize="small")
    ax.set_title(f"{program_name} – {_run_label(run)}\n{_stats_text(run)}", fontsize="medium")
    return figure_png(fig)


def _plot_error_all(lines: list[tuple[ReportRun, np.ndarray, np.ndarray]], program_name: str) -> bytes:
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    fig = new_figure()
    ax = fig.add_subplot()
    count = len(lines)
    for i, (run, x, y) in enumerate(lines):
        color = cmap(0.9 * i / max(1, count - 1))
        ax.plot(x, y, color=color, lw=0.7, ls="-" if run.kept else "--", label=_run_label(run))
    ax.set_xlabel("position along the programmed path / mm")
    ax.set_ylabel("contour error / µm")
    ax.grid(True, lw=0.4, alpha=0.5)
    fig.legend(loc="outside right upper", fontsize="small", ncols=max(1, math.ceil(count / 25)))
    ax.set_title(f"{program_name} – contour error along the path, all iterations", fontsize="medium")
    return figure_png(fig)


def _minor_log_label(ax: Any, v: float) -> str:
    """Label the 2 and 5 minor ticks of a log axis spanning less than two decades."""
    lo, hi = ax.get_ylim()
    if lo <= 0 or hi / lo > 100.0 or v <= 0:
        return ""
    mant = v / 10.0 ** math.floor(math.log10(v) + 1e-9)
    return f"{v:g}" if round(mant, 6) in (2.0, 5.0) else ""


def _plot_vs_iteration(runs: list[ReportRun], program_name: str) -> bytes:
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    ordered = sorted(runs, key=lambda r: r.iteration)
    it = np.array([r.iteration for r in ordered], dtype=float)
    kept = np.array([r.kept for r in ordered], dtype=bool)
    fig = new_figure()
    ax = fig.add_subplot()
    handles = []
    for key, name, marker, color in (("max", "max", "^", "C3"), ("rms", "RMS", "s", "C1"), ("mean", "mean", "o", "C0")):
        v = np.array([1000.0 * _stat(r, key) for r in ordered])
        v = np.where(np.isfinite(v) & (v > 0), v, np.nan)
        ax.plot(it, v, color=color, lw=1.0, alpha=0.7)
        ax.plot(it[kept], v[kept], ls="none", marker=marker, ms=7, color=color)
        ax.plot(it[~kept], v[~kept], ls="none", marker=marker, ms=7, mfc="none", mec=color, mew=1.5)
        handles.append(Line2D([], [], color=color, marker=marker, label=name))
    if (~kept).any():
        handles.append(Line2D([], [], ls="none", marker="o", mfc="none", mec="0.3", label="not kept"))
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration")
    ax.set_ylabel("contour error / µm")
    ax.grid(True, which="both", lw=0.4, alpha=0.5)
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _pos: _minor_log_label(ax, v)))
    fig.legend(handles=handles, loc="outside right upper", fontsize="small")
    ax.set_title(f"{program_name} – contour error per iteration", fontsize="medium")
    return figure_png(fig)


# --------------------------------------------------------------------------- tables


def _best_run(runs: list[ReportRun], best_iteration: int | None) -> ReportRun | None:
    if best_iteration is not None:
        for r in runs:
            if r.iteration == best_iteration:
                return r
        raise ValueError(f"best_iteration {best_iteration} is not one of the runs")
    kept = [r for r in runs if r.kept and math.isfinite(_stat(r, "rms"))]
    if not kept:
        return None
    return min(kept, key=lambda r: (_stat(r, "rms"), _stat(r, "max"), r.iteration))


def _summary_csv(runs: list[ReportRun]) -> str:
    out = ["iteration,kept,max_mm,mean_mm,rms_mm,clipped,gain_scale"]
    for r in sorted(runs, key=lambda r: r.iteration):
        out.append(f"{r.iteration},{int(bool(r.kept))},{_stat(r, 'max'):.6f},{_stat(r, 'mean'):.6f},"
                   f"{_stat(r, 'rms'):.6f},{int(r.clipped)},{float(r.gain_scale):g}")
    return "\n".join(out) + "\n"


def _reduction(before: float, after: float) -> str:
    if not (math.isfinite(before) and math.isfinite(after)) or before <= 0:
        return "n/a"
    pct = 100.0 * (1.0 - after / before)
    word = "reduced" if pct >= 0 else "increased"
    return f"{word} by {abs(pct):.1f} % ({1000.0 * before:.3f} µm → {1000.0 * after:.3f} µm)"


def _summary_md(runs: list[ReportRun], *, program_name: str, status: str, message: str, best: ReportRun | None,
                n_changed: int, n_clipped: int, max_corr_mm: float, images: list[str]) -> str:
    ordered = sorted(runs, key=lambda r: r.iteration)
    lines = [f"# ilcnc learning report: {program_name}", ""]
    if status:
        lines.append(f"**Status:** {status}")
        lines.append("")
    if message:
        lines.extend([message.strip(), ""])
    lines.append("| iteration | kept | max_mm | mean_mm | rms_mm | clipped | gain_scale |")
    lines.append("|---:|:---:|---:|---:|---:|---:|---:|")
    for r in ordered:
        cells = [f"{_stat(r, k):.6f}" if math.isfinite(_stat(r, k)) else "–" for k in ("max", "mean", "rms")]
        it = f"**{r.iteration}**" if best is not None and r is best else str(r.iteration)
        lines.append(f"| {it} | {'yes' if r.kept else 'no'} | {' | '.join(cells)} | {int(r.clipped)} | "
                     f"{float(r.gain_scale):g} |")
    lines.append("")
    base = next((r for r in ordered if r.iteration == 0), ordered[0] if ordered else None)
    if best is not None and base is not None:
        lines.append(f"Best kept iteration: **{best.iteration}** (compared with iteration {base.iteration}).")
        lines.append("")
        lines.append(f"- RMS contour error {_reduction(_stat(base, 'rms'), _stat(best, 'rms'))}")
        lines.append(f"- max contour error {_reduction(_stat(base, 'max'), _stat(best, 'max'))}")
    else:
        lines.append("Best kept iteration: none.")
    lines.append("")
    corr = f", largest correction {max_corr_mm:.6f} mm" if n_changed and math.isfinite(max_corr_mm) else ""
    lines.append(f"Output program: {n_changed} end point(s) changed, {n_clipped} clipped to the correction bound{corr} "
                 "(see `commands.csv`).")
    lines.append("")
    for name in images:
        lines.append(f"![{name}]({name})")
        lines.append("")
    return "\n".join(lines)


def _commands(diff: CommandDiff) -> tuple[str, int, int, float]:
    """commands.csv text, number of changed and of clipped listed commands, largest correction (mm)."""
    k = np.asarray(diff.k, dtype=np.int64).ravel()
    count = k.size
    line = np.asarray(diff.line, dtype=np.int64).ravel()
    old = np.asarray(diff.old_mm, dtype=float)
    new = np.asarray(diff.new_mm, dtype=float)
    clipped = np.asarray(diff.clipped, dtype=bool).ravel()
    if line.size != count or clipped.size != count or old.shape != (count, 3) or new.shape != (count, 3):
        raise ValueError(f"CommandDiff: inconsistent shapes k {k.shape}, line {line.shape}, old_mm {old.shape}, "
                         f"new_mm {new.shape}, clipped {clipped.shape}")
    d = new - old
    fin_old, fin_new = np.isfinite(old), np.isfinite(new)
    with np.errstate(invalid="ignore"):
        moved = np.where(fin_old & fin_new, np.abs(d) > CHANGE_TOL_MM, fin_old != fin_new)
    changed = moved.any(axis=1)
    sel = np.flatnonzero(changed | clipped)
    sel = sel[np.argsort(k[sel], kind="stable")]
    corr = np.sqrt(np.sum(d[sel] ** 2, axis=1))
    data = np.empty((sel.size, 13))
    data[:, 0] = k[sel]
    data[:, 1] = line[sel]
    data[:, 2:5] = old[sel]
    data[:, 5:8] = new[sel]
    data[:, 8:11] = d[sel]
    data[:, 11] = corr
    data[:, 12] = clipped[sel]
    data[:, 2:12] = np.round(data[:, 2:12], 6) + 0.0  # no "-0.000000"
    row = "%d,%d," + "%.6f," * 10 + "%d\n"
    buf = io.StringIO()
    buf.write("k,line,x_old,y_old,z_old,x_new,y_new,z_new,dx,dy,dz,correction_mm,clipped\n")
    for s in _chunks(sel.size, 100_000):
        block = data[s]
        buf.write((row * block.shape[0]) % tuple(block.ravel().tolist()))
    with np.errstate(invalid="ignore"):
        max_corr = float(np.fmax.reduce(corr[changed[sel]])) if changed.any() else math.nan
    return buf.getvalue(), int(changed.sum()), int(clipped.sum()), max_corr


# --------------------------------------------------------------------------- entry point



#: The files a report folder receives (``NNN``: an iteration number); :func:`is_report_file` tells them.
REPORT_FILES = ("summary.csv", "summary.md", "commands.csv", "error-along-path.png", "error-vs-iteration.png",
                "refined-corner.png", "path-iterNNN.png", "error-iterNNN.png", "corrections.png",
                "corrections-zoom.png", "corrections-along-path.png", "report.html")
_REPORT_FILE = re.compile("|".join(re.escape(n).replace("NNN", r"\d{3,}") for n in REPORT_FILES))


def is_report_file(name: str) -> bool:
    """A report could write a file of this name (an input named so must not be in the report folder)."""
    return _REPORT_FILE.fullmatch(name) is not None

def write_report(out_dir: Path, *, program_name: str, path_mm: np.ndarray, runs: list[ReportRun], diff: CommandDiff,
                 magnify: float | None = None, status: str = "", message: str = "",
                 best_iteration: int | None = None, max_points: int = MAX_PLOT_POINTS) -> list[Path]:
    """Write the plots and tables of a learning run into ``out_dir``.

    Parameters
    ----------
    out_dir : Path
        Output directory; created when missing (its parent must exist).
    program_name : str
        Name of the part program, used in titles.
    path_mm : ndarray of shape (M, 3)
        Programmed path (feed moves) as a polyline, mm; NaN rows separate
        disjoint pieces (e.g. where a rapid is).
    runs : list of ReportRun
        One entry per iteration (distinct iteration numbers), in any order.
    diff : CommandDiff
        Per-command diff of the final (best) program.
    magnify : float, optional
        Magnification of the deviation ``actual - foot`` in the path plots.
        Default: a 1-2-5 factor making the largest error about 5 % of the
        part's extent in the plotted plane (at least 1).
    status, message : str
        Outcome of the learning loop, copied into ``summary.md``.
    best_iteration : int, optional
        The iteration whose program was written; default: the kept iteration
        with the smallest RMS error. Used for the reductions in ``summary.md``.
    max_points : int
        Largest number of points of one plotted line.

    Returns
    -------
    list of Path
        The files written, in the order written.

    Raises
    ------
    InputError
        The parent of ``out_dir`` does not exist, ``out_dir`` is not a
        directory or cannot be created, or ``magnify`` is not a positive number.
    ValueError
        Inconsistent array shapes or duplicate iteration numbers.
    """
    out_dir = Path(out_dir)
    parent = out_dir.parent if str(out_dir.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(out_dir, None, f"cannot create the report directory: {parent} does not exist")
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(out_dir, None, "report output exists and is not a directory")
    try:
        out_dir.mkdir(exist_ok=True)
    except OSError as exc:
        raise InputError(out_dir, None, f"cannot create the report directory: {exc.strerror}") from None
    if magnify is not None and not (math.isfinite(magnify) and magnify > 0):
        raise InputError(None, None, f"report magnification must be a positive number, got {magnify!r}")
    iterations = [int(r.iteration) for r in runs]
    if len(set(iterations)) != len(iterations):
        raise ValueError(f"duplicate iteration numbers in runs: {sorted(iterations)}")
    if any(i < 0 for i in iterations):
        raise ValueError("iteration numbers must not be negative")
    sizes = [_n_samples(r) for r in runs]
    path = np.asarray(path_mm, dtype=float)
    if path.ndim != 2 or path.shape[1] != 3:
        raise ValueError(f"path_mm has shape {path.shape}, expected (M, 3)")

    import matplotlib

    written: list[Path] = []

    def put(name: str, data: bytes | str) -> None:
        written.append(write_atomic(out_dir / name, data))

    ext = axis_extent(path)
    axes = plane_axes(ext)
    extent = float(max(ext[axes[0]], ext[axes[1]])) if ext.size else 0.0
    if magnify is None:
        errs = [_stat(r, "max") for r in runs if r.actual_mm is not None and r.foot_mm is not None]
        if errs and not any(math.isfinite(e) for e in errs):
            errs = []
            for r, n in zip(runs, sizes, strict=True):
                if r.actual_mm is not None and r.foot_mm is not None and r.contour_mm is not None and n:
                    with np.errstate(invalid="ignore"):
                        errs.append(float(np.fmax.reduce(np.asarray(r.contour_mm, dtype=float))))
        finite = [e for e in errs if math.isfinite(e)]
        magnify = auto_magnify(extent, max(finite)) if finite else 1.0
    path_2d = _decimate_polyline(path[:, list(axes)], max_points)

    rc = {"agg.path.chunksize": 20_000, "path.simplify": True, "path.simplify_threshold": 0.3}
    lines: list[tuple[ReportRun, np.ndarray, np.ndarray]] = []
    images: list[str] = []
    with matplotlib.rc_context(rc):
        for r, n in zip(runs, sizes, strict=True):
            if r.actual_mm is not None and n:
                put(f"path-iter{r.iteration:03d}.png",
                    _plot_path(r, n, path_2d, axes, magnify, program_name, max_points))
            if r.contour_mm is not None and r.path_pos_mm is not None and n:
                line = _error_line(r, n, max_points)
                put(f"error-iter{r.iteration:03d}.png", _plot_error(r, line, program_name))
                lines.append((r, line[0], line[1]))
        if lines:
            lines.sort(key=lambda t: t[0].iteration)
            put("error-along-path.png", _plot_error_all(lines, program_name))
            images.append("error-along-path.png")
        if runs:
            put("error-vs-iteration.png", _plot_vs_iteration(runs, program_name))
            images.insert(0, "error-vs-iteration.png")

    commands_text, n_changed, n_clipped, max_corr = _commands(diff)
    best = _best_run(runs, best_iteration)
    put("summary.csv", _summary_csv(runs))
    put("summary.md", _summary_md(runs, program_name=program_name, status=status, message=message, best=best,
                                  n_changed=n_changed, n_clipped=n_clipped, max_corr_mm=max_corr, images=images))
    put("commands.csv", commands_text)
    return written


def plot_refined_corner(*, program_name: str, path_mm: np.ndarray, first: ReportRun, best: ReportRun,
                        commands_mm: np.ndarray, inserted: NDArray[np.bool_], radius_mm: float = 1.0) -> bytes:
    """The worst spot of the first run, zoomed: the drawing, the refined and corrected end points (inserted
    ones marked), and the actual path of the first and the best run with their deviation magnified.

    Parameters
    ----------
    path_mm : ndarray (M, 3)
        The drawing as a polyline (NaN rows between pieces), mm.
    first, best : ReportRun
        The first run and the output's run, with actual positions, foot points and contour errors.
    commands_mm : ndarray (K, 3)
        End points of the output's commands (refined and corrected), mm.
    inserted : ndarray (K,) bool
        Which commands the refinement inserted.
    radius_mm : float
        Half the side of the zoomed square, mm.
    """
    assert first.actual_mm is not None and first.foot_mm is not None and first.contour_mm is not None
    e = np.where(_valid_mask(first.actual_mm.shape[0], first.feed_mask), first.contour_mm, np.nan)
    w = int(np.nanargmax(e))
    centre = first.foot_mm[w]
    ext = axis_extent(path_mm)
    a0, a1 = plane_axes(ext)
    worst = max(float(np.nanmax(e)), 1e-6)
    mag = auto_magnify(2.0 * radius_mm, worst) * 4.0  # the zoom: the deviation shows at ~20 % of the window

    def near(p: np.ndarray) -> NDArray[np.bool_]:
        return np.all(np.abs(p[:, [a0, a1]] - centre[[a0, a1]]) <= 1.5 * radius_mm, axis=1)

    fig = new_figure(7.5, 7.5)
    ax = fig.add_subplot()
    pm = path_mm.copy()
    pm[~near(np.nan_to_num(pm, nan=1e9))] = np.nan
    ax.plot(pm[:, a0], pm[:, a1], color="0.25", lw=1.0, label="drawing")
    for run, colour, name in ((first, "C0", "first run"), (best, "C3", f"iteration {best.iteration}")):
        if run.actual_mm is None or run.foot_mm is None:
            continue
        sel = near(run.foot_mm) & _valid_mask(run.actual_mm.shape[0], run.feed_mask)
        f = run.foot_mm[sel]
        a = f + mag * (run.actual_mm[sel] - f)
        ax.plot(a[:, a0], a[:, a1], ".", ms=1.5, color=colour, label=f"{name}: actual, deviation ×{format_factor(mag)}")
    c = near(commands_mm)
    ax.plot(commands_mm[c & ~inserted, a0], commands_mm[c & ~inserted, a1], "s", ms=5, mfc="none", mec="0.1",
            label="end points of the program")
    ax.plot(commands_mm[c & inserted, a0], commands_mm[c & inserted, a1], "x", ms=7, mew=1.5, color="C2",
            label="inserted by the refinement")
    ax.set_xlim(centre[a0] - radius_mm, centre[a0] + radius_mm)
    ax.set_ylim(centre[a1] - radius_mm, centre[a1] + radius_mm)
    ax.set_aspect("equal")
    ax.set_xlabel(f"{_AXES[a0]} / mm")
    ax.set_ylabel(f"{_AXES[a1]} / mm")
    ax.grid(True, lw=0.4, alpha=0.5)
    fig.legend(loc="outside lower center", ncols=2, fontsize="small")
    ax.set_title(f"{program_name}: the first run's worst spot ({1000.0 * worst:.2f} µm), zoomed\n"
                 f"first {_stats_text(first)}\niteration {best.iteration}: {_stats_text(best)}", fontsize="small")
    return figure_png(fig)
