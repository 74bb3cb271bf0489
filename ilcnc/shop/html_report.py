"""``report.html``: one self-contained page of a learning run, to mail around.

:func:`render_html` builds the page from figures (PNG bytes, embedded as
base64 ``data:`` URIs), the iteration table, the worst commands with their
source lines, and the program diff (:class:`ilcnc.shop.diff.ProgramDiff`).
The page has inline CSS only: no script, no external URL, no server; it reads
the same in a mail client's viewer as in a browser. Every text from a program
or a path is HTML-escaped (a comment may hold ``<`` or ``&``).

A 10,000-command program changes thousands of lines: the diff lists the
:data:`DIFF_ROWS` largest corrections (in program order) and the first
:data:`INSERTED_ROWS` inserted lines, and the page says how many it left out
and which command lists them all.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ilcnc.shop.diff import ProgramDiff

__all__ = ["DIFF_ROWS", "INSERTED_ROWS", "HtmlFigure", "HtmlReport", "IterationRow", "WorstRow", "render_html"]

#: Changed lines the page lists (the largest corrections).
DIFF_ROWS = 200
#: Inserted lines the page lists (the first ones).
INSERTED_ROWS = 100

_CSS = """
body { font-family: sans-serif; font-size: 14px; margin: 16px; color: #111; background: #fff; }
h1 { font-size: 20px; } h2 { font-size: 17px; margin-top: 28px; border-bottom: 1px solid #999; }
table { border-collapse: collapse; margin: 8px 0; }
th, td { border: 1px solid #bbb; padding: 2px 6px; vertical-align: top; }
th { background: #eee; } td.n { text-align: right; font-variant-numeric: tabular-nums; }
td.code { font-family: monospace; white-space: pre; }
tr.best td { font-weight: bold; } tr.dropped td { color: #777; }
figure { margin: 12px 0; } img { display: block; max-width: none; }
figcaption { font-size: 13px; color: #333; max-width: 900px; }
p.warn { color: #a00; font-weight: bold; } p.note { color: #333; }
"""


@dataclass(frozen=True, slots=True, kw_only=True)
class IterationRow:
    """One row of the iteration table (figures in mm, printed in µm).

    Attributes
    ----------
    iteration : int
    status : str
        ``kept``, ``not kept``, ``not measured yet``.
    cutting_mm : tuple of float or None
        Cutting moves' (max, mean, RMS) contour error, mm.
    air_max_mm : float or None
        Air moves' largest error, mm.
    cycle_time_s : float or None
    clipped : int
    gain_scale : float
    measured_from : str
        ``virtual``, ``log``, ``points`` or empty.
    best : bool
        The run's best kept iteration.
    output : bool
        The iteration the figures and the diff show.
    """

    iteration: int
    status: str
    cutting_mm: tuple[float, float, float] | None
    air_max_mm: float | None
    cycle_time_s: float | None
    clipped: int
    gain_scale: float
    measured_from: str
    best: bool = False
    output: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class WorstRow:
    """A command of the worst-commands table.

    Attributes
    ----------
    k : int
        Command index.
    line : int
        1-based source line.
    text : str
        The source line as written.
    error_first_um, error_best_um : float
        ``|E(k)|`` of the first and the best measured iteration, µm (NaN: not measured).
    correction_um : ndarray (3,)
        ΔX ΔY ΔZ of its end point in the output, µm.
    air : bool
        An air command.
    """

    k: int
    line: int
    text: str
    error_first_um: float
    error_best_um: float
    correction_um: NDArray[np.float64]
    air: bool = False


@dataclass(frozen=True, slots=True)
class HtmlFigure:
    """A PNG with its file name and a caption."""

    name: str
    caption: str
    png: bytes


@dataclass(frozen=True, slots=True, kw_only=True)
class HtmlReport:
    """Everything the page shows.

    Attributes
    ----------
    program_name : str
    facts : list of (str, str)
        Label and value lines at the top (status, state, output, cutting rule ...).
    iterations : list of IterationRow
    figures : list of HtmlFigure
    worst : list of WorstRow
    worst_note : str
        How the worst commands were chosen.
    diff : ProgramDiff or None
        The program diff of the output against the original.
    diff_command : str
        The command that lists the full diff.
    notes : list of str
        Further lines, one paragraph each.
    """

    program_name: str
    facts: list[tuple[str, str]]
    iterations: list[IterationRow]
    figures: list[HtmlFigure]
    worst: list[WorstRow]
    worst_note: str
    diff: ProgramDiff | None
    diff_command: str = ""
    notes: list[str] = field(default_factory=list)


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _um(v: float | None, digits: int = 2) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _iteration_table(rows: Sequence[IterationRow]) -> list[str]:
    out = ['<table id="iterations">',
           "<tr><th>iteration</th><th>status</th><th>cutting max µm</th><th>cutting mean µm</th>"
           "<th>cutting RMS µm</th><th>air max µm</th><th>cycle s</th><th>clipped</th><th>gain scale</th>"
           "<th>measured</th></tr>"]
    for r in rows:
        cut = r.cutting_mm or (math.nan, math.nan, math.nan)
        cls = "best" if r.best else "dropped" if r.status == "not kept" else ""
        tags = [t for t, on in (("best", r.best), ("shown", r.output)) if on]
        label = f"{r.iteration}" + (f" ({', '.join(tags)})" if tags else "")
        air = None if r.air_max_mm is None else 1000.0 * r.air_max_mm
        cyc = "–" if r.cycle_time_s is None else f"{r.cycle_time_s:.2f}"
        out.append(f'<tr class="{cls}"><td class="n">{_e(label)}</td><td>{_e(r.status)}</td>'
                   + "".join(f'<td class="n">{_um(1000.0 * v)}</td>' for v in cut)
                   + f'<td class="n">{_um(air)}</td><td class="n">{cyc}</td><td class="n">{r.clipped}</td>'
                   f'<td class="n">{r.gain_scale:g}</td><td>{_e(r.measured_from)}</td></tr>')
    out.append("</table>")
    return out


def _worst_table(rows: Sequence[WorstRow]) -> list[str]:
    out = ['<table id="worst">',
           "<tr><th>line</th><th>k</th><th>source line</th><th>|E| first µm</th><th>|E| best µm</th>"
           "<th>ΔX µm</th><th>ΔY µm</th><th>ΔZ µm</th><th>|Δ| µm</th></tr>"]
    for r in rows:
        d = np.asarray(r.correction_um, float)
        air = " (air)" if r.air else ""
        out.append(f'<tr><td class="n">{r.line}</td><td class="n">{r.k}{air}</td><td class="code">{_e(r.text)}</td>'
                   f'<td class="n">{_um(r.error_first_um)}</td><td class="n">{_um(r.error_best_um)}</td>'
                   + "".join(f'<td class="n">{_um(float(v), 3)}</td>' for v in d)
                   + f'<td class="n">{_um(float(np.linalg.norm(d)), 3)}</td></tr>')
    out.append("</table>")
    return out


def _diff_section(diff: ProgramDiff, command: str) -> list[str]:
    changed = diff.changed
    corrected = diff.corrected
    out = [f"<p>{len(changed)} line(s) changed ({len(corrected)} with a moved end point), {len(diff.inserted)}"
           f" inserted, {len(diff.removed)} removed; original {diff.lines_original} lines, output"
           f" {diff.lines_output}.</p>"]
    if diff.breaches:
        out.append(f'<p class="warn">CONTRACT BREACH: {len(diff.breaches)} change(s) besides coordinates, arc centres,'
                   " feeds and marked inserted lines:</p><ul>")
        out.extend(f"<li>{_e(b)}</li>" for b in diff.breaches[:50])
        out.append("</ul>")

    def size(c: object) -> float:
        d = getattr(c, "delta_mm", None)
        return -1.0 if d is None else float(np.linalg.norm(d))

    shown = sorted(changed, key=size, reverse=True)[:DIFF_ROWS]
    shown.sort(key=lambda c: c.line)
    if len(changed) > len(shown):
        out.append(f'<p class="note">Listed: the {len(shown)} changed lines with the largest corrections, in program'
                   f" order; {len(changed) - len(shown)} more changed lines are not listed"
                   f"{' (all: ' + _e(command) + ')' if command else ''}.</p>")
    out.append('<table id="diff"><tr><th>line</th><th>out line</th><th>original</th><th>output</th><th>ΔX µm</th>'
               "<th>ΔY µm</th><th>ΔZ µm</th><th>|Δ| µm</th></tr>")
    for c in shown:
        d = c.delta_um
        cells = (["–"] * 4 if d is None else [_um(float(v), 3) for v in d] + [_um(float(np.linalg.norm(d)), 3)])
        out.append(f'<tr><td class="n">{c.line}</td><td class="n">{c.out_line}</td><td class="code">{_e(c.old)}</td>'
                   f'<td class="code">{_e(c.new)}</td>' + "".join(f'<td class="n">{v}</td>' for v in cells) + "</tr>")
    out.append("</table>")
    if diff.inserted:
        ins = diff.inserted[:INSERTED_ROWS]
        out.append(f"<h3>Inserted lines ({len(diff.inserted)})</h3>")
        if len(diff.inserted) > len(ins):
            out.append(f'<p class="note">Listed: the first {len(ins)}; {len(diff.inserted) - len(ins)} more are not'
                       " listed.</p>")
        out.append('<table id="inserted"><tr><th>out line</th><th>before line</th><th>text</th></tr>')
        for i in ins:
            before = "end" if i.before_line is None else str(i.before_line)
            out.append(f'<tr><td class="n">{i.out_line}</td><td class="n">{before}</td>'
                       f'<td class="code">{_e(i.text)}</td></tr>')
        out.append("</table>")
    return out


def render_html(report: HtmlReport) -> str:
    """The page (UTF-8 text) of ``report``."""
    name = _e(report.program_name)
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           f"<title>ilcnc learning report: {name}</title>", f"<style>{_CSS}</style></head><body>",
           f"<h1>ilcnc learning report: {name}</h1>", '<table id="facts">']
    out.extend(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in report.facts)
    out.append("</table>")
    out.extend(f'<p class="note">{_e(n)}</p>' for n in report.notes)
    out.append("<h2>Iterations</h2>")
    out.append('<p class="note">Contour error of the cutting moves; the air moves (feed moves above the stock top)'
               " apart. A greyed row was not kept by the guard.</p>")
    out.extend(_iteration_table(report.iterations))
    out.append("<h2>Figures</h2>")
    for f in report.figures:
        data = base64.b64encode(f.png).decode("ascii")
        out.append(f'<figure id="{_e(f.name)}"><img src="data:image/png;base64,{data}" alt="{_e(f.name)}">'
                   f"<figcaption>{_e(f.name)}: {_e(f.caption)}</figcaption></figure>")
    out.append("<h2>Worst commands</h2>")
    out.append(f'<p class="note">{_e(report.worst_note)}</p>')
    out.extend(_worst_table(report.worst))
    out.append("<h2>Program diff</h2>")
    if report.diff is None:
        out.append("<p>No rewritten program yet.</p>")
    else:
        out.extend(_diff_section(report.diff, report.diff_command))
    out.append("</body></html>")
    return "\n".join(out) + "\n"
