"""Write the shipped probe height maps (samples/own/probemaps/) as each sender writes its file.

    python bench/probemaps.py            # (re)write samples/own/probemaps/*
    python bench/probemaps.py --check    # exit 1 when a shipped file differs from what this script writes

The layouts follow the senders' own writers (docs/probemaps.md): bCNC ``Probe.save``, Candle
``frmMain::saveHeightMap``, OpenCNCPilot ``HeightMap.Save`` and the cncjs autolevel extension's probe file.
Two surfaces over the extent of samples/third_party/contour/Gates_combined_R12.nc (X 0..142, Y 0..115 mm):
a tilted plane and a warped sheet, in mm, heights relative to the work Z zero at X0 Y0 (where the user
touched off before probing).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "samples" / "own" / "probemaps"

#: The probed rectangle (mm) and its grid: 16 x 13 probes, 10 mm apart.
X0, X1, NX = -5.0, 145.0, 16
Y0, Y1, NY = -5.0, 115.0, 13


def tilt(x: float, y: float) -> float:
    """A stock top tilted 0.4 mm over 150 mm in X and -0.2 mm over 120 mm in Y, mm."""
    return 0.4 * x / 150.0 - 0.2 * y / 120.0


def warp(x: float, y: float) -> float:
    """A warped sheet (a PCB blank off its vacuum table): a saddle and a bulge of about 0.1 mm, mm."""
    return 0.06 * math.sin(2 * math.pi * x / 120.0) * math.cos(2 * math.pi * y / 100.0) + 0.0004 * x


SURFACES: dict[str, Callable[[float, float], float]] = {"tilt": tilt, "warp": warp}


def _js(v: float) -> str:
    """A number as JavaScript's ``${v}`` prints it (shortest round trip, no '.0' on whole numbers)."""
    if v == 0:
        return "0"
    if v == int(v) and abs(v) < 1e21:
        return str(int(v))
    return repr(v)


Grid = tuple[float, float, int, float, float, int]
#: The shipped maps' grid: (xmin, xmax, nx, ymin, ymax, ny), mm.
GRID: Grid = (X0, X1, NX, Y0, Y1, NY)


def _grid(g: Grid) -> tuple[list[float], list[float]]:
    x0, x1, nx, y0, y1, ny = g
    xs = [x0 + (x1 - x0) * i / (nx - 1) for i in range(nx)]
    ys = [y0 + (y1 - y0) * j / (ny - 1) for j in range(ny)]
    return xs, ys


def bcnc(f: Callable[[float, float], float], g: Grid = GRID) -> bytes:
    """bCNC ``Probe.save``: ``xmin xmax xn``, ``ymin ymax yn``, ``zmin zmax feed``, two blank lines, then per row
    of y the points ``x y z`` (``%g``) and a blank line. Heights: work Z of the probed surface."""
    xs, ys = _grid(g)
    x0, x1, nx, y0, y1, ny = g
    out = [f"{x0:g} {x1:g} {nx}\n", f"{y0:g} {y1:g} {ny}\n", f"{-1.0:g} {3.0:g} {10.0:g}\n", "\n\n"]
    for y in ys:
        for x in xs:
            out.append(f"{x:g} {y:g} {round(f(x, y), 6):g}\n")
        out.append("\n")
    return "".join(out).encode()


def candle(f: Callable[[float, float], float], g: Grid = GRID) -> bytes:
    """Candle ``saveHeightMap`` (v3, CR LF): the border (spin boxes, 3 decimals), the origin, the grid, the
    interpolation, then rows of ``z;z;...`` relative to the first probe, made at the origin (X0 Y0)."""
    xs, ys = _grid(g)
    x0, x1, nx, y0, y1, ny = g
    z0 = f(0.0, 0.0)
    lines = ["candle map v3", f"{x0:.3f};{y0:.3f};{x1 - x0:.3f};{y1 - y0:.3f}", "0.000;0.000",
             f"{nx};{ny};-1.000;3.000;10", f"0;{4 * nx};{4 * ny}"]
    for y in ys:
        lines.append(";".join(_js(round(f(x, y) - z0, 6)) for x in xs))
    return ("\r\n".join(lines) + "\r\n").encode()


def opencncpilot(f: Callable[[float, float], float], g: Grid = GRID) -> bytes:
    """OpenCNCPilot ``HeightMap.Save``: .NET's indented XmlWriter (UTF-8 with BOM, CR LF), one ``point`` per node,
    x outer, y inner. Heights: work Z of the probed surface."""
    xs, ys = _grid(g)
    x0, x1, nx, y0, y1, ny = g
    lines = ['<?xml version="1.0" encoding="utf-8"?>',
             f'<heightmap MinX="{_js(x0)}" MinY="{_js(y0)}" MaxX="{_js(x1)}" MaxY="{_js(y1)}" SizeX="{nx}" SizeY="{ny}">']
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            lines.append(f'  <point X="{i}" Y="{j}">{_js(round(f(x, y), 6))}</point>')
    lines.append("</heightmap>")
    return b"\xef\xbb\xbf" + "\r\n".join(lines).encode()


def cncjs(f: Callable[[float, float], float], g: Grid = GRID) -> bytes:
    """cncjs-kt-ext's probe file (``__last_Z_probe.txt``): ``x y z 0 0 0 0 0 0`` per probe in probing order, the
    first at (xmin, ymin) where the extension zeroes Z (``G10 L20 P1 Z0``), then rows of y, x rising."""
    xs, ys = _grid(g)
    z0 = f(xs[0], ys[0])
    out = []
    for y in ys:
        for x in xs:
            out.append(f"{_js(x)} {_js(y)} {_js(round(f(x, y) - z0, 6))} 0 0 0 0 0 0\n")
    return "".join(out).encode()


WRITERS: dict[str, tuple[str, Callable[..., bytes]]] = {
    "bcnc": (".probe", bcnc), "candle": (".map", candle), "opencncpilot": (".hmap", opencncpilot),
    "cncjs": ("_probe.txt", cncjs),
}


def files() -> dict[str, bytes]:
    """Every shipped map: name -> content."""
    out = {}
    for sname, f in SURFACES.items():
        for wname, (suffix, write) in WRITERS.items():
            out[f"gates_{sname}_{wname}{suffix}"] = write(f)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare with the shipped files instead of writing them")
    args = ap.parse_args(argv)
    bad = 0
    OUT.mkdir(parents=True, exist_ok=True)
    for name, data in files().items():
        p = OUT / name
        if args.check:
            if not p.exists() or p.read_bytes() != data:
                print(f"differs: {p}")
                bad += 1
        else:
            p.write_bytes(data)
            print(f"wrote {p.relative_to(REPO)} ({len(data)} bytes)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
