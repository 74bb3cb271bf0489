"""Bad input that crashed, or was read wrong, or refused with the wrong exit code (issue 25 items 13, 15, 17).

Each case failed before its fix: a traceback (int16 overflow of an arc's turn count, a TypeError on a
manifest), a misleading message (a byte-order mark read as the word 'ï', CR line ends read as one block), a
silently accepted word (Q on a G1, which rs274 refuses), a log refused for a blank line after its last
sample, and usage errors that exited 1 instead of 2.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcnc.cli import app

REPO = Path(__file__).resolve().parents[1]
MILL = REPO / "configs" / "example-mill.yaml"
STAR = REPO / "samples" / "own" / "star.ngc"
runner = CliRunner()


def _one_error(res: object, code: int) -> str:
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception  # type: ignore[attr-defined]
    assert res.exit_code == code, res.output  # type: ignore[attr-defined]
    lines = [ln for ln in res.output.splitlines() if ln.strip()]  # type: ignore[attr-defined]
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


@pytest.mark.parametrize(("name", "text", "says"), [
    ("turns.ngc", b"G21 G90 G17\nG0 X0 Y0 Z1\nG1 Z-1 F100\nG2 X0 Y0 I5 J0 P32768\nM2\n",
     "turns.ngc:4: arc P32768: at most 10,000 turns of one arc or helix"),
    ("turns.h", b"0 BEGIN PGM T MM\n1 TOOL CALL 1 Z S1000\n2 L X+10 Y+0 Z+5 R0 FMAX\n3 CC X+0 Y+0\n4 L Z-1 F100\n"
                b"5 CP IPA+99999999 IZ-1 DR+\n6 END PGM T MM\n",
     "turns.h:6: CP sweeps 277,778 turns: at most 10,000 turns of one arc or helix"),
    ("q.ngc", b"G21 G90\nG0 X0 Y0\nG1 X10 Q5 F100\nM2\n",
     "q.ngc:3: Q word with no G5, G10, G64, G73, G76, G83, M19, M66, M67, M68 or user M code that uses it"),
    ("bom.ngc", b"\xef\xbb\xbfG21 G90\nG0 X0 Y0\nG1 X10 F100\nM2\n", "bom.ngc:1: the file starts with a UTF-8 byte-order mark"),
    ("cr.ngc", b"G21 G90\rG0 X0 Y0\rG1 X10 F100\rM2\r", "cr.ngc:1: its lines end in CR alone (classic Mac OS)"),
])
def test_a_program_the_controls_refuse_is_refused_with_its_line(tmp_path: Path, name: str, text: bytes, says: str) -> None:
    p = tmp_path / name
    p.write_bytes(text)
    line = _one_error(runner.invoke(app, ["inspect", str(p)]), 1)
    assert line.startswith(f"error: {p.parent}/{says}") or line.startswith(f"error: {tmp_path / says}"), line


def test_q_is_read_where_a_code_uses_it(tmp_path: Path) -> None:
    p = tmp_path / "q2.ngc"  # a G83 hole, the next hole of the modal cycle, G64 P Q: all rs274 accepts
    p.write_bytes(b"G21 G90\nG0 X0 Y0 Z5\nG83 X1 Y1 Z-5 R1 Q1 F100\nX2 Y2 Q0.5\nG80\nG64 P0.01 Q0.01\nM2\n")
    assert runner.invoke(app, ["inspect", str(p)]).exit_code == 0


@pytest.mark.parametrize(("head", "says"), [
    ("profiles: 5", "profiles: must be a profile file name or a list of them, got 5"),
    ("profiles: [{a: 1}]", "profiles: must be a profile file name or a list of them, got [{'a': 1}]"),
    ("iterations: abc", "iterations: must be a whole number from 1 to 1000, got 'abc'"),
    ("iterations: 1000000", "iterations: must be a whole number from 1 to 1000, got 1000000"),
    ("iterations: -3", "iterations: must be a whole number from 1 to 1000, got -3"),
    (f"profiles: ['{'x' * 300}']\nparts:\n  - program: star.ngc\n    profiles: {{p: 1}}",
     "part 1: profiles: must be a profile file name or a list of them, got {'p': 1}"),
])
def test_a_bad_manifest_is_one_line_not_a_type_error(tmp_path: Path, head: str, says: str) -> None:
    shutil.copy(STAR, tmp_path / "star.ngc")
    body = head if "parts:" in head else head + "\nparts:\n  - program: star.ngc\n"
    (tmp_path / "m.yaml").write_text(body)
    line = _one_error(runner.invoke(app, ["batch", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "out"),
                                          "--profile", str(MILL)]), 1)
    assert line == f"error: {tmp_path / 'm.yaml'}: {says}"
    assert len(line) < 200  # a message names a value, it does not print it whole


def test_a_blank_line_after_the_last_sample_of_a_log_is_no_error(tmp_path: Path) -> None:
    log = tmp_path / "run0.csv"
    assert runner.invoke(app, ["simulate", str(STAR), "--profile", str(MILL), "--log-out", str(log)]).exit_code == 0
    blank = tmp_path / "run0-blank.csv"
    blank.write_bytes(log.read_bytes() + b"\n\n")
    outs = []
    for i, lg in enumerate((log, blank)):
        res = runner.invoke(app, ["learn", str(STAR), "--profile", str(MILL), "--log", str(lg), "--state",
                                  str(tmp_path / f"st{i}"), "--out", str(tmp_path / f"star.{i}.ngc")])
        assert res.exit_code == 0, res.output
        outs.append((tmp_path / f"star.{i}.ngc").read_bytes())
    assert outs[0] == outs[1]


@pytest.mark.parametrize(("args", "says"), [
    (["learn", STAR, "--profile", MILL, "--out", "o.ngc", "--log", "run0.csv", "--points", "run0.csv", "--state", "s"],
     "error: --log and --points do not go together"),
    (["learn", STAR, "--profile", MILL, "--out", "o.ngc", "--log", "run0.csv"], "error: --log/--points make one"),
    (["simulate", STAR, "--profile", MILL, "--compare", "run0.csv", "--log-out", "x.csv"], "error: --compare judges"),
    (["learn", STAR, "--profile", MILL, "--out", "o.ngc", "--log", "run0.csv", "--state", "s", "--log-columns",
      "n line foo"], "error: --log-columns names the columns of a halsampler log: unknown halsampler column name(s) foo"),
    (["learn", STAR, "--profile", MILL, "--out", "o.ngc", "--log", "run0.csv", "--state", "s", "--log-period", "inf"],
     "error: --log-period must be a finite number > 0 and <= 1 s, got inf"),
])
def test_usage_errors_exit_2_naming_the_option(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: list, says: str) -> None:
    monkeypatch.chdir(tmp_path)
    assert runner.invoke(app, ["simulate", str(STAR), "--profile", str(MILL), "--log-out", "run0.csv"]).exit_code == 0
    line = _one_error(runner.invoke(app, [str(a) for a in args]), 2)
    assert line.startswith(says), line
    assert not (tmp_path / "o.ngc").exists() and not (tmp_path / "s").exists() and not (tmp_path / "x.csv").exists()


def test_outputs_are_checked_against_the_inputs_before_any_work(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 25 items 6 and 7: --report over the log (named summary.csv), --out over the program (the whole loop
    ran and wrote P.state/ before refusing), --out inside the state (damaged it for good)."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(STAR, "star.ngc")
    assert runner.invoke(app, ["simulate", "star.ngc", "--profile", str(MILL), "--log-out", "summary.csv"]).exit_code == 0
    log = (tmp_path / "summary.csv").read_bytes()
    line = _one_error(runner.invoke(app, ["learn", "star.ngc", "--profile", str(MILL), "--out", "o.ngc", "--log",
                                          "summary.csv", "--state", "S1", "--report", "."]), 1)
    assert line == "error: .: holds the log as summary.csv, a file the report writes: choose another folder for --report"
    assert (tmp_path / "summary.csv").read_bytes() == log and not (tmp_path / "S1").exists()
    line = _one_error(runner.invoke(app, ["learn", "star.ngc", "--profile", str(MILL), "--out", "star.ngc"]), 1)
    assert line == "error: star.ngc: is the program of this run: choose another output path (--out)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["star.ngc", "summary.csv"]  # no state, nothing else
    first = runner.invoke(app, ["learn", "star.ngc", "--profile", str(MILL), "--out", "o1.ngc", "--log", "summary.csv",
                                "--state", "S1"])
    assert first.exit_code == 0, first.output
    state = {p: p.read_bytes() for p in (tmp_path / "S1").rglob("*") if p.is_file()}
    line = _one_error(runner.invoke(app, ["learn", "o1.ngc", "--profile", str(MILL), "--out", "S1/iter-002.ngc",
                                          "--log", "summary.csv", "--state", "S1"]), 1)
    assert line.startswith("error: S1/iter-002.ngc: is inside the learning state S1")
    assert {p: p.read_bytes() for p in (tmp_path / "S1").rglob("*") if p.is_file()} == state


def _no_hang(args: list[str], seconds: int = 60) -> object:
    import signal

    def _alarm(_signum: int, _frame: object) -> None:
        raise TimeoutError

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(seconds)
    try:
        return runner.invoke(app, args)
    except TimeoutError:
        pytest.fail(f"ilcnc {' '.join(args)} still runs after {seconds} s")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize(("name", "text", "command", "says"), [
    ("holes.ngc", b"G21 G90\nG0 X0 Y0 Z5\nG81 X1 Y1 Z-1 R1 L100000000 F100\nM2\n", "inspect",
     "holes.ngc:3: L1e+08: at most 10,000 repeats of a canned cycle in one block"),
    ("far.ngc", b"G21 G90\nG0 X0 Y0 Z5\nG1 Z-1 F100\nG1 X999999999 F100\nM2\n", "simulate",
     "far.ngc:4: the program's motion takes at least 166,667 h at the profile's feeds"),
    ("far.h", b"0 BEGIN PGM T MM\n1 TOOL CALL 1 Z S1000\n2 CYCL DEF 7.0 DATUM SHIFT\n3 CYCL DEF 7.1 X+999999999\n"
              b"4 L X+0 Y+0 Z+5 R0 FMAX\n5 L Z-1 F100\n6 L X+10 F100\n7 END PGM T MM\n", "simulate",
     "far.h:5: the program's motion takes at least"),  # the rapid to the shifted datum
])
def test_a_program_beyond_any_machine_is_refused_not_run_for_ever(tmp_path: Path, name: str, text: bytes, command: str,
                                                                  says: str) -> None:
    """Issue 25 item 14: these hung inspect or simulate."""
    p = tmp_path / name
    p.write_bytes(text)
    args = ["inspect", str(p)] if command == "inspect" else ["simulate", str(p), "--profile", str(MILL)]
    line = _one_error(_no_hang(args), 1)
    assert line.startswith(f"error: {tmp_path / says}"), line


def test_a_pipe_or_a_device_is_refused_not_read_for_ever(tmp_path: Path) -> None:
    import os

    fifo = tmp_path / "prog.ngc"
    os.mkfifo(fifo)
    for p in (fifo, Path("/dev/zero")):
        line = _one_error(_no_hang(["inspect", str(p)]), 1)
        assert line == f"error: {p}: is not a regular file (a pipe or a device): give a file"


def test_a_feed_limit_no_machine_has_is_refused_when_the_profile_loads(tmp_path: Path) -> None:
    text = MILL.read_text().replace("max_velocity_mm_min: 30000", "max_velocity_mm_min: 1e-300", 1)
    assert "1e-300" in text
    (tmp_path / "slow.yaml").write_text(text)
    line = _one_error(_no_hang(["simulate", str(STAR), "--profile", str(tmp_path / "slow.yaml")]), 1)
    assert line.endswith("max_velocity_mm_min: must be >= 1 and <= 1000000, got 1e-300"), line


def test_parts_of_one_name_in_two_dialects_learn_side_by_side(tmp_path: Path) -> None:
    """Issue 25 item 16: star.h and star.ngc in one folder shared OUT/star.state (one of them failed)."""
    parts = tmp_path / "parts"
    parts.mkdir()
    for name in ("star.h", "star.ngc"):
        shutil.copy(REPO / "samples" / "own" / name, parts / name)
    res = runner.invoke(app, ["batch", str(parts), "--out", str(tmp_path / "out"), "--profile", str(MILL),
                              "--iterations", "1", "--json"])
    assert res.exit_code == 0, res.output
    import json

    statuses = [r["status"] for r in json.loads(res.stdout)["parts"]]
    assert len(statuses) == 2 and "error" not in statuses, statuses
    assert sorted(p.name for p in (tmp_path / "out").iterdir() if p.name.endswith(".state")) == [
        "star.ilc.h.state", "star.ilc.ngc.state"]


def test_a_yaml_alias_bomb_in_a_manifest_is_one_line_in_bounded_memory(tmp_path: Path) -> None:
    """Issue 25 item 15: nine anchors nesting nine lists each (387 M elements) reached 4.6 GB after 120 s: the
    message printed the whole value. The run gets 1 GB of address space here (the unbounded message needed 2 GB
    and 54 s); the refusal needs a few MB."""
    import resource
    import subprocess
    import sys

    rows = ['a: &a ["x","x","x","x","x","x","x","x","x"]']
    for prev, name in zip("abcdefgh", "bcdefghi", strict=True):
        rows.append(f"{name}: &{name} [{','.join([f'*{prev}'] * 9)}]")
    rows += ["profiles: *i", "parts:", "  - program: star.ngc"]
    shutil.copy(STAR, tmp_path / "star.ngc")
    (tmp_path / "m.yaml").write_text("\n".join(rows) + "\n")

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))

    import os

    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # no per-core buffers
    cp = subprocess.run([sys.executable, "-m", "ilcnc", "batch", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "o")],
                        capture_output=True, text=True, timeout=300, preexec_fn=limit, env=env)
    assert cp.returncode == 1, cp.stderr[-500:]
    lines = cp.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {tmp_path / 'm.yaml'}: profiles: must be a profile file"), lines
    assert len(lines[0]) < 250


@pytest.mark.parametrize("program", ["../star.ngc", "/etc/passwd", "sub/../../star.ngc"])
def test_a_manifest_program_outside_its_folder_is_refused_unless_allowed(tmp_path: Path, program: str) -> None:
    # item 15: a manifest mailed in names files of this machine (/etc/passwd went into the error message)
    shutil.copy(STAR, tmp_path / "star.ngc")
    m = tmp_path / "m"
    m.mkdir()
    (m / "sub").mkdir()
    man = m / "parts.yaml"
    man.write_text(f"profiles: [{MILL}]\nparts:\n  - program: {program}\n")
    line = _one_error(runner.invoke(app, ["batch", str(man), "--out", str(tmp_path / "out")]), 1)
    assert line.startswith(f"error: {man}: part 1: program '{program}' is outside the manifest's folder"), line
    assert line.endswith(": move it there, or give --allow-outside"), line
    assert not (tmp_path / "out").exists()
    if program != "/etc/passwd":
        res = runner.invoke(app, ["batch", str(man), "--out", str(tmp_path / "out"), "--allow-outside", "--iterations",
                                  "1", "--json"])
        assert res.exit_code == 0, res.output
