"""Run LinuxCNC's RS-274NGC interpreter (the ``gcode`` module) on a program and dump its motion as JSON.

Run with Debian's system Python, which is the only one that can import the module::

    /usr/bin/python3 tests/lcnc_gcode_dump.py PROGRAM VARFILE OUT.json [G21|G20]

It is a helper of ``tests/test_linuxcnc_interp.py``; it must not import ilcnc or
anything outside the standard library and the ``gcode`` extension.

Output (OUT.json, one JSON object; stdout gets the program's own (PRINT,...) lines)::

    {"result": int, "min_error": int, "error": str, "last_line": int,
     "error_line": int, "moves": [[kind, line, x, y, z, cx, cy, cz], ...]}

* coordinates are the interpreter's internal units, **inches**, full doubles,
  in the active work coordinate system (offsets are not applied);
* ``kind``: 0 straight traverse, 1 straight feed, 2 arc CW, 3 arc CCW,
  9 any other motion (probe, rigid tap ...); arcs carry their centre,
  straight moves ``null`` centres; ``line`` is the 1-based source line;
* rows of kind 100 / 101 are not moves but the new G5x / G92 offset (x, y, z),
  inches, in effect for the moves after them; rows of kind 102 the new XY
  rotation of the work system (degrees, in the x column);
* ``error_line`` is the line of the last block that made a canon call (the
  module announces ``next_line`` only then); ``last_line`` is what
  ``gcode.parse`` returns (the failing line, or the one after it for read
  errors). The test takes the refused line from rs274 instead.

Without a running LinuxCNC the module has no tool table (its tool data lives in
a shared memory map that LinuxCNC's task creates): any T, H or D word makes the
process die with SIGSEGV. The test then falls back to rs274 for that program.
"""

from __future__ import annotations

import json
import sys

import gcode  # type: ignore[import-not-found]

# canon plane code -> (first axis, second axis, normal axis) as indices into (x, y, z)
_PLANES = {1: (0, 1, 2), 2: (1, 2, 0), 3: (2, 0, 1)}
_OTHER_MOTION = ("straight_probe", "rigid_tap", "nurbs_feed", "spline_feed", "nurbs_g5_feed", "nurbs_g6_feed")


class Canon:
    """The minimum canon the interpreter needs; records motion, ignores everything else."""

    def __init__(self, parameter_file: str) -> None:
        self.parameter_file = parameter_file
        self.lineno = 0
        self.plane = 1
        self.moves: list[list] = []

    # queries of the interpreter
    def get_external_length_units(self) -> float:
        return 1.0

    def get_external_angular_units(self) -> float:
        return 1.0

    def get_axis_mask(self) -> int:
        return 0x3F  # X Y Z A B C, as the standalone rs274

    def get_block_delete(self) -> bool:
        return False

    def get_tool(self, idx: int) -> tuple:
        # every tool exists, with zero length and zero diameter (rs274 gets the same table with -t)
        return (idx, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0)

    def check_abort(self) -> bool:
        return False

    # calls we record
    def next_line(self, st) -> None:
        self.lineno = st.sequence_number

    def set_plane(self, plane: int) -> None:
        self.plane = plane

    def set_g5x_offset(self, index: int, x: float, y: float, z: float, *rest: float) -> None:
        self.moves.append([100, self.lineno, x, y, z, None, None, None])

    def set_g92_offset(self, x: float, y: float, z: float, *rest: float) -> None:
        self.moves.append([101, self.lineno, x, y, z, None, None, None])

    def set_xy_rotation(self, t: float) -> None:
        self.moves.append([102, self.lineno, t, None, None, None, None, None])

    def straight_traverse(self, x: float, y: float, z: float, *rest: float) -> None:
        self.moves.append([0, self.lineno, x, y, z, None, None, None])

    def straight_feed(self, x: float, y: float, z: float, *rest: float) -> None:
        self.moves.append([1, self.lineno, x, y, z, None, None, None])

    def arc_feed(
        self,
        first_end: float,
        second_end: float,
        first_axis: float,
        second_axis: float,
        rotation: int,
        axis_end: float,
        *rest: float,
    ) -> None:
        a1, a2, n = _PLANES[self.plane]
        end = [0.0, 0.0, 0.0]
        centre: list[float | None] = [None, None, None]
        end[a1], end[a2], end[n] = first_end, second_end, axis_end
        centre[a1], centre[a2] = first_axis, second_axis
        self.moves.append([2 if rotation < 0 else 3, self.lineno, *end, *centre])

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        if name in _OTHER_MOTION:
            return lambda *a, **k: self.moves.append([9, self.lineno, None, None, None, None, None, None])
        return lambda *a, **k: None


def main(argv: list[str]) -> int:
    program, var_file, out = argv[1], argv[2], argv[3]
    unitcode = argv[4] if len(argv) > 4 else "G21"
    canon = Canon(var_file)
    result, last_line = gcode.parse(program, canon, unitcode, "")
    error = gcode.strerror(result) if result > gcode.MIN_ERROR else ""
    with open(out, "w") as f:
        json.dump(
            {
                "result": result,
                "min_error": gcode.MIN_ERROR,
                "error": error,
                "last_line": last_line,
                "error_line": canon.lineno,
                "moves": canon.moves,
            },
            f,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
