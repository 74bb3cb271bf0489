"""Axis-log CSV: round trip and refusal of broken logs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ilcnc.axislog.detect import detect_log_format, read_log
from ilcnc.axislog.log import AxisLog, format_axis_log, read_axis_log, write_axis_log
from ilcnc.axislog.points import read_points
from ilcnc.axislog.tncscope import read_tncscope
from ilcnc.errors import InputError


def _log(n: int = 1000, z: bool = True) -> AxisLog:
    t = np.arange(n) * 0.001
    ref = np.column_stack([np.sin(t), np.cos(t), t if z else np.full(n, np.nan)])
    act = ref - 0.001
    return AxisLog(t, np.arange(n) // 10, np.arange(n) // 10 + 5, ref, act)


def test_round_trip(tmp_path: Path) -> None:
    log = _log()
    p = write_axis_log(tmp_path / "a.csv", log)
    back = read_axis_log(p)
    assert p.read_text().splitlines()[0] == "t_s,k,line,x_ref,y_ref,z_ref,x_act,y_act,z_act"
    assert np.allclose(back.ref_mm, log.ref_mm, atol=1e-6) and np.allclose(back.act_mm, log.act_mm, atol=1e-6)
    assert back.k.tolist() == log.k.tolist() and back.line.tolist() == log.line.tolist()


def test_two_axis_log_has_no_z(tmp_path: Path) -> None:
    p = write_axis_log(tmp_path / "a.csv", _log(z=False))
    assert p.read_text().splitlines()[0] == "t_s,k,line,x_ref,y_ref,x_act,y_act"
    assert not read_axis_log(p).has_z


@pytest.mark.parametrize(
    ("edit", "line", "needle"),
    [
        (lambda rows: rows.__setitem__(5, ",".join([*rows[5].split(",")[:3], "nan", *rows[5].split(",")[4:]])), 6,
         "x_ref is not a finite number"),
        (lambda rows: rows.__delitem__(slice(100, 110)), 101, "gap"),
        (lambda rows: rows.__setitem__(50, rows[50][: len(rows[50]) // 2]), 51, "columns"),
        (lambda rows: rows.__setitem__(0, "t,x,y"), 1, "header"),
        (lambda rows: rows.insert(20, rows[19]), 21, "does not increase"),
    ],
)
def test_broken_logs_are_refused_with_their_line(tmp_path: Path, edit, line: int | None, needle: str) -> None:
    rows = format_axis_log(_log()).splitlines()
    edit(rows)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError) as info:
        read_axis_log(p)
    assert needle in str(info.value)
    if line is not None:
        assert info.value.line == line
    assert "\n" not in str(info.value)


# ---------------------------------------------------------------------------
# Comment lines in ilcnc logs, TNCscope exports, measured points, read_log
# ---------------------------------------------------------------------------

DATA = Path(__file__).parent / "data" / "logs"


def test_axis_log_skips_leading_comment_lines_and_keeps_line_numbers(tmp_path: Path) -> None:
    log = read_axis_log(DATA / "ilcnc.csv")
    assert log.t_s.tolist() == [0.0, 0.001, 0.002, 0.003]
    assert log.k.tolist() == [0, 0, 1, 1] and log.line.tolist() == [3, 3, 4, 4]
    assert log.ref_mm[:, 0].tolist() == [0.0, 0.01, 0.03, 0.06] and not log.has_z
    rows = (DATA / "ilcnc.csv").read_text().splitlines()
    rows[5] = rows[5].replace("0.015000", "nan")  # file line 6
    p = tmp_path / "c.csv"
    p.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError, match="x_act is not a finite number") as info:
        read_axis_log(p)
    assert info.value.line == 6
    rows = (DATA / "ilcnc.csv").read_text().splitlines()
    rows[2] = "t,x,y"
    p.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError, match="header") as info:
        read_axis_log(p)
    assert info.value.line == 3


def test_tncscope_english_comma_ms_mm() -> None:
    log = read_tncscope(DATA / "tncscope_en.csv")
    assert log.t_s.tolist() == (np.arange(8.0) * 1e-3).tolist()
    assert log.line.tolist() == [12, 12, 12, 13, 13, 13, 13, 13]  # "NC block number", not the "Program line" text
    assert log.k.tolist() == [-1] * 8
    assert log.ref_mm[:, 0].tolist() == [0.0, 0.01, 0.03, 0.06, 0.1, 0.15, 0.2, 0.25]
    assert log.ref_mm[:, 1].tolist() == [0.0, 0.0, 0.0, 0.0, 0.001, 0.004, 0.009, 0.016]
    assert log.ref_mm[:, 2].tolist() == [-1.0] * 8
    assert log.act_mm[:, 0].tolist() == [0.0, 0.002, 0.015, 0.04, 0.078, 0.125, 0.174, 0.224]  # not the following error
    assert log.act_mm[:, 1].tolist() == [0.0, 0.0, 0.0, 0.0, 0.0, 0.001, 0.005, 0.011]
    assert log.act_mm[:, 2].tolist() == [-1.0, -1.0, -0.999, -1.0, -1.001, -1.0, -1.0, -1.0]
    assert log.has_z


def test_tncscope_german_semicolon_decimal_comma_um_cp1252() -> None:
    assert b"\xb5m" in (DATA / "tncscope_de.csv").read_bytes()  # Windows-1252 micro sign, CRLF lines
    log = read_tncscope(DATA / "tncscope_de.csv")
    assert log.t_s.tolist() == (np.array([0.0, 0.6, 1.2, 1.8, 2.4, 3.0, 3.6]) * 1e-3).tolist()
    assert log.line.tolist() == [0, 0, 7, 7, 7, 8, 8]  # empty "Satznummer" cells are 0
    ref_x = np.array([10000, 10000, 9999.5, 9998, 9995.5, 9992, 9987.5]) * 1e-3
    act_y = np.array([0, 0, 99.1, 198.7, 298.2, 397.9, 497.4]) * 1e-3
    assert log.ref_mm[:, 0].tolist() == ref_x.tolist()
    assert log.act_mm[:, 1].tolist() == act_y.tolist()
    assert log.ref_mm[:, 1].tolist() == (np.array([0, 0, 100.2, 200.4, 300.5, 400.6, 500.5]) * 1e-3).tolist()
    assert log.act_mm[:, 0].tolist() == (np.array([10000, 10000, 10000, 9999.1, 9997.3, 9994.6, 9990.8]) * 1e-3).tolist()
    assert not log.has_z and np.isnan(log.ref_mm[:, 2]).all()


def test_tncscope_time_from_sampling_line_tab_separated_inch() -> None:
    log = read_tncscope(DATA / "tncscope_sampling.txt")
    assert log.t_s.tolist() == (np.arange(5) * 0.5e-3).tolist()
    assert log.line.tolist() == [0] * 5  # no block-number column
    assert log.ref_mm[:, 0].tolist() == (np.array([1.0, 1.001, 1.003, 1.006, 1.01]) * 25.4).tolist()
    assert log.act_mm[:, 1].tolist() == (np.array([2.0, 2.0, 2.0001, 2.0008, 2.0021]) * 25.4).tolist()  # not "v act X"
    assert not log.has_z


def test_tncscope_unit_row_and_unitless_time_matched_to_sampling_time(tmp_path: Path) -> None:
    p = tmp_path / "u.csv"
    p.write_text("Abtastzeit: 3 ms\nZeit;Lage-Soll X;Lage-Soll Y;Istposition X;Istposition Y\n"
                 "[s];[mm];[mm];[um];[um]\n0,000;1;2;1000;2000\n0,003;1,5;2;1100;2000\n")
    log = read_tncscope(p)
    assert log.t_s.tolist() == [0.0, 0.003]  # the unit row says s
    assert log.act_mm[:, 0].tolist() == [1.0, 1.1] and log.ref_mm[:, 0].tolist() == [1.0, 1.5]
    p.write_text("Abtastzeit: 3 ms\nZeit;X soll;Y soll;X ist;Y ist\n0;1;2;1;2\n3;1,5;2;1,1;2\n")
    assert read_tncscope(p).t_s.tolist() == [0.0, 0.003]  # no unit: ms, as the sampling time says


def test_tncscope_quoted_utf16_tab_export(tmp_path: Path) -> None:
    p = tmp_path / "q.txt"
    text = ('"Abtastzeit"\t"0,6 ms"\r\n"t [s]"\t"Satz-Nr."\t"s nom X [mm]"\t"s nom Y [mm]"\t"s act X [mm]"\t"s act Y [mm]"\r\n'
            '"0,0000"\t"N10"\t"1,5"\t"2"\t"1,5"\t"2"\r\n"0,0006"\t"N20"\t"1,6"\t"2"\t"1,55"\t"2"\r\n')
    p.write_bytes(text.encode("utf-16"))
    log = read_tncscope(p)
    assert log.t_s.tolist() == [0.0, 0.0006] and log.line.tolist() == [10, 20]
    assert log.ref_mm[:, 0].tolist() == [1.5, 1.6] and log.act_mm[:, 0].tolist() == [1.5, 1.55]
    assert detect_log_format(p) == "tncscope"


def test_tncscope_columns_override(tmp_path: Path) -> None:
    log = read_tncscope(DATA / "tncscope_en.csv", columns={"line": None, "x_act": "X following error"})
    assert log.line.tolist() == [0] * 8
    assert log.act_mm[:, 0].tolist() == [0.0, 0.008, 0.015, 0.02, 0.022, 0.025, 0.026, 0.026]
    p = tmp_path / "raw.csv"  # no header at all: every column by index
    p.write_text("0.5,3,1.0,2.0,1.1,2.1\n1.0,3,1.5,2.0,1.4,2.1\n")
    log = read_tncscope(p, columns={"t_s": 0, "line": 1, "x_ref": 2, "y_ref": 3, "x_act": 4, "y_act": 5})
    assert log.t_s.tolist() == [0.5e-3, 1.0e-3] and log.line.tolist() == [3, 3]
    assert log.ref_mm[:, 0].tolist() == [1.0, 1.5] and log.act_mm[:, 1].tolist() == [2.1, 2.1]
    with pytest.raises(InputError, match="unknown TNCscope column name"):
        read_tncscope(p, columns={"x_nom": 2})
    with pytest.raises(InputError, match="'Pos X'"):
        read_tncscope(DATA / "tncscope_en.csv", columns={"x_act": "Pos X"})


def _en_rows() -> list[str]:
    return (DATA / "tncscope_en.csv").read_text().splitlines()


def _broken(tmp_path: Path, rows: list[str]) -> Path:
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(rows) + "\n")
    return p


def _drop_column(rows: list[str], col: int) -> list[str]:
    return rows[:5] + [",".join(c for i, c in enumerate(r.split(",")) if i != col) for r in rows[5:]]


@pytest.mark.parametrize(
    ("edit", "line", "needles"),
    [
        (lambda r: r.__setitem__(10, r[10].replace("0.078000", "nan")), 11,
         ("column 7 ('X actual position [mm]') is not a finite number", "'nan'")),
        (lambda r: r.__setitem__(10, r[10].replace("0.078000", "0,078")), 11, ("12 columns but the header has 11",)),
        (lambda r: r.__setitem__(10, r[10].replace("0.078000", "0.07.8")), 11, ("column 7", "'0.07.8' is not a number")),
        (lambda r: r.__setitem__(10, r[10].replace(",0.001000,", ",,")), 11, ("column 5", "is empty")),
        (lambda r: r.__delitem__(slice(8, 10)), 9, ("gap of 3.000 ms", "sample period 1.000 ms")),
        (lambda r: r.__setitem__(9, "1.0" + r[9][3:]), 10, ("time does not increase",)),
        (lambda r: r.__setitem__(12, r[12][:40]), 13, ("expected at least 9 columns", "truncated")),
        (lambda r: r.__setitem__(slice(None), _drop_column(r, 7)), 6,
         ("lacks y_act", "x_ref='X nominal position [mm]'", "x_act='X actual position [mm]'", "t_s='Time [ms]'")),
        (lambda r: r.__setitem__(slice(None), [x for i, x in enumerate(_drop_column(r, 0)) if i != 3]), 5,
         ("lacks time", "no sampling-time line")),
        (lambda r: r.__setitem__(5, r[5].replace("[ms]", "[h]")), 6, ("column 1 ('Time [h]'): unknown time unit 'h'",)),
    ],
)
def test_broken_tncscope_exports_are_refused_with_their_line(tmp_path: Path, edit, line: int, needles: tuple[str, ...]) -> None:
    rows = _en_rows()
    edit(rows)
    with pytest.raises(InputError) as info:
        read_tncscope(_broken(tmp_path, rows))
    for needle in needles:
        assert needle in str(info.value)
    assert info.value.line == line
    assert str(info.value).startswith(f"{tmp_path / 'bad.csv'}:{line}: ")
    assert "\n" not in str(info.value)


def test_tncscope_without_any_header_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    p.write_text("some,thing\n1,2\n")
    with pytest.raises(InputError, match="no TNCscope header row found"):
        read_tncscope(p)
    p.write_text("")
    with pytest.raises(InputError, match="empty"):
        read_tncscope(p)
    p.write_text(_en_rows()[5] + "\n")
    with pytest.raises(InputError, match="header but no samples"):
        read_tncscope(p)


def test_read_points_k_layout() -> None:
    pts = read_points(DATA / "points_k.csv")
    assert pts.k is not None and pts.k.tolist() == [0, 1, 4] and pts.k.dtype == np.int64
    assert pts.xyz_mm is None
    assert pts.dev_mm.tolist() == [[0.012, -0.004, 0.001], [-0.003, 0.008, 0.0], [0.0005, 0.0, -0.002]]
    assert pts.line.tolist() == [3, 4, 5] and pts.n_points == 3


def test_read_points_xyz_layout_without_z() -> None:
    pts = read_points(DATA / "points_xy.csv")
    assert pts.k is None and pts.xyz_mm is not None
    assert pts.xyz_mm[:, :2].tolist() == [[10.0, 5.0], [-10.0, 5.0]] and np.isnan(pts.xyz_mm[:, 2]).all()
    assert pts.dev_mm.tolist() == [[0.012, -0.004, 0.0], [-0.003, 0.008, 0.0]]  # no dz: 0
    assert pts.line.tolist() == [2, 3]


@pytest.mark.parametrize(
    ("text", "line", "needle"),
    [
        ("", None, "empty points file"),
        ("# only a comment\n\n", None, "empty points file"),
        ("k,dx,dy,dz\n", None, "no points"),
        ("k,dx,dz\n0,1,2\n", 1, "lacks dy"),
        ("x,dx,dy\n0,1,2\n", 1, "lacks y"),
        ("k,dx,dy\n0,0.1,0.2\n1,abc,0.2\n", 3, "dx: 'abc' is not a number"),
        ("k,dx,dy\n0,0.1,inf\n", 2, "dy is not a finite number"),
        ("k,dx,dy\n0,0.1\n", 2, "expected 3 columns"),
        ("k,dx,dy\n-1,0.1,0.2\n", 2, "integer >= 0"),
        ("k,dx,dy\n1.5,0.1,0.2\n", 2, "integer >= 0"),
        ("k,dx,dy\n# note\n3,0.1,0.2\n4,0,0\n3,0.2,0.1\n", 5, "duplicate k=3 (first on line 3)"),
    ],
)
def test_broken_points_are_refused(tmp_path: Path, text: str, line: int | None, needle: str) -> None:
    p = tmp_path / "p.csv"
    p.write_text(text)
    with pytest.raises(InputError) as info:
        read_points(p)
    assert needle in str(info.value)
    assert info.value.line == line


def test_read_points_semicolon_decimal_comma_and_units(tmp_path: Path) -> None:
    p = tmp_path / "p.csv"
    p.write_text("K;DX [µm];DY [µm]\n2;12,5;-4\n")
    pts = read_points(p)
    assert pts.k is not None and pts.k.tolist() == [2]
    assert pts.dev_mm.tolist() == [[12.5e-3, -4e-3, 0.0]]


@pytest.mark.parametrize(
    ("name", "fmt"),
    [("ilcnc.csv", "ilcnc"), ("halsampler.txt", "halsampler"), ("tncscope_en.csv", "tncscope"),
     ("tncscope_de.csv", "tncscope"), ("tncscope_sampling.txt", "tncscope")],
)
def test_read_log_detects_the_format(name: str, fmt: str) -> None:
    assert detect_log_format(DATA / name) == fmt
    auto = read_log(DATA / name)
    given = read_log(DATA / name, fmt=fmt)
    assert auto.t_s.tolist() == given.t_s.tolist()
    assert np.array_equal(auto.act_mm, given.act_mm, equal_nan=True)


def test_read_log_halsampler_default_columns() -> None:
    log = read_log(DATA / "halsampler.txt", period_s=2e-3)
    assert log.t_s.tolist() == [0.0, 0.002, 0.004, 0.006, 0.008]  # aligned at the first program line
    assert log.line.tolist() == [4, 4, 5, 5, 5]  # the settle tail keeps the last line
    assert log.ref_mm.tolist() == [[0.01, 0.0, 5.0], [0.03, 0.0, 5.0], [0.06, 0.01, 5.0], [0.1, 0.03, 5.0], [0.1, 0.03, 5.0]]
    assert log.act_mm[:, 1].tolist() == [0.0, 0.0, 0.004, 0.018, 0.027]


def test_read_log_inch_units(tmp_path: Path) -> None:
    for name in ("ilcnc.csv", "halsampler.txt"):
        mm = read_log(DATA / name)
        inch = read_log(DATA / name, units="inch")
        assert np.array_equal(inch.ref_mm, mm.ref_mm * 25.4, equal_nan=True)
        assert np.array_equal(inch.act_mm, mm.act_mm * 25.4, equal_nan=True)
        assert inch.t_s.tolist() == mm.t_s.tolist()
    p = tmp_path / "scope.csv"
    p.write_text("Time [ms],X nom,Y nom,X act,Y act\n0,1,2,1,2\n1,1.5,2,1.25,2\n")
    assert read_log(p, units="inch").act_mm[:, 0].tolist() == [25.4, 1.25 * 25.4]  # header without a unit
    assert read_log(DATA / "tncscope_sampling.txt", units="inch").ref_mm[0, 0] == 25.4  # [inch] header: converted once
    with pytest.raises(InputError, match="is in mm, but the positions were said to be in inch") as info:
        read_log(DATA / "tncscope_en.csv", units="inch")
    assert info.value.line == 6


def test_read_log_refuses_bad_options(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown log format"):
        read_log(DATA / "ilcnc.csv", fmt="csv")
    with pytest.raises(ValueError, match="unknown log units"):
        read_log(DATA / "ilcnc.csv", units="cm")
    with pytest.raises(InputError, match="fixed column names"):
        read_log(DATA / "ilcnc.csv", columns={"x_ref": 3})
    with pytest.raises(InputError, match="file not found"):
        read_log(tmp_path / "missing.csv")
    (tmp_path / "empty.csv").write_text("\n\n")
    with pytest.raises(InputError, match="empty log file"):
        read_log(tmp_path / "empty.csv")


def test_an_axis_log_is_read_block_by_block_alike(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # issue 25 item 13: a 10 M-row log held its whole text, its lines and their join at once (a MemoryError under
    # 4 GB); rows are now parsed in blocks. Blocks of 7 rows read the same samples as one block, and errors keep
    # their file line across block boundaries.
    import ilcnc.axislog.log as log_mod

    n = 50
    t = np.arange(n) * 1e-3
    ref = np.column_stack([np.linspace(0, 5, n), np.zeros(n), np.zeros(n)])
    log = AxisLog(t, np.zeros(n, np.int64), np.full(n, 3, np.int64), ref, ref - 0.001)
    p = tmp_path / "a.csv"
    p.write_text("# two\n# comment lines\n" + format_axis_log(log) + "\n\n")
    whole = read_axis_log(p)
    monkeypatch.setattr(log_mod, "ROWS_PER_BLOCK", 7)
    small = read_axis_log(p)
    for a, b in ((whole.t_s, small.t_s), (whole.ref_mm, small.ref_mm), (whole.act_mm, small.act_mm)):
        assert np.array_equal(a, b)
    lines = p.read_text().splitlines()
    bad = lines.copy()
    bad[30] = bad[30].replace(",", ",x", 1)  # file line 31, in the fifth block of 7
    p.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError) as ei:
        read_axis_log(p)
    assert ei.value.line == 31 and "is not a number" in ei.value.problem
    gap = [*lines[:20], "", *lines[20:]]  # an empty line at file line 21, samples after it
    p.write_text("\n".join(gap) + "\n")
    with pytest.raises(InputError) as ei:
        read_axis_log(p)
    assert ei.value.line == 21 and ei.value.problem == "empty line in the axis log"
