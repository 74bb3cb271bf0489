"""Axis-log CSV: round trip and refusal of broken logs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import InputError
from ilcnc.logs import AxisLog, format_axis_log, read_axis_log, write_axis_log


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
