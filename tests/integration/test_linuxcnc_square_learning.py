"""Issue 9 on LinuxCNC's own motion: a 50 mm square at F3000, four measured learning iterations.

run the square on LinuxCNC → ``ilcnc learn --log`` → compensated program → run it → ... (four learning
iterations, time-scaled ×8, about 20 s in all). The square is programmed as 200 G01 moves of 1 mm
(``G64 P0.01 Q0``, the path control docs/linuxcnc.md §4 recommends): learning per G01 command can only
shape a corner through the end points near it, so the plain four-move square gains about 4 % (figures in
docs/papers.md, section "Real controller"). The profile is configs/linuxcnc-sim.yaml as shipped: law ``p``,
Γ 0.5, Q filter 20 Hz, and three model-assisted steps after each measured one (``learning.model_steps``).

Measured (LinuxCNC 2.9, Debian 12; the runs are deterministic): RMS 22.30 → 11.85 → 9.29 → 8.12 → 7.18 µm,
−67.8 % (without the model steps −47 %; with Γ 1 and no Q filter −61 %).
"""

from __future__ import annotations

from itertools import pairwise

import pytest

from tests.integration._lcnc import PROFILE, cli_json, needs_linuxcnc

pytestmark = needs_linuxcnc()


def square_program(side_mm: float = 50.0, step_mm: float = 1.0, feed_mm_min: float = 3000.0) -> str:
    """A closed square, counter-clockwise from the origin, as G01 moves of ``step_mm``."""
    corners = [(0.0, 0.0), (side_mm, 0.0), (side_mm, side_mm), (0.0, side_mm), (0.0, 0.0)]
    lines = ["G21 G90 G17 G64 P0.01 Q0", "G0 X0 Y0 Z0", f"G1 F{feed_mm_min:g}"]
    n = round(side_mm / step_mm)
    for (x0, y0), (x1, y1) in pairwise(corners):
        lines += [f"G1 X{x0 + (x1 - x0) * i / n:.4f} Y{y0 + (y1 - y0) * i / n:.4f}" for i in range(1, n + 1)]
    return "\n".join([*lines, "M2", ""])


@pytest.fixture(scope="module")
def loop(tmp_path_factory) -> dict:
    d = tmp_path_factory.mktemp("lcnc-square")
    part = d / "square.ngc"
    part.write_text(square_program())
    profile = PROFILE  # as shipped: Γ 0.5, Q 20 Hz, 3 model-assisted steps per measured one
    state = d / "state"
    log = d / "run0.csv"
    cli_json("linuxcnc", "run", part, "--log-out", log, "--time-scale", 8)
    for i in range(1, 5):
        out = d / f"square.ilc{i}.ngc"
        cli_json("learn", part, "--profile", profile, "--log", log, "--state", state, "--out", out)
        log = d / f"run{i}.csv"
        cli_json("linuxcnc", "run", out, "--log-out", log, "--time-scale", 8)
    last = cli_json("learn", part, "--profile", profile, "--log", log, "--state", state, "--out", d / "square.ilc5.ngc")
    return {"part": part, "last": last}


def test_the_program_is_a_50_mm_square_of_200_g01_moves(loop) -> None:
    insp = cli_json("inspect", loop["part"], "--profile", PROFILE)
    assert insp["g01_commands"] == 200
    assert insp["extents_mm"]["min"][:2] == [0.0, 0.0] and insp["extents_mm"]["max"][:2] == [50.0, 50.0]


def test_four_iterations_on_linuxcnc_cut_the_square_error_by_60_percent(loop) -> None:
    its = loop["last"]["iterations"]
    rms = [it["contour_error_mm"]["rms"] for it in its[:5]]
    mx = [it["contour_error_mm"]["max"] for it in its[:5]]
    assert all(it["kept"] for it in its[:5]), its
    assert all(it["measured_from"] == "log" for it in its[:5]), its
    assert all(b < a for a, b in pairwise(rms)), rms
    assert all(b < a for a, b in pairwise(mx)), mx
    # issue 9: >= 60 % RMS after four iterations. Measured 2026-11-23: 22.30 -> 11.85 -> 9.29 -> 8.12 -> 7.18 µm
    # (-67.8 %; max 193 -> 84 µm). Without the model steps: -47 % (Γ 0.5) and -61 % (Γ 1, no Q filter).
    assert rms[4] <= 0.40 * rms[0], rms
