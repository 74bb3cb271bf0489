"""Probe height maps of the G-code senders: bCNC, Candle, OpenCNCPilot and the cncjs autolevel extension.

Each sender probes the stock's top surface on a rectangular grid and saves the probed Z values. The layouts
(read from each sender's own writer, docs/probemaps.md):

* **bCNC** (``.probe``, ``Probe.save`` in ``bCNC/CNC.py``): three header lines ``xmin xmax xn``,
  ``ymin ymax yn``, ``zmin zmax feed``, then ``yn`` rows of ``xn`` lines ``x y z`` (y outer, x inner,
  a blank line after each row). Its ``.xyz`` save is the same points without the header.
* **Candle** (``.map``, ``frmMain::saveHeightMap``): ``candle map v3``; ``x;y;width;height`` of the probed
  rectangle; ``originX;originY`` (where the first probe zeroes the map); ``pointsX;pointsY;zBottom;zTop;feed``;
  ``interpolation;stepX;stepY``; then ``pointsY`` rows of ``pointsX`` values ``z;z;...`` (row i at
  ``y + i * height / (pointsY - 1)``). Values in mm, relative to the probe at the origin.
* **OpenCNCPilot** (``.hmap``, ``HeightMap.Save``): XML ``<heightmap MinX MinY MaxX MaxY SizeX SizeY>``
  with one ``<point X="i" Y="j">z</point>`` per probed grid node (x outer, y inner).
* **cncjs autolevel** (``__last_Z_probe.txt`` of ``kreso-t/cncjs-kt-ext``, ``(PROBEOPEN file)``): one line
  ``x y z 0 0 0 0 0 0`` per probe in work coordinates, LinuxCNC's probe-file layout; the points lie on a
  grid (rows in y, the first probe at (xmin, ymin) is where the extension sets Z zero). LinuxCNC's own
  ``PROBEOPEN`` files and bCNC's ``.xyz`` read the same way.

A map is returned as :class:`HeightMap`: grid coordinates and heights in mm, and the point whose height
the sender takes as zero (``reference_xy_mm``; None when the map holds heights relative to the Z zero the
machine had while probing, as bCNC and OpenCNCPilot apply them).
"""

from __future__ import annotations

import hashlib
import math
import re
import xml.parsers.expat
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.log import decode_text
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes

__all__ = ["HEIGHT_MAP_FORMATS", "HeightMap", "detect_height_map", "read_height_map"]

#: The sender formats :func:`read_height_map` reads.
HEIGHT_MAP_FORMATS = ("bcnc", "candle", "opencncpilot", "xyz")

#: Probes of a point list closer than this in x (or y), mm, are one grid column (row): the senders write the
#: machine's probe position, which is quantised to its steps (Grbl reports 3 decimals).
GRID_SNAP_MM = 0.01

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


@dataclass(frozen=True, slots=True)
class HeightMap:
    """A probed surface on a rectangular grid.

    Attributes
    ----------
    path : Path
        The file read.
    fmt : str
        One of :data:`HEIGHT_MAP_FORMATS`.
    x_mm : ndarray (nx,)
        Grid columns, increasing, mm (work coordinates of the probing).
    y_mm : ndarray (ny,)
        Grid rows, increasing, mm.
    z_mm : ndarray (ny, nx)
        Probed surface height at each node, mm (row j at ``y_mm[j]``).
    reference_xy_mm : tuple of float or None
        The point where the sender's map is zero (Candle's origin, the autolevel extension's first probe);
        None: the heights are relative to the Z zero the machine had while probing.
    sha256 : str
        Hash of the file's bytes (what the output's marker names).
    """

    path: Path
    fmt: str
    x_mm: NDArray[np.float64]
    y_mm: NDArray[np.float64]
    z_mm: NDArray[np.float64]
    reference_xy_mm: tuple[float, float] | None
    sha256: str

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx)."""
        return int(self.z_mm.shape[0]), int(self.z_mm.shape[1])


def _num(p: Path, line: int, text: str, what: str) -> float:
    t = text.strip()
    if not _NUMBER.match(t):
        if t.lower() in ("nan", "+nan", "-nan", "inf", "-inf", "+inf", "infinity", "-infinity"):
            raise InputError(p, line, f"{what} is not a finite number ({t!r})")
        raise InputError(p, line, f"{what}: {'empty value' if not t else repr(t) + ' is not a number'}")
    return float(t)


def _count(p: Path, line: int, text: str, what: str) -> int:
    v = _num(p, line, text, what)
    if v != int(v) or v < 2:
        raise InputError(p, line, f"{what} must be a whole number of grid points >= 2, got {text.strip()}")
    return int(v)


def _axis(p: Path, line: int, lo: float, hi: float, n: int, what: str) -> NDArray[np.float64]:
    if not hi > lo:
        raise InputError(p, line, f"{what}: the grid's end {hi:g} must be above its start {lo:g}")
    return lo + (hi - lo) * np.arange(n) / (n - 1)


def _content(text: str) -> list[tuple[int, str]]:
    return [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines()) if ln.strip()]


def detect_height_map(path: str | Path, data: bytes | None = None) -> str | None:
    """The sender format of a height-map file, or None when it is not one (a points CSV, say).

    By content: Candle's signature line, OpenCNCPilot's ``<heightmap`` element, bCNC's three-line header
    (``xmin xmax xn`` ...), or lines of three or more space-separated numbers (a point list); the suffix
    ``.probe`` (bCNC), ``.map`` (Candle) or ``.hmap`` (OpenCNCPilot) names the format of a file whose
    content is damaged, so that its error says what is wrong rather than that the file is no map.
    """
    p = Path(path)
    raw = read_bytes(p) if data is None else data
    text = decode_text(raw[:4096])
    head = [ln for _i, ln in _content(text)][:4]
    suffix = p.suffix.lower()
    if head and head[0].lower().startswith("candle map"):
        return "candle"
    if "<heightmap" in text:
        return "opencncpilot"
    if suffix in (".probe", ".map", ".hmap"):
        return {".probe": "bcnc", ".map": "candle", ".hmap": "opencncpilot"}[suffix]
    rows = [ln.split() for ln in head]
    if len(rows) >= 3 and all(len(r) == 3 and all(_NUMBER.match(c) for c in r) for r in rows[:3]):
        n1, n2 = float(rows[0][2]), float(rows[1][2])
        if n1 == int(n1) >= 2 and n2 == int(n2) >= 2 and (len(rows) < 4 or len(rows[3]) == 3):
            # bCNC's header: two grid counts; a point list's third column is a height (a count only by chance)
            body = [ln for _i, ln in _content(decode_text(raw))][3:]
            if len(body) == int(n1) * int(n2):
                return "bcnc"
    if rows and all(len(r) >= 3 and all(_NUMBER.match(c) for c in r[:3]) for r in rows):
        return "xyz"
    return None


def read_height_map(path: str | Path) -> HeightMap:
    """Read a sender's probe height map (format by content, see :func:`detect_height_map`).

    Parameters
    ----------
    path : str or Path
        The map file.

    Returns
    -------
    HeightMap

    Raises
    ------
    InputError
        Not a height map, or a malformed one: a short or ragged grid, a value that is no number or is NaN /
        infinite, a point off the grid or given twice, a grid node without a probe (line named).
    """
    p = Path(path)
    raw = read_bytes(p)
    fmt = detect_height_map(p, raw)
    if fmt is None:
        raise InputError(p, None, "is no probe height map (bCNC .probe, Candle .map, OpenCNCPilot XML or x y z lines)")
    text = decode_text(raw)
    sha = hashlib.sha256(raw).hexdigest()
    if fmt == "candle":
        x, y, z, ref = _read_candle(p, text)
    elif fmt == "opencncpilot":
        x, y, z, ref = _read_opencncpilot(p, raw)
    elif fmt == "bcnc":
        x, y, z, ref = _read_bcnc(p, text)
    else:
        x, y, z, ref = _read_xyz(p, text)
    return HeightMap(p, fmt, x, y, z, ref, sha)


_Grid = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], "tuple[float, float] | None"]


def _read_bcnc(p: Path, text: str) -> _Grid:
    lines = _content(text)
    if len(lines) < 3:
        raise InputError(p, None, "bCNC probe file: expected the header lines xmin xmax xn, ymin ymax yn, zmin zmax feed")
    head = []
    for (ln, t), what in zip(lines[:3], ("x", "y", "z"), strict=True):
        cells = t.split()
        if len(cells) != 3:
            raise InputError(p, ln, f"bCNC probe header: expected 3 numbers ({what}min {what}max ...), got {len(cells)}")
        head.append([_num(p, ln, c, f"header {what}") for c in cells])
    nx = _count(p, lines[0][0], lines[0][1].split()[2], "xn")
    ny = _count(p, lines[1][0], lines[1][1].split()[2], "yn")
    body = lines[3:]
    if len(body) != nx * ny:
        where = body[-1][0] if body else lines[2][0]
        raise InputError(p, where, f"bCNC probe file: {len(body)} points for a {nx} x {ny} grid (expected {nx * ny}):"
                         " a ragged or truncated grid")
    xs = _axis(p, lines[0][0], head[0][0], head[0][1], nx, "x")
    ys = _axis(p, lines[1][0], head[1][0], head[1][1], ny, "y")
    z = np.empty((ny, nx))
    step = (xs[1] - xs[0], ys[1] - ys[0])
    for k, (ln, t) in enumerate(body):
        cells = t.split()
        if len(cells) != 3:
            raise InputError(p, ln, f"expected x y z, got {len(cells)} values")
        px, py, pz = (_num(p, ln, c, w) for c, w in zip(cells, "xyz", strict=True))
        j, i = divmod(k, nx)
        # bCNC's own loader drops a point farther than a tenth of a step from its node
        if abs(px - xs[i]) > step[0] / 10 or abs(py - ys[j]) > step[1] / 10:
            raise InputError(p, ln, f"point ({px:g}, {py:g}) is not grid node ({xs[i]:g}, {ys[j]:g}) of row {j + 1},"
                             f" column {i + 1}: rows must run in y, points in x")
        z[j, i] = pz
    return xs, ys, z, None


def _read_candle(p: Path, text: str) -> _Grid:
    lines = _content(text)
    if not lines[0][1].lower() == "candle map v3":
        raise InputError(p, lines[0][0], f"Candle map: expected the signature 'candle map v3', got {lines[0][1]!r}")
    if len(lines) < 5:
        raise InputError(p, None, "Candle map: expected 4 header lines after the signature (border, origin, grid,"
                         " interpolation)")

    def fields(k: int, n: int, what: str) -> list[float]:
        ln, t = lines[k]
        cells = t.split(";")
        if len(cells) < n:
            raise InputError(p, ln, f"Candle map {what}: expected {n} values separated by ';', got {len(cells)}")
        return [_num(p, ln, c, what) for c in cells[:n]]

    bx, by, bw, bh = fields(1, 4, "border")
    ox, oy = fields(2, 2, "origin")
    grid_ln, grid_t = lines[3]
    fields(3, 5, "grid")
    nx = _count(p, grid_ln, grid_t.split(";")[0], "grid points in X")
    ny = _count(p, grid_ln, grid_t.split(";")[1], "grid points in Y")
    fields(4, 3, "interpolation")
    body = lines[5:]
    if len(body) != ny:
        where = body[-1][0] if body else lines[4][0]
        raise InputError(p, where, f"Candle map: {len(body)} rows for {ny} grid points in Y: a ragged or truncated grid")
    if len(body[0][1].split(";")) != nx:
        raise InputError(p, body[0][0], f"Candle map row 1: {len(body[0][1].split(';'))} values for {nx} grid points"
                         " in X (ragged grid)")
    xs = _axis(p, lines[1][0], bx, bx + bw, nx, "border x")
    ys = _axis(p, lines[1][0], by, by + bh, ny, "border y")
    z = np.empty((ny, nx))
    for j, (ln, t) in enumerate(body):
        cells = t.split(";")
        if len(cells) != nx:
            raise InputError(p, ln, f"Candle map row {j + 1}: {len(cells)} values for {nx} grid points in X (ragged grid)")
        z[j] = [_num(p, ln, c, f"row {j + 1} value {i + 1}") for i, c in enumerate(cells)]
    return xs, ys, z, (ox, oy)


def _read_opencncpilot(p: Path, raw: bytes) -> _Grid:
    head: dict[str, str] = {}
    head_line = [0]
    points: list[tuple[int, str, str, list[str]]] = []
    current: list[str] | None = None

    def start(name: str, attrs: dict[str, str]) -> None:
        nonlocal current
        if name == "heightmap":
            head.update(attrs)
            head_line[0] = parser.CurrentLineNumber
        elif name == "point":
            current = []
            points.append((parser.CurrentLineNumber, attrs.get("X", ""), attrs.get("Y", ""), current))

    def end(name: str) -> None:
        nonlocal current
        if name == "point":
            current = None

    def chars(data: str) -> None:
        if current is not None:
            current.append(data)

    parser = xml.parsers.expat.ParserCreate()
    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    try:
        parser.Parse(raw, True)
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(p, exc.lineno, f"OpenCNCPilot height map: broken XML ({xml.parsers.expat.ErrorString(exc.code)})"
                         ) from None
    if not head:
        raise InputError(p, None, "OpenCNCPilot height map: no <heightmap> element")
    hl = head_line[0]
    vals = {}
    for key in ("MinX", "MinY", "MaxX", "MaxY", "SizeX", "SizeY"):
        if key not in head:
            raise InputError(p, hl, f"OpenCNCPilot height map: <heightmap> lacks the attribute {key}")
        vals[key] = _num(p, hl, head[key], key)
    nx = _count(p, hl, head["SizeX"], "SizeX")
    ny = _count(p, hl, head["SizeY"], "SizeY")
    seen: dict[tuple[int, int], int] = {}
    height: dict[tuple[int, int], float] = {}
    for ln, sx, sy, body in points:
        i = _num(p, ln, sx, "point X index")
        j = _num(p, ln, sy, "point Y index")
        if i != int(i) or j != int(j) or not (0 <= i < nx and 0 <= j < ny):
            raise InputError(p, ln, f"point index ({sx}, {sy}) is outside the {nx} x {ny} grid")
        key = (int(i), int(j))
        if key in seen:
            raise InputError(p, ln, f"point ({key[0]}, {key[1]}) given twice (first on line {seen[key]})")
        seen[key] = ln
        height[key] = _num(p, ln, "".join(body), f"height of point ({key[0]}, {key[1]})")
    if len(height) < nx * ny:  # before any array of the grid's size: a damaged SizeX must not take the memory
        first = next(((i, j) for i in range(nx) for j in range(ny) if (i, j) not in height), (0, 0))
        raise InputError(p, None, f"OpenCNCPilot height map: {nx * ny - len(height)} of {nx * ny} grid points not"
                         f" probed (first: X={first[0]} Y={first[1]}); finish the probing in OpenCNCPilot")
    xs = _axis(p, hl, vals["MinX"], vals["MaxX"], nx, "MinX/MaxX")
    ys = _axis(p, hl, vals["MinY"], vals["MaxY"], ny, "MinY/MaxY")
    z = np.empty((ny, nx))
    for (i, j), v in height.items():
        z[j, i] = v
    return xs, ys, z, None


def _clusters(p: Path, v: NDArray[np.float64], what: str) -> NDArray[np.float64]:
    """The distinct grid coordinates of point coordinates ``v`` (values within :data:`GRID_SNAP_MM` are one)."""
    s = np.sort(v)
    cut = np.flatnonzero(np.diff(s) > GRID_SNAP_MM) + 1
    groups = np.split(s, cut)
    for g in groups:
        if g[-1] - g[0] > 2 * GRID_SNAP_MM:
            raise InputError(p, None, f"probe points: {what} values from {g[0]:g} to {g[-1]:g} mm form no grid line"
                             f" (steps below {GRID_SNAP_MM} mm)")
    return np.array([g.mean() for g in groups])


def _read_xyz(p: Path, text: str) -> _Grid:
    rows = _content(text)
    pts = np.empty((len(rows), 3))
    lines = np.empty(len(rows), dtype=np.int64)
    for k, (ln, t) in enumerate(rows):
        cells = t.split()
        if len(cells) < 3:
            raise InputError(p, ln, f"expected x y z (and optionally 6 more values), got {len(cells)} values")
        pts[k] = [_num(p, ln, c, w) for c, w in zip(cells[:3], "xyz", strict=True)]
        lines[k] = ln
    xs = _clusters(p, pts[:, 0], "x")
    ys = _clusters(p, pts[:, 1], "y")
    if xs.size < 2 or ys.size < 2:
        raise InputError(p, None, f"probe points span {xs.size} x {ys.size} grid lines: a height map needs at least 2 x 2")
    i = np.abs(pts[:, 0][:, None] - xs[None, :]).argmin(axis=1)
    j = np.abs(pts[:, 1][:, None] - ys[None, :]).argmin(axis=1)
    z = np.full((ys.size, xs.size), math.nan)
    first: dict[tuple[int, int], int] = {}
    for k in range(len(rows)):
        key = (int(j[k]), int(i[k]))
        if key in first:
            raise InputError(p, int(lines[k]), f"probe point ({pts[k, 0]:g}, {pts[k, 1]:g}) given twice (first on line"
                             f" {first[key]})")
        first[key] = int(lines[k])
        z[key] = pts[k, 2]
    missing = np.argwhere(np.isnan(z))
    if missing.size:
        jj, ii = (int(v) for v in missing[0])
        raise InputError(p, None, f"probe points are no full grid: {missing.shape[0]} of {xs.size * ys.size} nodes"
                         f" without a probe (first: x={xs[ii]:g} y={ys[jj]:g}); a ragged grid")
    if p.suffix.lower() == ".xyz":  # bCNC's header-less save: heights as bCNC applies them
        return xs, ys, z, None
    # the autolevel extension (and a LinuxCNC probing routine) zero Z at the first probe
    return xs, ys, z, (float(pts[0, 0]), float(pts[0, 1]))
