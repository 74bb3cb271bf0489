"""The virtual CNC end to end: analytic checks, --against, bad input."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcnc.errors import InputError
from ilcnc.profile.load import default_profile, profile_from_dict
from ilcnc.program.gcode import read_gcode
from ilcnc.vcnc.simulate import simulate_program

from .conftest import OWN, REPO


def _profile(drive: dict, planner: str = "constant_feed", **machine: object):
    d = copy.deepcopy(default_profile().to_dict())
    for ax in d["axes"].values():
        ax["drive"] = dict(drive)
    d["planner"]["profile"] = planner
    d["machine"].update(machine)
    return profile_from_dict(d)


def _prog(text: str):
    return read_gcode(Path("t.ngc"), text.encode())


def test_p_loop_following_error_is_v_over_kv() -> None:
    # a P position loop closed at the servo period (no feed-forward, no friction): e = v / Kv
    kp = 1.6  # (m/min)/mm, i.e. Kv = 1.6 * 1000 / 60 = 26.7 1/s
    prof = _profile({"model": "p_ff_friction", "kp_m_min_mm": kp, "kff": 0.0, "velocity_bandwidth_hz": 200.0})
    res = simulate_program(_prog("G21 G90\nG0 X0 Y0 Z0\nG1 X300 F3000\nM2\n"), prof)
    lag = res.reference.pos_mm[:, 0] - res.actual_mm[:, 0]
    mid = slice(res.reference.n_samples // 3, 2 * res.reference.n_samples // 3)
    assert np.median(lag[mid]) == pytest.approx(50.0 / (kp * 1000.0 / 60.0), rel=0.01)


def test_first_order_loop_lags_by_its_time_constant_plus_half_a_period() -> None:
    # the closed loop T/(Ts+1) fed with the held reference: lag v*(T + Ts/2), the hold adding half a period
    tau = 0.02
    prof = _profile({"model": "first_order_delay", "time_constant_s": tau})
    res = simulate_program(_prog("G21 G90\nG0 X0 Y0 Z0\nG1 X200 F3000\nM2\n"), prof)
    lag = res.reference.pos_mm[:, 0] - res.actual_mm[:, 0]
    mid = slice(res.reference.n_samples // 3, 2 * res.reference.n_samples // 3)
    assert np.median(lag[mid]) == pytest.approx(50.0 * (tau + 0.0005), rel=0.005)


def test_circle_radial_shrinkage_of_a_first_order_loop() -> None:
    tau, r, feed = 0.02, 10.0, 3000.0
    prof = _profile({"model": "first_order_delay", "time_constant_s": tau})
    res = simulate_program(_prog(f"G21 G90 G17\nG0 X{r} Y0 Z0\nG2 X{r} Y0 I-{r} J0 P3 F{feed}\nM2\n"), prof)
    n = res.reference.n_samples
    late = slice(n // 2, n - 10)  # after the start transient
    radius = np.hypot(res.actual_mm[late, 0], res.actual_mm[late, 1])
    omega = feed / 60.0 / r
    expect = r * (1.0 - 1.0 / np.sqrt(1.0 + (omega * tau) ** 2))
    assert r - radius.mean() == pytest.approx(expect, rel=0.05)
    # the contour error reported is that shrinkage
    assert res.stats["max"] == pytest.approx(expect, rel=0.05)


def test_compensated_program_is_judged_against_the_original(tmp_path: Path) -> None:
    prof = default_profile()
    orig = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X50 F3000\nY50\nM2\n")
    moved = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X50.2 F3000\nY50\nM2\n")
    own = simulate_program(moved, prof)
    judged = simulate_program(moved, prof, against=orig)
    assert judged.stats["max"] > own.stats["max"] + 0.1  # the 0.2 mm overshoot is an error of the drawing
    other = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X50 F3000\nM2\n")
    with pytest.raises(InputError, match="not the same part"):
        simulate_program(moved, prof, against=other)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ilcnc", *args], capture_output=True, text=True, timeout=300)


def test_simulate_command_writes_log_and_json(tmp_path: Path) -> None:
    out = tmp_path / "log.csv"
    r = _cli("simulate", str(OWN / "star.ngc"), "--profile", str(REPO / "configs" / "example-mill.yaml"),
             "--log-out", str(out), "--corners", "5", "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert set(summary) == {"program", "samples", "cycle_time_s", "contour_error_mm", "air_error_mm", "cutting_rule", "worst",
                            "corners"}
    # the worst corner (ilcnc.shop.corners) is the run's cutting max, taken over the same samples
    assert summary["corners"]["corners"][0]["max_mm"] == summary["contour_error_mm"]["max"]
    assert summary["samples"] == len(out.read_text().splitlines()) - 1
    assert 0 < summary["contour_error_mm"]["rms"] <= summary["contour_error_mm"]["max"] < 0.1
    assert summary["worst"]["line"] > 0


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda d: d["axes"]["x"]["drive"].pop("omega0_rad_s"), "axes.x.drive.omega0_rad_s"),
        (lambda d: d["axes"]["y"].__setitem__("max_acceleration_m_s2", 0), "axes.y.max_acceleration_m_s2"),
    ],
)
def test_bad_profiles_are_refused(tmp_path: Path, edit, needle: str) -> None:
    d = copy.deepcopy(default_profile().to_dict())
    edit(d)
    prof = tmp_path / "bad.yaml"
    prof.write_text(yaml.safe_dump(d))
    r = _cli("simulate", str(OWN / "square.ngc"), "--profile", str(prof))
    assert r.returncode == 1
    assert needle in r.stderr and "bad.yaml:" in r.stderr and r.stderr.count("\n") == 1


def test_program_beyond_travel_is_refused(tmp_path: Path) -> None:
    d = copy.deepcopy(default_profile().to_dict())
    d["machine"]["travel_mm"] = {"x": [-10, 40], "y": [-10, 100], "z": [-50, 50]}
    prof = tmp_path / "small.yaml"
    prof.write_text(yaml.safe_dump(d))
    r = _cli("simulate", str(OWN / "square.ngc"), "--profile", str(prof))
    assert r.returncode == 1
    assert "square.ngc:5:" in r.stderr and "outside the machine travel" in r.stderr


def test_feed_stats_equal_the_nan_reductions() -> None:
    # one pass for the mask and the statistics: np.nanmax / nanargmax exactly, np.nanmean to a few ulp
    from ilcnc.vcnc.simulate import _feed_stats

    rng = np.random.default_rng(3)
    n = 100_003
    move = rng.integers(-1, 50, n).astype(np.int32)
    rapid = rng.random(50) < 0.2
    dist = rng.random(n) * 1e-2
    dist[rng.random(n) < 0.01] = np.nan
    feed, stats, worst = _feed_stats(move, rapid, dist)
    ref_feed = (move >= 0) & ~rapid[np.maximum(move, 0)]
    np.testing.assert_array_equal(feed, ref_feed)
    d = np.where(ref_feed & np.isfinite(dist), dist, np.nan)
    assert worst == int(np.nanargmax(d))
    assert stats["max"] == float(np.nanmax(d))
    assert stats["mean"] == pytest.approx(float(np.nanmean(d)), rel=1e-14)
    assert stats["rms"] == pytest.approx(float(np.sqrt(np.nanmean(d * d))), rel=1e-14)
    none = _feed_stats(move, np.ones(50, bool), dist)
    assert none[1] == {"max": 0.0, "mean": 0.0, "rms": 0.0} and none[2] == -1
    # with move classes: the cutting moves' figures, the air moves' apart, the feed mask over both
    from ilcnc.contour.air import MOVE_AIR, MOVE_CUT, MOVE_NOT_FED
    from ilcnc.vcnc.simulate import FeedStats

    cls = np.where(rapid, MOVE_NOT_FED, np.where(rng.random(50) < 0.3, MOVE_AIR, MOVE_CUT)).astype(np.int8)
    acc = FeedStats()
    half = n // 2
    feed2 = np.concatenate([acc.add(move[:half], cls, dist[:half]), acc.add(move[half:], cls, dist[half:], half)])
    np.testing.assert_array_equal(feed2, ref_feed)
    mc = np.maximum(move, 0)
    for got, want in ((acc.result()[0], MOVE_CUT), (acc.air_result(), MOVE_AIR)):
        d = np.where((move >= 0) & (cls[mc] == want) & np.isfinite(dist), dist, np.nan)
        assert got["max"] == float(np.nanmax(d))
        assert got["rms"] == pytest.approx(float(np.sqrt(np.nanmean(d * d))), rel=1e-14)
    d = np.where((move >= 0) & (cls[mc] == MOVE_CUT) & np.isfinite(dist), dist, np.nan)
    assert acc.result()[1] == int(np.nanargmax(d))
