"""Every table fits 80 columns and cuts nothing (issue 23 item 7): names and numbers wrap, never end in '…'."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcnc.cli import app

from .conftest import OWN, REPO, SAMPLES

PROFILE = REPO / "configs" / "example-mill.yaml"
runner = CliRunner()


def _run(*args: object) -> str:
    res = runner.invoke(app, [str(a) for a in args], env={"COLUMNS": "80"})
    assert res.exit_code in (0, 1), res.output
    return res.stdout


def _fits(out: str) -> None:
    assert "…" not in out
    wide = [line for line in out.splitlines() if len(line) > 80]
    assert not wide, wide


def test_batch_table(tmp_path: Path) -> None:
    parts = tmp_path / "parts"
    parts.mkdir()
    shutil.copy(SAMPLES / "contour" / "locket_outside.ngc", parts / "locket_outside_with_a_long_name.ngc")
    shutil.copy(OWN / "square.ngc", parts)
    out = _run("batch", parts, "--profile", PROFILE, "--out", tmp_path / "out", "--iterations", "1")
    _fits(out)
    joined = "".join(out.split())  # a folded name continues on the next line
    assert "square.ngc" in out and "17.46→" in out and "44.03→44.05" in out and "max_iterations" in joined
    assert "example-mill.yaml" in out  # one profile: named once, in the title


@pytest.mark.parametrize("args", [
    ("tune", "--profile", PROFILE, "--method", "lifted", OWN / "square.ngc"),
    ("simulate", OWN / "star.ngc", "--profile", PROFILE),
])
def test_tune_and_simulate_tables(args: tuple[object, ...]) -> None:
    _fits(_run(*args))


def test_learn_table_and_one_line_per_iteration_when_piped(tmp_path: Path) -> None:
    res = runner.invoke(app, ["learn", str(OWN / "square.ngc"), "--profile", str(PROFILE), "--out",
                              str(tmp_path / "sq.ngc"), "--iterations", "1"], env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.output
    _fits(res.stdout)
    assert "44.03" in res.stdout
    # (a cold numba cache adds its one 'compiling' line: ilcnc._jit)
    assert [ln for ln in res.stderr.splitlines() if ln.startswith("learning:")] == [
        "learning: iteration 0/1", "learning: iteration 1/1"]
