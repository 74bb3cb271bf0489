"""Tests of ilcnc.shop.report: files written, tables, command diff, decimation."""

from __future__ import annotations

import csv
import io
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import InputError
from ilcnc.shop.report import (
    CommandDiff,
    ReportRun,
    _select,
    auto_magnify,
    plane_axes,
    write_report,
)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
SIDE = 20.0
CORNERS = np.array([[0, 0, 0], [SIDE, 0, 0], [SIDE, SIDE, 0], [0, SIDE, 0], [0, 0, 0]], dtype=float)
# (iteration, kept, error amplitude in mm); iteration 2 made the error grow and was not kept
ITERATIONS = [(0, True, 0.050), (1, True, 0.020), (2, False, 0.030), (3, True, 0.010)]


def square_samples(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Foot points, arc length and inward (left) unit normal of n samples along the CCW square."""
    s = np.linspace(0.0, 4 * SIDE, n, endpoint=False)
    side = np.minimum((s // SIDE).astype(int), 3)
    f = s - side * SIDE
    start = CORNERS[side]
    direction = CORNERS[side + 1] - CORNERS[side]
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    foot = start + f[:, None] * direction
    normal = np.stack([-direction[:, 1], direction[:, 0], np.zeros(n)], axis=1)  # left of a CCW path = inward
    return foot, s, normal


def make_run(iteration: int, kept: bool, amp: float, n: int = 4000) -> ReportRun:
    foot, s, normal = square_samples(n)
    err = amp * (0.75 + 0.25 * np.sin(2 * np.pi * s / SIDE))  # > 0: inward, max 1.0 * amp
    actual = foot + err[:, None] * normal
    feed = np.ones(n, dtype=bool)
    feed[:50] = False  # an approach move: not part of the path
    actual[:50] = [-5.0, -5.0, 5.0]
    contour = np.where(feed, err, np.nan)
    fe = err[feed]
    stats = {"max": float(fe.max()), "mean": float(fe.mean()), "rms": float(np.sqrt(np.mean(fe * fe)))}
    return ReportRun(iteration=iteration, kept=kept, stats_mm=stats, clipped=iteration, gain_scale=1.0 if kept else 0.5,
                     actual_mm=actual, contour_mm=contour, signed_mm=np.where(feed, err, np.nan), path_pos_mm=s,
                     feed_mask=feed, foot_mm=np.where(feed[:, None], foot, np.nan))


def make_diff() -> CommandDiff:
    k = np.arange(8)
    old = np.array([[float(i), 2.0 * i, -1.0] for i in k])
    new = old.copy()
    new[1] += [0.003, -0.004, 0.0]  # changed, correction 0.005
    new[4, 2] += 0.012  # changed in Z only
    new[6] += [1e-12, 0.0, 0.0]  # float noise: not a change
    new[7] += [-0.0006, 0.0008, 0.0]  # changed and clipped, correction 0.001
    clipped = np.zeros(8, dtype=bool)
    clipped[[5, 7]] = True  # 5: clipped although its end point ends up unchanged
    return CommandDiff(k=k, line=10 + 2 * k, old_mm=old, new_mm=new, clipped=clipped)


def square_path() -> np.ndarray:
    # the square plus a disjoint piece after a rapid (NaN row)
    return np.vstack([CORNERS, [np.nan] * 3, [[5.0, 5.0, 0.0], [15.0, 15.0, 0.0]]])


def all_runs() -> list[ReportRun]:
    runs = [make_run(i, kept, amp) for i, kept, amp in ITERATIONS]
    # a measured step without log samples
    runs.append(ReportRun(iteration=4, kept=True, stats_mm={"max": 0.009, "mean": 0.006, "rms": 0.007}, clipped=0,
                          gain_scale=1.0, actual_mm=None, contour_mm=None, signed_mm=None, path_pos_mm=None,
                          feed_mask=None))
    return runs


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == PNG_SIGNATURE
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path], list[ReportRun]]:
    out = tmp_path_factory.mktemp("rep") / "report"  # does not exist yet: write_report creates it
    runs = all_runs()
    written = write_report(out, program_name="square.ngc", path_mm=square_path(), runs=runs, diff=make_diff(),
                           status="converged", message="RMS below tolerance after 3 iterations")
    return out, written, runs


def test_all_files_written(report):
    out, written, _ = report
    names = {p.name for p in written}
    expected = {f"path-iter{i:03d}.png" for i, _, _ in ITERATIONS} | {f"error-iter{i:03d}.png" for i, _, _ in ITERATIONS}
    expected |= {"error-along-path.png", "error-vs-iteration.png", "summary.csv", "summary.md", "commands.csv"}
    assert names == expected
    assert len(written) == len(expected)
    for p in written:
        assert p.parent == out and p.is_file()
    # the run without samples gets no path or error plot
    assert not (out / "path-iter004.png").exists()
    assert not (out / "error-iter004.png").exists()
    # atomic writes leave no temporary files behind
    assert sorted(p.name for p in out.iterdir()) == sorted(names)


def test_pngs_are_sensible(report):
    _, written, _ = report
    for p in written:
        if p.suffix != ".png":
            continue
        data = p.read_bytes()
        assert data.startswith(PNG_SIGNATURE), p.name
        w, h = png_size(data)
        assert 400 <= w <= 3000 and 300 <= h <= 3000, (p.name, w, h)
        assert 5_000 < len(data) < 3_000_000, (p.name, len(data))


def test_summary_csv(report):
    out, _, runs = report
    rows = list(csv.DictReader(io.StringIO((out / "summary.csv").read_text())))
    assert list(rows[0]) == ["iteration", "kept", "max_mm", "mean_mm", "rms_mm", "clipped", "gain_scale"]
    assert [int(r["iteration"]) for r in rows] == [0, 1, 2, 3, 4]
    by_it = {r.iteration: r for r in runs}
    for row in rows:
        run = by_it[int(row["iteration"])]
        assert int(row["kept"]) == int(run.kept)
        for key in ("max", "mean", "rms"):
            assert float(row[f"{key}_mm"]) == pytest.approx(run.stats_mm[key], abs=1e-6)
        assert int(row["clipped"]) == run.clipped
        assert float(row["gain_scale"]) == run.gain_scale
    assert float(rows[0]["max_mm"]) == pytest.approx(0.050, abs=1e-6)
    assert rows[2]["kept"] == "0" and float(rows[2]["gain_scale"]) == 0.5


def test_summary_md(report):
    out, _, runs = report
    md = (out / "summary.md").read_text()
    assert "square.ngc" in md and "converged" in md and "RMS below tolerance" in md
    assert "| iteration | kept | max_mm | mean_mm | rms_mm | clipped | gain_scale |" in md
    assert md.count("\n| ") == 1 + 5 + 1 - 1  # header, separator does not start with "| ", 5 rows
    # best kept iteration is the measured step 4 (smallest RMS), compared with iteration 0
    assert "Best kept iteration: **4**" in md
    rms0, rms4 = runs[0].stats_mm["rms"], 0.007
    assert f"RMS contour error reduced by {100 * (1 - rms4 / rms0):.1f} %" in md
    assert f"max contour error reduced by {100 * (1 - 0.009 / 0.050):.1f} %" in md
    assert "![error-vs-iteration.png](error-vs-iteration.png)" in md


def test_best_iteration_given(tmp_path):
    runs = all_runs()
    write_report(tmp_path / "r", program_name="p", path_mm=square_path(), runs=runs, diff=make_diff(), best_iteration=3)
    md = (tmp_path / "r" / "summary.md").read_text()
    assert "Best kept iteration: **3**" in md
    assert f"max contour error reduced by {100 * (1 - 0.010 / 0.050):.1f} %" in md


def test_commands_csv(report):
    out, _, _ = report
    text = (out / "commands.csv").read_text()
    rows = list(csv.DictReader(io.StringIO(text)))
    assert list(rows[0]) == ["k", "line", "x_old", "y_old", "z_old", "x_new", "y_new", "z_new", "dx", "dy", "dz",
                             "correction_mm", "clipped"]
    assert [int(r["k"]) for r in rows] == [1, 4, 5, 7]
    assert [int(r["line"]) for r in rows] == [12, 18, 20, 24]
    corr = {int(r["k"]): float(r["correction_mm"]) for r in rows}
    assert corr == pytest.approx({1: 0.005, 4: 0.012, 5: 0.0, 7: 0.001}, abs=1e-9)
    assert {int(r["k"]): int(r["clipped"]) for r in rows} == {1: 0, 4: 0, 5: 1, 7: 1}
    diff = make_diff()
    for r in rows:
        k = int(r["k"])
        for j, a in enumerate("xyz"):
            assert float(r[f"{a}_old"]) == pytest.approx(diff.old_mm[k, j], abs=1e-6)
            assert float(r[f"{a}_new"]) == pytest.approx(diff.new_mm[k, j], abs=1e-6)
            assert float(r[f"d{a}"]) == pytest.approx(diff.new_mm[k, j] - diff.old_mm[k, j], abs=1e-6)
    # numbers have 6 decimals and there is no negative zero
    line1 = text.splitlines()[1].split(",")
    assert all(len(v.split(".")[1]) == 6 for v in line1[2:12])
    assert "-0.000000" not in text


def test_missing_parent_is_input_error(tmp_path):
    out = tmp_path / "missing" / "report"
    with pytest.raises(InputError) as info:
        write_report(out, program_name="p", path_mm=square_path(), runs=all_runs(), diff=make_diff())
    assert str(out) in str(info.value)
    assert not out.parent.exists()


def test_output_is_a_file_is_input_error(tmp_path):
    out = tmp_path / "report"
    out.write_text("x")
    with pytest.raises(InputError):
        write_report(out, program_name="p", path_mm=square_path(), runs=all_runs(), diff=make_diff())


def test_existing_directory_and_explicit_magnify(tmp_path):
    runs = [make_run(0, True, 0.05)]
    written = write_report(tmp_path, program_name="p", path_mm=square_path(), runs=runs, diff=make_diff(), magnify=50)
    assert (tmp_path / "path-iter000.png") in written
    with pytest.raises(InputError):
        write_report(tmp_path, program_name="p", path_mm=square_path(), runs=runs, diff=make_diff(), magnify=0.0)


def test_run_without_samples_only(tmp_path):
    runs = all_runs()[-1:]
    written = write_report(tmp_path / "r", program_name="p", path_mm=square_path(), runs=runs, diff=make_diff())
    assert {p.name for p in written} == {"error-vs-iteration.png", "summary.csv", "summary.md", "commands.csv"}


def test_inconsistent_shapes_raise(tmp_path):
    run = make_run(0, True, 0.05)
    run.contour_mm = run.contour_mm[:-1]
    with pytest.raises(ValueError, match="contour_mm"):
        write_report(tmp_path, program_name="p", path_mm=square_path(), runs=[run], diff=make_diff())
    with pytest.raises(ValueError, match="duplicate"):
        write_report(tmp_path, program_name="p", path_mm=square_path(), runs=[make_run(0, True, 0.05)] * 2,
                     diff=make_diff())


def test_auto_magnify():
    assert auto_magnify(20.0, 0.050) == 20.0  # raw 20
    assert auto_magnify(20.0, 0.075) == 10.0  # raw 13.3
    assert auto_magnify(100.0, 0.001) == 5000.0
    assert auto_magnify(20.0, 5.0) == 1.0  # never shrinks
    assert auto_magnify(20.0, 0.0) == 1.0
    assert auto_magnify(0.0, 0.01) == 1.0
    assert auto_magnify(20.0, math.nan) == 1.0


def test_plane_axes():
    assert plane_axes(np.array([20.0, 20.0, 5.0])) == (0, 1)
    assert plane_axes(np.array([20.0, 0.0, 0.0])) == (0, 1)
    assert plane_axes(np.array([20.0, 0.0, 10.0])) == (0, 2)
    assert plane_axes(np.array([0.0, 30.0, 10.0])) == (1, 2)


def test_select_decimates_and_keeps_peaks():
    rng = np.random.default_rng(1)
    n = 2_000_000
    err = rng.random(n)
    err[1_234_567] = 10.0
    valid = np.ones(n, dtype=bool)
    valid[500_000:500_010] = False  # a rapid
    valid[-5:] = False
    for envelope in (True, False):
        idx, brk = _select(valid, err, 1000, envelope=envelope)
        assert 0 < idx.size <= 1000
        assert np.all(np.diff(idx) > 0)
        assert valid[idx].all()
        assert 1_234_567 in idx
        # exactly one break: across the rapid
        assert brk.sum() == 1
        b = int(np.flatnonzero(brk)[0])
        assert idx[b - 1] < 500_000 and idx[b] >= 500_010
    # small inputs are not decimated
    idx, brk = _select(valid[:300], err[:300], 1000, envelope=True)
    assert np.array_equal(idx, np.arange(300)) and not brk.any()


def test_select_without_error_and_all_nan():
    valid = np.zeros(10, dtype=bool)
    valid[[2, 3, 7]] = True
    idx, brk = _select(valid, None, 100, envelope=False)
    assert idx.tolist() == [2, 3, 7] and brk.tolist() == [False, False, True]
    idx, _ = _select(valid, np.full(10, np.nan), 4, envelope=False)
    assert valid[idx].all() and idx.size >= 1


def test_large_run_is_written(tmp_path):
    run = make_run(0, True, 0.05, n=1_000_000)
    written = write_report(tmp_path, program_name="big", path_mm=square_path(), runs=[run], diff=make_diff())
    assert (tmp_path / "path-iter000.png") in written
