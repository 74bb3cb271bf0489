"""Bad input on the command line: exit 1, one line ``file:line: problem``, nothing written.

Every case runs ``python -m ilcnc`` as a user would (a subprocess) and checks
that it exits with code 1, prints exactly one line on stderr naming the file
(and the line, where one applies) and the problem, prints no traceback, and
leaves no output file and no temporary file behind.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from ilcnc import __version__

from .conftest import REPO

EXAMPLE_PROFILE = REPO / "configs" / "example-mill.yaml"

GOOD_GCODE = b"G21 G90 G17\nG0 X0 Y0 Z5\nG1 Z-1 F200\nG1 X10 Y0\nG1 X10 Y10\nG1 X0 Y10\nG1 X0 Y0\nG0 Z5\nM2\n"

HEIDENHAIN_SYNTAX_ERROR = (
    b"0 BEGIN PGM T MM\n"
    b"1 BLK FORM 0.1 Z X+0 Y+0 Z-10\n"
    b"2 BLK FORM 0.2 X+100 Y+100 Z+0\n"
    b"3 TOOL CALL 1 Z S1000\n"
    b"4 L X+0 Y+0 Z+5 R0 FMAX\n"
    b"5 L Z-1 F200\n"
    b"6 L X+10 Y+ R0 F500\n"  # a sign without a number
    b"7 L X+20 Y+0\n"
    b"8 END PGM T MM\n"
)


def run_cli(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ilcnc", *map(str, args)],
        capture_output=True, text=True, timeout=120, cwd=cwd,
    )


def assert_one_line_error(r: subprocess.CompletedProcess[str], file: Path, line: int | None, problem: str) -> str:
    """Exit 1, no traceback, one stderr line ``error: FILE[:LINE]: ...problem...``."""
    assert r.returncode == 1, f"exit code {r.returncode}\nstdout: {r.stdout}\nstderr: {r.stderr}"
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, f"stderr is not one line:\n{r.stderr}"
    msg = lines[0]
    assert msg.startswith("error: "), msg
    where = f"{file}:{line}: " if line is not None else f"{file}: "
    assert where in msg, f"{where!r} not in {msg!r}"
    assert re.search(problem, msg, re.IGNORECASE), f"{problem!r} not in {msg!r}"
    assert r.stdout == "", f"unexpected output on stdout: {r.stdout!r}"
    return msg


def assert_nothing_written(out_dir: Path) -> None:
    left = sorted(p.name for p in out_dir.iterdir())
    assert left == [], f"files left behind in the output directory: {left}"


@dataclass(frozen=True)
class BadProgram:
    """A program the reader must refuse: its name, bytes, and where/what the error is."""

    name: str
    data: bytes
    line: int | None
    problem: str


BAD_PROGRAMS = {
    "binary file": BadProgram("part.nc", bytes(range(256)) * 16, None, "binary"),
    "binary file with a G-code suffix and a text start": BadProgram("part.ngc", b"G21\nG1 X1\x00\x00\x01\x02" * 50, None,
                                                                    "binary"),
    "empty file": BadProgram("part.ngc", b"", None, "empty"),
    "blank file": BadProgram("part.ngc", b"  \n\r\n\t\n", None, "empty"),
    "truncated line (word without its number)": BadProgram("part.ngc", GOOD_GCODE[:GOOD_GCODE.index(b"G1 X10 Y10") + 8],
                                                           5, "Y word without a number"),
    "truncated line (comment cut off)": BadProgram("part.nc", b"G21 G90\nG1 F100 X1 Y1 (finish pa", 2, "comment"),
    # E belongs to M66/M67/M68 only (issue 21): a stray E is refused as rs274 refuses it
    "unknown word": BadProgram("part.ngc", GOOD_GCODE.replace(b"G1 X10 Y0\n", b"G1 X10 Y0 E5\n"), 4, "E word with no"),
    "unknown G code": BadProgram("part.ngc", GOOD_GCODE.replace(b"G1 X10 Y10\n", b"G1.7 X10 Y10\n"), 5, "G1.7"),
    "Heidenhain block with a syntax error": BadProgram("part.h", HEIDENHAIN_SYNTAX_ERROR, 7, "."),
}


def _write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


@pytest.fixture
def dirs(tmp_path: Path) -> tuple[Path, Path]:
    """(input directory, output directory); the output directory must stay empty."""
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    out.mkdir()
    return src, out


def _skip_without_heidenhain(bad: BadProgram) -> None:
    if bad.name.endswith(".h"):
        pytest.importorskip("ilcnc.program.heidenhain", reason="the Klartext reader is not there yet")


@pytest.mark.parametrize("case", list(BAD_PROGRAMS), ids=list(BAD_PROGRAMS))
def test_export_of_a_bad_program(case: str, dirs: tuple[Path, Path]) -> None:
    bad = BAD_PROGRAMS[case]
    _skip_without_heidenhain(bad)
    src_dir, out_dir = dirs
    prog = _write(src_dir / bad.name, bad.data)
    r = run_cli("export", prog, "--out", out_dir / ("out" + prog.suffix))
    assert_one_line_error(r, prog, bad.line, bad.problem)
    assert_nothing_written(out_dir)
    assert prog.read_bytes() == bad.data


@pytest.mark.parametrize("case", list(BAD_PROGRAMS), ids=list(BAD_PROGRAMS))
def test_inspect_of_a_bad_program(case: str, dirs: tuple[Path, Path]) -> None:
    bad = BAD_PROGRAMS[case]
    _skip_without_heidenhain(bad)
    src_dir, out_dir = dirs
    prog = _write(src_dir / bad.name, bad.data)
    r = run_cli("inspect", prog, "--moves", out_dir / "moves.csv")
    assert_one_line_error(r, prog, bad.line, bad.problem)
    assert_nothing_written(out_dir)


def test_corrections_with_a_k_that_does_not_exist(dirs: tuple[Path, Path]) -> None:
    src_dir, out_dir = dirs
    prog = _write(src_dir / "part.ngc", GOOD_GCODE)  # 5 G01 commands: k = 0..4
    csv = _write(src_dir / "corr.csv", b"k,dx,dy,dz\n0,0.010,0,0\n# a comment\n5,0.010,0,0\n")
    r = run_cli("export", prog, "--out", out_dir / "out.ngc", "--corrections", csv)
    assert_one_line_error(r, csv, 4, r"k=5 does not exist")
    assert_nothing_written(out_dir)


@pytest.mark.parametrize(
    ("content", "line", "problem"),
    [
        (b"k,dx,dy,dz\n-1,0.01,0,0\n", 2, "does not exist"),
        (b"k,dx,dy,dz\n1.5,0.01,0,0\n", 2, "not an integer"),
        (b"k,dx,dy,dz\n1,abc,0,0\n", 2, "not a number"),
        (b"k,dx,dy,dz\n1,nan,0,0\n", 2, "not finite"),
        (b"k,dx,dy,dz\n1,0.01,0,0\n1,0.02,0,0\n", 3, "twice"),
        (b"x,y,z\n", 1, "header"),
        (b"", None, "empty"),
    ],
    ids=["negative k", "fractional k", "bad number", "nan", "repeated k", "bad header", "empty file"],
)
def test_other_bad_corrections(content: bytes, line: int | None, problem: str, dirs: tuple[Path, Path]) -> None:
    src_dir, out_dir = dirs
    prog = _write(src_dir / "part.ngc", GOOD_GCODE)
    csv = _write(src_dir / "corr.csv", content)
    r = run_cli("export", prog, "--out", out_dir / "out.ngc", "--corrections", csv)
    assert_one_line_error(r, csv, line, problem)
    assert_nothing_written(out_dir)


def _negative_jerk_profile(src_dir: Path) -> tuple[Path, int]:
    """The example profile with the X axis' jerk made negative; returns (path, line of that key)."""
    lines = EXAMPLE_PROFILE.read_text(encoding="utf-8").splitlines(keepends=True)
    for i, text in enumerate(lines):
        if re.match(r"\s+max_jerk_m_s3:\s*[0-9.]+\s*(#.*)?$", text):
            lines[i] = re.sub(r"max_jerk_m_s3:\s*[0-9.]+", "max_jerk_m_s3: -5", text)
            break
    else:  # pragma: no cover - the example profile changed
        pytest.fail("no max_jerk_m_s3 key in configs/example-mill.yaml")
    path = src_dir / "mill.yaml"
    path.write_text("".join(lines), encoding="utf-8")
    return path, i + 1


@pytest.mark.parametrize("command", ["export", "inspect"])
def test_profile_with_a_negative_jerk(command: str, dirs: tuple[Path, Path]) -> None:
    src_dir, out_dir = dirs
    prog = _write(src_dir / "part.ngc", GOOD_GCODE)
    profile, line = _negative_jerk_profile(src_dir)
    if command == "export":
        r = run_cli("export", prog, "--out", out_dir / "out.ngc", "--profile", profile)
    else:
        r = run_cli("inspect", prog, "--profile", profile, "--moves", out_dir / "moves.csv")
    assert_one_line_error(r, profile, line, r"max_jerk_m_s3.*-5")
    assert_nothing_written(out_dir)


@pytest.mark.parametrize(
    "setup",
    [
        "missing program",
        "program is a directory",
        "unknown output suffix",
        "output directory does not exist",
        "missing corrections file",
        "missing profile",
    ],
)
def test_other_bad_arguments(setup: str, dirs: tuple[Path, Path]) -> None:
    src_dir, out_dir = dirs
    prog = _write(src_dir / "part.ngc", GOOD_GCODE)
    out = out_dir / "out.ngc"
    cases: dict[str, Callable[[], tuple[list[str | Path], Path, str]]] = {
        "missing program": lambda: (["export", src_dir / "nope.ngc", "--out", out], src_dir / "nope.ngc", "not found"),
        "program is a directory": lambda: (["export", src_dir, "--out", out], src_dir, "directory"),
        "unknown output suffix": lambda: (["export", prog, "--out", out_dir / "out.docx"], out_dir / "out.docx",
                                          "suffix"),
        "output directory does not exist": lambda: (["export", prog, "--out", out_dir / "sub" / "out.ngc"],
                                                    out_dir / "sub" / "out.ngc", "does not exist"),
        "missing corrections file": lambda: (["export", prog, "--out", out, "--corrections", src_dir / "c.csv"],
                                             src_dir / "c.csv", "not found"),
        "missing profile": lambda: (["inspect", prog, "--profile", src_dir / "m.yaml"], src_dir / "m.yaml", "not found"),
    }
    args, file, problem = cases[setup]()
    r = run_cli(*args)
    assert_one_line_error(r, file, None, problem)
    assert_nothing_written(out_dir)


def test_export_never_writes_over_its_input(dirs: tuple[Path, Path]) -> None:
    src_dir, _ = dirs
    prog = _write(src_dir / "part.ngc", GOOD_GCODE)
    r = run_cli("export", prog, "--out", prog)
    assert_one_line_error(r, prog, None, "input")
    assert prog.read_bytes() == GOOD_GCODE
    assert sorted(p.name for p in src_dir.iterdir()) == ["part.ngc"]


def test_debug_shows_the_traceback(dirs: tuple[Path, Path]) -> None:
    src_dir, _ = dirs
    prog = _write(src_dir / "part.ngc", BAD_PROGRAMS["unknown word"].data)
    r = run_cli("--debug", "inspect", prog)
    assert r.returncode != 0
    assert "Traceback" in r.stderr and "E word with no" in r.stderr


# --------------------------------------------------------------------------- usage


def test_version() -> None:
    r = run_cli("--version")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"ilcnc {__version__}"


def test_version_of_the_console_script() -> None:
    script = shutil.which("ilcnc", path=str(Path(sys.executable).parent)) or shutil.which("ilcnc")
    if script is None:
        pytest.skip("the ilcnc console script is not installed (pip install -e .)")
    r = subprocess.run([script, "--version"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"ilcnc {__version__}"


@pytest.mark.parametrize("args", [["--help"], ["export", "--help"], ["inspect", "--help"]], ids=" ".join)
def test_help_exits_0(args: list[str]) -> None:
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    assert "Usage" in r.stdout
    if args == ["--help"]:
        assert "export" in r.stdout and "inspect" in r.stdout


@pytest.mark.parametrize(
    "args",
    [
        ["export", "--nonsense"],
        ["--nonsense"],
        ["inspect"],
        ["export", "part.ngc"],
        ["export", "part.ngc", "--out", "o.ngc", "--decimals", "99"],
        ["frobnicate"],
    ],
    ids=["unknown option", "unknown global option", "missing argument", "missing --out", "decimals out of range",
         "unknown command"],
)
def test_bad_usage_exits_2(args: list[str], tmp_path: Path) -> None:
    _write(tmp_path / "part.ngc", GOOD_GCODE)
    r = run_cli(*args, cwd=tmp_path)
    assert r.returncode == 2, f"exit code {r.returncode}\n{r.stderr}"
    assert "Traceback" not in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["part.ngc"]
