"""Controller in the loop: part programs run on LinuxCNC's own motion controller (headless simulation).

The tests marked ``linuxcnc`` launch the configuration in ``configs/linuxcnc-sim``
through :func:`ilcnc.shop.linuxcnc.run_program` (about 3-7 s per launch; LinuxCNC is a
single instance per machine, so runs are serialised by a lock and must not be
spread over parallel workers). They are skipped, with the reason, when
LinuxCNC is not installed. The other tests (halsampler reading, time scaling
of the program text and INI) need nothing installed.

What the LinuxCNC runs check, on the 50 mm square ``samples/own/square.ngc``
(``G64 P0.05 Q0``, F3000):

* the log contains the program's motion lines in program order;
* the commanded path passes every corner within the G64 P tolerance;
* the actual position lags the commanded one by v / Kv on the straight edges
  (the HAL model: P loop with gain ``[ILCNC] KV``, first-order velocity drive);
* a time-scaled run (k = 4) gives the same log as k = 1 (after alignment);
* two runs give identical logs;
* a program LinuxCNC refuses and a following-error stop raise InputError
  naming the line.
"""

from __future__ import annotations

import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from ilcnc.axislog.halsampler import commands_from_lines, read_halsampler
from ilcnc.errors import InputError
from ilcnc.program import read_program
from ilcnc.shop import linuxcnc as lcnc
from ilcnc.shop import linuxcnc_config as lcnc_config

REPO = Path(__file__).resolve().parents[2]
SQUARE = REPO / "samples" / "own" / "square.ngc"
CONFIG = REPO / "configs" / "linuxcnc-sim"

HAVE_LINUXCNC = shutil.which("linuxcnc") is not None
needs_linuxcnc = [
    pytest.mark.linuxcnc,
    pytest.mark.skipif(
        not HAVE_LINUXCNC,
        reason="LinuxCNC is not installed ('linuxcnc' not on PATH; Debian 12: apt-get install linuxcnc-uspace): "
        "cannot run programs on LinuxCNC's motion controller",
    ),
]


def _mark(f):  # type: ignore[no-untyped-def]
    for m in needs_linuxcnc:
        f = m(f)
    return f


# ---------------------------------------------------------------------------
# LinuxCNC runs (shared: each launch costs seconds)
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def square_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, lcnc.RunResult]:
    d = tmp_path_factory.mktemp("lcnc-square")
    runs: dict[str, lcnc.RunResult] = {}
    for name, k in (("k1", 1), ("k4", 4), ("k4b", 4)):
        t = time.monotonic()
        runs[name] = lcnc.run_program(SQUARE, CONFIG, d / f"square-{name}.log", time_scale=k, settle_s=0.2)
        runs[name].messages.append(f"test: call took {time.monotonic() - t:.2f} s")
    return runs


def _as_array(r: lcnc.RunResult) -> np.ndarray:
    log = r.log
    return np.column_stack([log.t_s, log.line, log.ref_mm, log.act_mm])


def _point_to_path(p: np.ndarray, path: np.ndarray) -> float:
    """Distance from point p to the polyline through the samples (mm)."""
    a, b = path[:-1], path[1:]
    d = b - a
    n2 = (d * d).sum(axis=1)
    n2[n2 == 0] = 1.0
    u = np.clip(((p - a) * d).sum(axis=1) / n2, 0.0, 1.0)
    q = a + u[:, None] * d
    return float(np.sqrt(((q - p) ** 2).sum(axis=1)).min())


@_mark
def test_square_log_has_program_lines_in_order(square_runs: dict[str, lcnc.RunResult], record_property) -> None:  # type: ignore[no-untyped-def]
    r = square_runs["k1"]
    for name, run in square_runs.items():
        record_property(f"{name}_wall_s", round(run.wall_s, 2))
        record_property(f"{name}_program_s", round(run.program_s, 3))
    prog = read_program(SQUARE)
    log = r.log
    assert log.n_samples > 4000
    assert log.t_s[0] == 0.0 and np.allclose(np.diff(log.t_s), r.period_s)
    seen = log.line[np.r_[True, np.diff(log.line) != 0]].tolist()
    assert seen == prog.moves.line.tolist()  # every motion line, in program order (3..9)
    k = commands_from_lines(log.line, prog)
    ks = k[np.r_[True, np.diff(k) != 0]]
    assert ks[ks >= 0].tolist() == list(range(prog.n_commands))
    # the settle tail belongs to the last block and the axes come to rest on the programmed end point
    assert log.line[-1] == prog.moves.line[-1]
    assert np.allclose(log.ref_mm[-1], prog.moves.end_mm[-1], atol=1e-6)
    assert np.abs(log.act_mm[-1] - log.ref_mm[-1]).max() < 0.01
    # the raw log at log_path reads back to the same axis log
    back = read_halsampler(r.log_path, period_s=r.period_s, tail_s=0.2)
    assert np.array_equal(back.ref_mm, log.ref_mm) and np.array_equal(back.line, log.line)


@_mark
def test_commanded_path_passes_corners_within_g64_tolerance(square_runs: dict[str, lcnc.RunResult]) -> None:
    text = SQUARE.read_text()
    tol = float(re.search(r"G64\s*P\s*([0-9.]+)", text).group(1))  # type: ignore[union-attr]
    log = square_runs["k1"].log
    path = log.ref_mm[(log.line >= 4) & (log.line <= 9)]  # G1 Z0, the four edges, G0 Z5
    corners = {(0.0, 0.0, 0.0): None, (50.0, 0.0, 0.0): True, (50.0, 50.0, 0.0): True, (0.0, 50.0, 0.0): True}
    for corner, blended in corners.items():
        dist = _point_to_path(np.array(corner), path)
        # within P; 1 % for LinuxCNC's own blend-arc sizing (measured: 0.0502 mm at P0.05)
        assert dist <= 1.01 * tol, (corner, dist)
        if blended:  # the 90 degree XY corners are blended with about the full tolerance (not an exact stop)
            assert dist > 0.5 * tol, (corner, dist)


@_mark
def test_actual_lags_commanded_by_v_over_kv(square_runs: dict[str, lcnc.RunResult]) -> None:
    kv = float(lcnc_config.read_ini(CONFIG)["ILCNC"]["KV"])
    v = 3000.0 / 60.0  # F3000 in mm/s
    log = square_runs["k1"].log
    dt = square_runs["k1"].period_s
    for line, axis, sign in ((5, 0, 1.0), (6, 1, 1.0), (7, 0, -1.0), (8, 1, -1.0)):
        m = log.line == line
        ref, act = log.ref_mm[m, axis], log.act_mm[m, axis]
        speed = sign * np.gradient(ref) / dt
        steady = np.abs(speed - v) < 1e-6
        assert steady.sum() > 500  # most of each 50 mm edge runs at F3000
        lag = sign * (ref - act)[steady]
        # type-1 loop: following error v / Kv once the transient after the corner has died out
        settled = lag[len(lag) // 2 :]
        assert np.abs(settled - v / kv).max() < 1e-5, (line, settled.min(), settled.max(), v / kv)


@_mark
def test_time_scaled_run_gives_the_same_log(square_runs: dict[str, lcnc.RunResult]) -> None:
    a, b = _as_array(square_runs["k1"]), _as_array(square_runs["k4"])
    assert square_runs["k4"].time_scale == 4
    assert a.shape == b.shape
    assert np.abs(a[:, 2:5] - b[:, 2:5]).max() <= 1e-6  # commanded path
    assert np.abs(a[:, 5:8] - b[:, 5:8]).max() <= 1e-6  # actual path
    assert np.array_equal(a[:, :2], b[:, :2])  # time and line
    # and faster: the program's motion took about a quarter of the wall time
    assert square_runs["k4"].program_wall_s < 0.5 * square_runs["k1"].program_wall_s


@_mark
def test_two_runs_are_identical(square_runs: dict[str, lcnc.RunResult]) -> None:
    a, b = _as_array(square_runs["k4"]), _as_array(square_runs["k4b"])
    assert a.shape == b.shape and np.array_equal(a, b)


@_mark
def test_refused_program_names_the_line(tmp_path: Path) -> None:
    prog = tmp_path / "refused.ngc"
    prog.write_text("(refused by LinuxCNC)\nG21 G90 G17\nG0 X0 Y0 Z0\nG1 F3000 X10\nG1 X1 Q\nX0\nM2\n")
    with pytest.raises(InputError) as ei:
        lcnc.run_program(prog, CONFIG, tmp_path / "refused.log")
    e = ei.value
    assert e.line == 5 and e.file == str(prog)
    assert "refused" in e.problem and "reading real value" in e.problem
    assert "\n" not in str(e)


@_mark
def test_following_error_stop_is_an_input_error(tmp_path: Path) -> None:
    prog = tmp_path / "fast.ngc"
    prog.write_text("G21 G90 G17 G64 P0.05 Q0\nG0 X0 Y0 Z0\nG1 F6000 X50\nY50\nX0\nM2\n")
    # F6000 = 100 mm/s lags 100 / KV = 3.3 mm: more than a 1 mm following-error limit
    tight = {f"JOINT_{j}": {"FERROR": 1, "MIN_FERROR": 1} for j in range(3)}
    with pytest.raises(InputError) as ei:
        lcnc.run_program(prog, CONFIG, tmp_path / "fast.log", time_scale=4, ini_overrides=tight)
    assert "following error" in ei.value.problem
    assert ei.value.line == 3


# ---------------------------------------------------------------------------
# No LinuxCNC needed
# ---------------------------------------------------------------------------


def test_not_installed_is_an_input_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(lcnc.shutil, "which", lambda name: None)
    with pytest.raises(InputError, match="not installed"):
        lcnc.run_program(SQUARE, CONFIG, tmp_path / "x.log")


def test_time_scale_out_of_range(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="time scale"):
        lcnc.run_program(SQUARE, CONFIG, tmp_path / "x.log", time_scale=lcnc.MAX_TIME_SCALE + 1)


def test_scale_program_time_keeps_lines_and_scales_feeds_and_dwells() -> None:
    src = (
        "(F100 in a comment)\n"
        "N10 G1 X10 F3000 ; F7\n"
        "g1x1f1234.5\n"
        "G1 F#1 X2\n"
        "G1 F[#<f>*2]\n"
        "o100 if [#1 GT 2]\n"
        "G4 P0.5\n"
        "G64 P0.05 Q0\n"
        "G1 X[fix[2.5]] F 100 Y1\n"
        "%\n"
    )
    out = lcnc_config.scale_program_time(src, 4)
    assert out.count("\n") == src.count("\n")
    assert out.splitlines() == [
        "(F100 in a comment)",
        "N10 G1 X10 F12000 ; F7",
        "g1x1f4938",
        "G1 F[#1*4] X2",
        "G1 F[[#<f>*2]*4]",
        "o100 if [#1 GT 2]",
        "G4 P0.125",
        "G64 P0.05 Q0",
        "G1 X[fix[2.5]] F400 Y1",
        "%",
    ]
    assert lcnc_config.scale_program_time(src, 1) == src


def test_scaled_ini_text() -> None:
    ini = (
        "[EMCMOT]\nSERVO_PERIOD = 1000000\n[ILCNC]\nKV = 30\nLP_GAIN = 0.181\n"
        "[TRAJ]\nMAX_LINEAR_VELOCITY = 100\nMAX_LINEAR_ACCELERATION = 1000\n# MAX_VELOCITY = 5\n"
        "[JOINT_0]\nMAX_VELOCITY = 100\nFERROR = 10\nHOME_SEARCH_VEL = 0\n"
    )
    overrides = {"JOINT_0": {"FERROR": 1, "MIN_FERROR": 0.5}, "NEW": {"A": 1}}
    out = lcnc_config.read_ini_text(lcnc_config.scaled_ini_text(ini, 4, overrides))
    assert out["EMCMOT"]["SERVO_PERIOD"] == "250000"
    assert out["ILCNC"] == {"KV": "120", "LP_GAIN": "0.181"}
    # LinuxCNC's default ramp frequency (100 Hz), which the INI leaves out, written out and scaled: a rate x k
    assert out["TRAJ"] == {"MAX_LINEAR_VELOCITY": "400", "MAX_LINEAR_ACCELERATION": "16000",
                           "ARC_BLEND_RAMP_FREQ": "400"}
    assert out["JOINT_0"] == {"MAX_VELOCITY": "400", "FERROR": "1", "HOME_SEARCH_VEL": "0", "MIN_FERROR": "0.5"}
    assert out["NEW"] == {"A": "1"}
    with pytest.raises(InputError, match="divisible"):
        lcnc_config.scaled_ini_text(ini, 3)
    # the INI's own value is scaled, an override is taken as a real-time value and scaled too; k = 1: as written
    own = ini.replace("[TRAJ]\n", "[TRAJ]\nARC_BLEND_RAMP_FREQ = 50\n")
    assert lcnc_config.read_ini_text(lcnc_config.scaled_ini_text(own, 8))["TRAJ"]["ARC_BLEND_RAMP_FREQ"] == "400"
    ov = lcnc_config.scaled_ini_text(ini, 2, {"TRAJ": {"ARC_BLEND_RAMP_FREQ": 30}})
    assert lcnc_config.read_ini_text(ov)["TRAJ"]["ARC_BLEND_RAMP_FREQ"] == "60"
    assert lcnc_config.scaled_ini_text(ini, 1) == ini


_HALSAMPLER = """\
overrun
7 0 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000
8 0 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000
9 3 0.000000 0.000000 0.000042 0.000000 0.000000 0.000000
10 3 0.000000 0.000000 0.000375 0.000000 0.000000 0.000010
11 4 0.000000 0.000000 0.001417 0.000000 0.000000 0.000100
12 0 0.000000 0.000000 0.002000 0.000000 0.000000 0.000900
13 0 0.000000 0.000000 0.002000 0.000000 0.000000 0.001500
14 0 0.000000 0.000000 0.002000 0.000000 0.000000 0.001900
"""


def test_read_halsampler_aligns_and_fills_the_tail(tmp_path: Path) -> None:
    p = tmp_path / "run.log"
    p.write_text(_HALSAMPLER)
    log = read_halsampler(p, period_s=0.001)
    assert log.t_s.tolist() == pytest.approx([0.0, 0.001, 0.002, 0.003, 0.004, 0.005])
    assert log.line.tolist() == [3, 3, 4, 4, 4, 4]  # the settle tail belongs to the last block
    assert log.k.tolist() == [-1] * 6
    assert log.ref_mm[0, 2] == pytest.approx(0.000042) and log.act_mm[-1, 2] == pytest.approx(0.0019)
    short = read_halsampler(p, period_s=0.001, tail_s=0.001)
    assert short.n_samples == 4
    raw = read_halsampler(p, period_s=0.001, align=False)
    assert raw.n_samples == 8 and raw.line.tolist()[:2] == [0, 0]
    # a column map: a real machine's log without sample numbers and only X/Y
    q = tmp_path / "xy.log"
    q.write_text("0 1.0 2.0 0.9 1.9\n5 1.5 2.0 1.0 1.95\n5 2.0 2.0 1.5 2.0\n")
    xy = read_halsampler(q, columns="line x_ref y_ref x_act y_act", period_s=0.0005)
    assert xy.n_samples == 2 and not xy.has_z and xy.t_s.tolist() == [0.0, 0.0005]
    by_map = read_halsampler(q, columns={"x_ref": 1, "y_ref": 2, "x_act": 3, "y_act": 4}, period_s=0.0005)
    assert by_map.n_samples == 2 and by_map.ref_mm[0, 0] == 1.5  # aligned on the first commanded change


def test_read_halsampler_refuses_lost_samples_and_bad_numbers(tmp_path: Path) -> None:
    p = tmp_path / "gap.log"
    p.write_text(_HALSAMPLER.replace("11 4", "13 4").replace("12 0", "14 0").replace("13 0", "15 0").replace("14 0", "16 0"))
    with pytest.raises(InputError, match="samples lost") as ei:
        read_halsampler(p)
    assert ei.value.line == 6
    p.write_text(_HALSAMPLER.replace("0.000375", "abc"))
    with pytest.raises(InputError, match="not a number") as ei:
        read_halsampler(p)
    assert ei.value.line == 5
    p.write_text(_HALSAMPLER.replace(" 3 ", " 0 ").replace(" 4 ", " 0 "))
    with pytest.raises(InputError, match="non-zero program line"):
        read_halsampler(p)
    with pytest.raises(InputError, match="lacks"):
        read_halsampler(p, columns=("n", "line", "x_ref"))


def test_commands_from_lines_follows_execution_order() -> None:
    prog = read_program(SQUARE)  # lines 3..9; commands k = 0..4 on lines 4..8
    line = np.array([3, 3, 4, 5, 5, 6, 7, 8, 9, 9, 12, 0])
    k = commands_from_lines(line, prog)
    assert k.tolist() == [-1, -1, 0, 1, 1, 2, 3, 4, -1, -1, -1, -1]


def test_a_stray_percent_is_refused_before_linuxcnc_starts(tmp_path: Path) -> None:
    # compass.ngc ends with '%' but does not start with one: LinuxCNC said "Bad character '%' used" only when the
    # run reached its last line, 75 s later at time scale 8. Refused before launching, with the line.
    prog = tmp_path / "compass.ngc"
    prog.write_bytes((REPO / "samples" / "compass.ngc").read_bytes())
    n = len(prog.read_text().splitlines())
    with pytest.raises(InputError) as ei:
        lcnc.run_program(prog, CONFIG, tmp_path / "x.log")
    assert ei.value.line == n and "add '%' as the first line" in ei.value.problem
    assert lcnc.stray_percent_line("%\nG1 X1\n%\n") is None  # a delimited program
    assert lcnc.stray_percent_line("G1 X1 (50% speed)\nM2\n") is None  # a % in a comment


# ---------------------------------------------------------------------------
# Restarts after dwells (the dwell gate, configs/linuxcnc-sim/README.md)
# ---------------------------------------------------------------------------

#: Two dwells, each followed by a plunge and 60 wavy G1 blocks of 1 mm at F3000 (20 ms a block).
_DWELL_PROGRAM = "\n".join(
    ["G21 G90 G17 G94", "G64 P0.01", "G0 X0 Y0 Z5", "G0 X10 Y0 Z1", "G4 P0.2", "G1 Z0 F3000"]
    + [f"G1 X{10 + i:.4f} Y{0.5 * np.sin(i * 0.2):.4f}" for i in range(1, 61)]
    + ["G0 Z5", "G0 X0 Y20", "G0 Z1", "G4 P0.15", "G1 Z0 F3000"]
    + [f"G1 X{i:.4f} Y{20 + 0.5 * np.cos(i * 0.15):.4f}" for i in range(1, 61)]
    + ["G0 Z5", "M2", ""])
#: (line of the plunge after each dwell, the dwell's P in s, line of the retract that ends its stretch)
_RESTARTS = ((6, 0.2, 67), (71, 0.15, 132))


@_mark
def test_restart_after_a_dwell_is_the_same_at_any_time_scale(tmp_path: Path) -> None:
    prog = tmp_path / "dwell.ngc"
    prog.write_text(_DWELL_PROGRAM)
    lines = _DWELL_PROGRAM.splitlines()
    assert [lines[a - 1].split()[0] for a, _, b in _RESTARTS] == ["G1", "G1"]
    assert [lines[b - 1] for _, _, b in _RESTARTS] == ["G0 Z5", "G0 Z5"]
    runs = {k: lcnc.run_program(prog, CONFIG, tmp_path / f"k{k}.log", time_scale=k) for k in (1, 8)}
    for r in runs.values():
        # the gate held both restarts; task's refill after a dwell no longer reads as a queue that ran low,
        # so the time-scaled run is not repeated at a smaller scale (it was: 8 -> 4 -> 2 -> 1)
        assert r.dwells_held == 2 and r.dwells_missed == 0, r.messages
        assert not any("ran low" in m for m in r.messages), r.messages
    assert runs[8].time_scale == 8
    a, b = runs[1].log, runs[8].log
    for start, p_s, end in _RESTARTS:
        i, j = int(np.flatnonzero(a.line == start)[0]), int(np.flatnonzero(b.line == start)[0])
        for log, s in ((a, i), (b, j)):
            still = s - 1
            while still > 0 and np.array_equal(log.ref_mm[still - 1], log.ref_mm[s - 1]):
                still -= 1
            # task dwells at least P once motion has stopped (longer by its own wall-clock latency)
            assert s - still >= round(p_s / runs[1].period_s)
        n = int(np.flatnonzero(a.line == end)[0]) - i
        assert n > 60 * 15  # the whole stretch: 60 blocks of 20 ms
        # from the restart on, the commanded path is k = 1's sample for sample (the planner saw the same queue)
        assert np.abs(a.ref_mm[i:i + n] - b.ref_mm[j:j + n]).max() <= 1e-6
        # the axes start from the lag the dwell left, which differs with the dwell's length. The drives are linear
        # and overdamped (Kv 30/s, tau 5 ms: damping 1/(2 sqrt(Kv tau)) = 1.29), so the two actual paths differ by
        # the free response to the difference of their states at the restart (at rest after the dwell): never more
        # than that difference, at most the sum of the two residual lags
        lag = np.abs(a.act_mm[i] - a.ref_mm[i]).max() + np.abs(b.act_mm[j] - b.ref_mm[j]).max()
        assert np.abs(a.act_mm[i:i + n] - b.act_mm[j:j + n]).max() <= lag + 1e-6
