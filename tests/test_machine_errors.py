"""Geometric and cutting errors in the virtual CNC and the learning loop (issue 8): seeds 002 and 004."""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.contour.path import PathGeometry
from ilcnc.contour.search import contour_error
from ilcnc.learning.learner import learn_virtual
from ilcnc.profile.load import load_profile, profile_from_dict
from ilcnc.program import read_program
from ilcnc.shop.workflow import LearnRequest, learn_part
from ilcnc.vcnc.machine_errors import ErrorSources, wall_normals
from ilcnc.vcnc.simulate import simulate_program
from ilcnc.vcnc.volumetric import load_volumetric
from tests.conftest import REPO, SAMPLES

CONFIGS = REPO / "configs"
OWN = REPO / "samples" / "own"
SEED002 = CONFIGS / "seed002-lu-volumetric.yaml"
CIRCLE = OWN / "seed002_circle.ngc"
JSDC = SAMPLES / "gcode" / "jsdc.gcode"

runner = CliRunner()


def _probe(ran_path: Path, original, geometry, out: Path) -> tuple[Path, np.ndarray]:
    """A virtual CMM: the part cut by ``ran_path`` measured at the original command points (measured − nominal)."""
    ran = read_program(ran_path)
    commanded = ran.command_end_mm
    dev = commanded + geometry.error_mm(commanded) - original.command_end_mm
    rows = ["k,dx,dy,dz"] + [f"{k},{d[0]:.7f},{d[1]:.7f},{d[2]:.7f}" for k, d in enumerate(dev)]
    out.write_text("\n".join(rows) + "\n")
    return out, dev


def _chord_rms_mm(ran_path: Path, original, geometry) -> float:
    """RMS contour error between the command points: every chord of the program that ran, sampled every
    0.1 mm, moved by the volumetric error, against the original polygon."""
    ran = read_program(ran_path)
    mv = ran.moves
    pts, hint = [], []
    for i in np.flatnonzero(mv.command >= 0):
        a, b = mv.start_mm[i], mv.end_mm[i]
        n = max(int(np.linalg.norm(b - a) / 0.1), 1)
        s = np.linspace(0.0, 1.0, n + 1)[:, None]
        pts.append(a + s * (b - a))
        hint.append(np.full(n + 1, i))
    q = np.vstack(pts)
    act = q + geometry.error_mm(q)
    err = contour_error(PathGeometry.from_moves(original.moves), act, np.concatenate(hint))
    return float(np.sqrt(np.mean(err.dist_mm**2)))


def test_seed002_circle_learned_from_points_cuts_the_point_error_by_99_percent(tmp_path) -> None:
    prof = load_profile(SEED002)
    geometry = load_volumetric(prof.resolve(prof.geometry.map))
    original = read_program(CIRCLE)
    assert original.n_commands == 11  # the plunge's end and 10 chord ends: seed 002's 11 command points
    state = tmp_path / "circle.state"
    ran = CIRCLE
    norms, chord_rms = [], []
    for i in range(10):
        pts, dev = _probe(ran, original, geometry, tmp_path / f"probe{i}.csv")
        norms.append(float(np.linalg.norm(dev)))
        chord_rms.append(_chord_rms_mm(ran, original, geometry))
        out = tmp_path / f"circle.ilc{i + 1}.ngc"
        oc = learn_part(LearnRequest(ran, SEED002, out, points=pts, state=state))
        assert oc.status == "stepped", oc.message
        ran = out
    _pts, dev = _probe(ran, original, geometry, tmp_path / "probe_final.csv")
    norms.append(float(np.linalg.norm(dev)))
    chord_rms.append(_chord_rms_mm(ran, original, geometry))
    assert norms[0] > 0.003  # a few µm per point
    # monotone; strictly while the update is larger than the resolution (10 nm), then it stands still
    assert all(b < a if a > 10 * prof.machine.resolution_mm else b <= a for a, b in pairwise(norms)), norms
    assert norms[-1] <= 0.01 * norms[0], norms  # >= 99 % within 10 iterations
    # between the points the straightness bows stay: the path improves, by less than the points
    assert chord_rms[-1] < 0.5 * chord_rms[0], chord_rms
    assert chord_rms[-1] / chord_rms[0] > norms[-1] / norms[0]
    # only G01 coordinate words changed; the program still reads
    text = ran.read_text()
    assert read_program(ran).n_commands == 11 and text.count("\n") == CIRCLE.read_text().count("\n")


def _geometry_only_profile(tmp_path: Path):
    """A machine that follows its program almost perfectly (K_v = 10,000 1/s behind the jerk-limited planner, a
    0.1 µm corner tolerance) with the shipped squareness + pitch map: the contour error is the geometric error."""
    d = load_profile(CONFIGS / "example-mill.yaml").to_dict()
    for ax in d["axes"].values():
        ax["drive"] = {"model": "first_order_delay", "time_constant_s": 0.0001}
    d["machine"]["resolution_mm"] = 0.00001
    d["planner"]["corner_tolerance_mm"] = 0.0001  # the planned path keeps to the corners within 0.1 µm
    d["machine"].pop("travel_mm", None)
    d["learning"].update({"law": "p", "gains": {"gamma": 1.0}, "iterations": 5, "stop_tolerance_mm": 0.00001,
                          "error": "path"})
    d["learning"].pop("q_filter_hz", None)
    d["geometry"] = {"map": str(CONFIGS / "volumetric-squareness-pitch.csv")}
    return profile_from_dict(d, path=tmp_path / "geo.yaml")


def test_squareness_and_pitch_on_a_cam_sample_learned_to_ten_percent(tmp_path) -> None:
    prof = _geometry_only_profile(tmp_path)
    prog = read_program(JSDC)
    res = learn_virtual(prog, prof, iterations=5)
    first, best = res.iterations[0], res.best_record
    shares = first.shares
    assert set(shares) == {"dynamic", "geometric"}
    assert shares["dynamic"]["rms"] < 0.02 * shares["geometric"]["rms"]  # the error is the geometry's
    assert len(res.iterations) <= 6 and res.status in ("max_iterations", "converged", "stopped")
    assert best.iteration <= 5 and best.stats["rms"] <= 0.10 * first.stats["rms"], [r.stats for r in res.iterations]
    assert best.stats["max"] < first.stats["max"]


def test_simulate_json_reports_each_share_and_the_wall_normal(tmp_path) -> None:
    res = runner.invoke(app, ["simulate", str(CIRCLE), "--profile", str(SEED002), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert set(data["error_shares_mm"]) == {"dynamic", "geometric"}
    assert 0.002 < data["error_shares_mm"]["geometric"]["max"] < 0.01
    # left of +Y travel is -X
    prog = read_program(OWN / "seed004_stepped.h")
    n = wall_normals(prog, "left")
    along_y = np.abs(prog.moves.end_mm[prog.command_moves, 1] - prog.moves.start_mm[prog.command_moves, 1]) > 0
    assert np.allclose(n[along_y], [-1.0, 0.0, 0.0])


def test_a_program_outside_the_map_names_its_line(tmp_path) -> None:
    p = tmp_path / "far.ngc"
    p.write_text("G21 G90\nG0 X10 Y10 Z-5\nG1 X390 Y10 F1000\nG1 X390 Y300\nM2\n")
    d = load_profile(SEED002).to_dict()
    d["machine"].pop("travel_mm")
    d["geometry"]["map"] = str(CONFIGS / "volumetric-seed002.csv")
    prof = profile_from_dict(d)
    with pytest.raises(Exception) as info:
        simulate_program(read_program(p), prof)
    msg = str(info.value)
    assert msg.startswith(f"{p}:4: the tool reaches") and "outside the volumetric map" in msg, msg
    assert "geometry.outside: extrapolate" in msg


def test_a_missing_map_file_is_one_line_exit_1(tmp_path) -> None:
    prof = tmp_path / "p.yaml"
    prof.write_text(SEED002.read_text().replace("volumetric-seed002.csv", "no-such-map.csv"))
    res = runner.invoke(app, ["simulate", str(CIRCLE), "--profile", str(prof), "--json"])
    assert res.exit_code == 1
    assert "no-such-map.csv: volumetric map named by geometry.map of p.yaml does not exist" in res.output


def test_error_sources_are_off_by_default() -> None:
    src = ErrorSources.from_profile(load_profile(CONFIGS / "example-mill.yaml"))
    assert not src.enabled and src.names == ()


STEPPED = OWN / "seed004_stepped.h"
STEPPED_PROFILE = CONFIGS / "seed004-stepped-cut.yaml"
#: Y ranges of the three stock zones (75 / 50 / 25 % immersion), 2 mm clear of the steps
ZONES_MM = ((2.0, 76.5), (80.5, 155.5), (159.5, 234.0))


def _zone_form_error_um(sim) -> list[float]:
    """Mean wall deviation in each zone, µm (seed 004 reports the mean deviation from the reference surface)."""
    y = sim.actual_mm[:, 1]
    return [float(np.mean(sim.error.dist_mm[sim.feed_mask & (y > a) & (y < b)]) * 1e3) for a, b in ZONES_MM]


def test_seed004_stepped_cut_learned_with_gamma_half(tmp_path) -> None:
    import re

    prof = load_profile(STEPPED_PROFILE)
    prog = read_program(STEPPED)
    assert prof.learning.gain("gamma", "x") == 0.5 and prof.cutting.enabled and prof.learning.error == "surface"
    assert (prof.tool.helix_deg, prof.tool.runout_um) == (30.0, 30.0)
    # the tool modes are the assumptions docs/papers.md states (no published tap test of a comparable tool could
    # be read and cited): holder/spindle 900 Hz / 0.04 / 40 N/um, tool 2400 Hz / 0.025 / 15 N/um, both directions;
    # the pins below hold for these values only
    assert {(m.direction, m.natural_frequency_hz, m.damping_ratio, m.stiffness_n_um) for m in prof.tool.modes} == {
        (d, 900.0, 0.04, 40.0) for d in ("normal", "feed")} | {(d, 2400.0, 0.025, 15.0) for d in ("normal", "feed")}
    res = learn_virtual(prog, prof, iterations=7, stop_on_stall=False, keep_runs=True)
    # the max falls under the 1 um stop tolerance after iteration 5: learning stops there (converged)
    assert len(res.iterations) == 6 and all(r.kept for r in res.iterations)
    rms = np.array([r.stats["rms"] for r in res.iterations]) * 1e3
    mx = np.array([r.stats["max"] for r in res.iterations]) * 1e3
    zones = np.array([_zone_form_error_um(r.run) for r in res.iterations])
    # the default program (iteration 0), helical model with 30 um runout and the assumed modes: 14.05 / 14.57 /
    # 15.05 um (re-measured, unchanged; bench/papers.py --seed 004 prints them too); the
    # figures are deterministic, 0.01 um covers their 3-decimal rounding in docs/papers.md. The paper measured
    # 8.41 / 11.96 / 17.21 um: these lie within a factor 2 of each (the ranges below), but the model does not
    # rise with falling immersion as the measurement does (runout's 15 um overcut dominates; docs/papers.md)
    assert zones[0] == pytest.approx([14.051, 14.568, 15.048], abs=0.01)
    for got, paper in zip(zones[0], (8.41, 11.96, 17.21), strict=True):
        assert paper / 2 <= got <= paper * 2
    assert mx[0] == pytest.approx(15.048, abs=0.01) and rms[0] == pytest.approx(14.220, abs=0.01)
    # eq. (4) per command with Gamma = 0.5 leaves (1 - Gamma) = half of E(k) per update; the SLE moves a little
    # with the radial depth the correction changes and corrections are rounded to 0.1 um, so each ratio is
    # 0.5 +- 0.05 (measured 0.50, 0.50, 0.50, 0.51, 0.47)
    assert np.all(np.abs(rms[1:] / rms[:-1] - 0.5) < 0.05), rms
    # the max falls too, with the per-end-point SLE (no step the corrected polyline cannot follow): 15.05 ->
    # 7.60 -> 3.88 -> 2.13 -> 1.26 -> 0.78 um
    assert np.all(np.diff(mx) < 0) and mx[-1] < 1.0, mx
    assert mx == pytest.approx([15.048, 7.598, 3.877, 2.134, 1.261, 0.777], abs=0.01)  # as docs/papers.md prints
    assert np.all(zones[-1] <= 0.05 * zones[0]), zones  # >= 95 % of the modelled form error removed per zone
    assert res.iterations[0].shares["cutting"]["rms"] > 10 * res.iterations[0].shares["dynamic"]["rms"]
    # the output is a Klartext program that reads back and differs only in corrected coordinate words
    out = tmp_path / "stepped.ilc.h"
    out.write_text(res.best_record.text, encoding="latin-1")
    back = read_program(out)
    assert back.n_commands == prog.n_commands and back.dialect == prog.dialect
    coord = re.compile(r"\b[XYZ][+-]?\d*\.?\d+")
    src, new = STEPPED.read_text().splitlines(), res.best_record.text.splitlines()
    assert len(src) == len(new)
    changed = [i for i, (a, b) in enumerate(zip(src, new, strict=True)) if a != b]
    assert changed and all(coord.sub("", src[i]) == coord.sub("", new[i]).replace("  ", " ") for i in changed)
    u = res.best_record.corrections_mm
    assert np.allclose(back.command_end_mm, prog.command_end_mm + u, atol=1e-9)
    # the corrections move the tool into the wall where it bends away (SLE > 0) and out where it overcuts (SLE < 0:
    # the long flute's 15 um here); every cutting command is corrected, the exit move in the air is not
    sle = ErrorSources.from_profile(prof).sle_mm(prog, prog)
    n = wall_normals(prog, "left")
    toward_wall = np.einsum("ij,ij->i", u, n)
    cut = np.abs(sle) > 1e-4
    assert cut.sum() == 119 and np.all(np.sign(toward_wall[cut]) == np.sign(sle[cut]))
    assert np.all(u[~cut] == 0.0)


BAD_MAPS = REPO / "tests" / "data" / "volumetric"


def _profile_with(tmp_path: Path, **sections) -> Path:
    """The seed 004 stepped-cut profile (absolute stock path) with sections replaced, written to tmp_path."""
    import yaml

    d = load_profile(STEPPED_PROFILE).to_dict()
    d["cutting"]["stock"] = str(OWN / "seed004_stepped_omi.csv")
    for k, v in sections.items():
        d[k] = v
    p = tmp_path / "p.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    return p


def _cli_error(*args) -> str:
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 1, res.output
    lines = [x for x in res.output.splitlines() if x.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    return lines[0]


@pytest.mark.parametrize(
    ("name", "where", "what"),
    [
        ("grid_holes.csv", "grid_holes.csv:4:", "hole"),
        ("grid_irregular.csv", "grid_irregular.csv:9:", ""),
        ("grid_nan.csv", "grid_nan.csv:5:", ""),
        ("grid_units.csv", "grid_units.csv:6:", "µm"),
    ],
)
def test_a_bad_map_named_by_the_profile_is_one_line_exit_1(tmp_path, name: str, where: str, what: str) -> None:
    prof = _profile_with(tmp_path, geometry={"map": str(BAD_MAPS / name)})
    line = _cli_error("simulate", STEPPED, "--profile", prof)
    assert where in line and what in line, line


def test_bad_frf_stock_and_probe_files_are_one_line_exit_1(tmp_path) -> None:
    frf = tmp_path / "frf.csv"
    frf.write_text("f_hz,re,im\n100,1e-7,-1e-8\n300,1e-7,-2e-8\n200,1e-7,-3e-8\n")
    tool = load_profile(STEPPED_PROFILE).to_dict()["tool"]
    tool.pop("modes")
    tool["frf_csv"] = str(frf)
    line = _cli_error("simulate", STEPPED, "--profile", _profile_with(tmp_path, tool=tool))
    assert "frf.csv:4:" in line and "increas" in line, line
    # a radial depth larger than the tool diameter
    stock = tmp_path / "stock.csv"
    stock.write_text("k,stock_mm\n0,9\n1,13\n")
    cutting = load_profile(STEPPED_PROFILE).to_dict()["cutting"]
    cutting["stock"] = str(stock)
    line = _cli_error("simulate", STEPPED, "--profile", _profile_with(tmp_path, cutting=cutting))
    assert "stock.csv:3:" in line and "diameter" in line, line
    # probe points that match no command
    pts = tmp_path / "probe.csv"
    pts.write_text("x,y,z,dx,dy,dz\n27,10,-8,0.001,0,0\n150,10,-8,0.001,0,0\n")
    line = _cli_error("learn", STEPPED, "--profile", STEPPED_PROFILE, "--points", pts, "--state", tmp_path / "st",
                      "--out", tmp_path / "o.h")
    assert "probe.csv:3:" in line and "from the nearest G01 end point" in line, line
    assert not (tmp_path / "st").exists()


def test_the_shipped_probe_file_steps_the_circle_and_its_closing_point_counts_for_both_commands(tmp_path) -> None:
    from ilcnc.shop.state import LearnState

    res = runner.invoke(app, ["learn", str(CIRCLE), "--profile", str(SEED002), "--points",
                              str(OWN / "seed002_circle_probe.csv"), "--state", str(tmp_path / "st"),
                              "--out", str(tmp_path / "c1.ngc"), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["status"] == "stepped" and not data["notes"]  # every command measured
    st = LearnState.load(tmp_path / "st")
    u = st.read_corrections(st.iterations[1])
    assert np.all(u[0] != 0.0) and np.array_equal(u[0], u[10])  # the first and last point: one place
    assert u[0] == pytest.approx([0.00084, -0.00059, -0.00057], abs=1e-5)  # gamma 0.5 x (nominal - measured)
