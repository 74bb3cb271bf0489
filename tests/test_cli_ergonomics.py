"""The command line in the shell and the terminal (issue 23 item 8).

``-h`` on every command; no ``<bool>`` after a flag in any help; shell completion offered and answering;
``--debug`` after the subcommand as before it; renamed options (``simulate --out`` is ``--log-out`` ...) still
working under their old names with one warning line; counts worded right ("ran 1 iteration") and no status
said twice ("stopped: ...: stopped").
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.cli_options import RENAMED_OPTIONS, renamed_args
from ilcnc.errors import InputError
from ilcnc.wording import plural

from .conftest import REPO, cli_output

OWN = REPO / "samples" / "own"
MILL = REPO / "configs" / "example-mill.yaml"
STAR = OWN / "star.ngc"
TNC_STEP = REPO / "tests" / "data" / "identify" / "tncscope_x_sopdt.csv"
HAL_STEP = REPO / "tests" / "data" / "identify" / "linuxcnc_x_step.hal.log"
WIDE = {"COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"}  # one option per help row: no word folded away

runner = CliRunner()


def _commands() -> Iterator[tuple[list[str], object]]:
    """(path, click command) of the app, every group and every command, read from the app itself."""
    def walk(cmd: object, path: list[str]) -> Iterator[tuple[list[str], object]]:
        yield path, cmd
        for name, sub in (getattr(cmd, "commands", None) or {}).items():
            yield from walk(sub, [*path, name])

    yield from walk(typer.main.get_command(app), [])


COMMANDS = list(_commands())
IDS = [" ".join(p) or "ilcnc" for p, _c in COMMANDS]
LEAVES = [(p, c) for p, c in COMMANDS if not getattr(c, "commands", None)]
COMMANDS_BY_NAME = [(" ".join(p), c) for p, c in COMMANDS]


def test_the_walk_finds_every_command_and_group() -> None:
    names = {" ".join(p) for p, _c in COMMANDS}
    assert {"", "learn", "simulate", "identify", "check", "batch", "report", "linuxcnc", "linuxcnc run",
            "linuxcnc profile", "linuxcnc prepare"} <= names
    assert len(LEAVES) == 14


@pytest.mark.parametrize("path", [p for p, _c in COMMANDS], ids=IDS)
def test_h_is_help_everywhere(path: list[str]) -> None:
    long = runner.invoke(app, [*path, "--help"], env=WIDE)
    short = runner.invoke(app, [*path, "-h"], env=WIDE)
    assert long.exit_code == 0 and short.exit_code == 0, short.output
    assert "Usage:" in short.output
    assert short.output == long.output


@pytest.mark.parametrize("path", [p for p, _c in COMMANDS], ids=IDS)
def test_no_bool_metavar_in_any_help(path: list[str]) -> None:
    out = runner.invoke(app, [*path, "--help"], env=WIDE).output
    assert "<bool>" not in out
    assert re.search(r"--help\s+-h\s+Show this message", out), out  # the flag row itself is there, without a type


def test_options_that_take_a_value_still_show_their_type() -> None:
    out = runner.invoke(app, ["learn", "--help"], env=WIDE).output
    assert re.search(r"--profile\s+<path>", out) and re.search(r"--iterations\s+<int range>", out), out
    assert re.search(r"--stamp\s+Add a provenance comment", out), out


def test_completion_options_are_offered() -> None:
    out = runner.invoke(app, ["--help"], env=WIDE).output
    assert "--install-completion" in out and "--show-completion" in out


@pytest.mark.parametrize(("shell", "env"), [
    ("bash", {"COMP_WORDS": "ilcnc simulate --lo", "COMP_CWORD": "2"}),
    ("zsh", {"_TYPER_COMPLETE_ARGS": "ilcnc simulate --lo"}),
    ("fish", {"_TYPER_COMPLETE_ARGS": "ilcnc simulate --lo", "_TYPER_COMPLETE_FISH_ACTION": "get-args"}),
])
def test_completion_answers_with_the_commands_options(shell: str, env: dict[str, str]) -> None:
    """What an installed completion script asks ilcnc (the variables typer's scripts set) and what it answers."""
    res = runner.invoke(app, [], env={"_ILCNC_COMPLETE": f"complete_{shell}", **env}, prog_name="ilcnc")
    assert res.exit_code == 0, res.output
    for opt in ("--log-out", "--log-format", "--log-units", "--log-columns", "--log-offset"):
        assert opt in res.output
    assert "--profile" not in res.output  # only what starts with --lo


def test_completion_after_an_old_option_name_prints_no_warning() -> None:
    env = {"_ILCNC_COMPLETE": "complete_bash", "COMP_WORDS": "ilcnc simulate x.ngc --out log.csv --pro",
           "COMP_CWORD": "5"}
    res = runner.invoke(app, [], env=env, prog_name="ilcnc")
    assert res.exit_code == 0 and res.output.split() == ["--profile"], res.output


def test_show_completion_prints_the_script_of_the_calling_shell() -> None:
    """Run from bash (``; true`` keeps bash as the parent instead of exec'ing ilcnc): typer finds the shell."""
    if subprocess.run(["bash", "-c", "true"], capture_output=True).returncode != 0:
        pytest.skip("no bash on this machine")
    cmd = f"'{sys.executable}' -m ilcnc --show-completion; true"
    cp = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert cp.returncode == 0, cp.stderr
    assert "_ilcnc_completion()" in cp.stdout and "complete_bash" in cp.stdout, cp.stdout + cp.stderr


@pytest.mark.parametrize("path", [p for p, _c in LEAVES], ids=[" ".join(p) for p, _c in LEAVES])
def test_every_command_takes_debug(path: list[str]) -> None:
    cmd = dict(COMMANDS_BY_NAME)[" ".join(path)]
    assert any("--debug" in p.opts for p in cmd.params)  # type: ignore[attr-defined]


def test_debug_after_the_command_raises_the_error_as_before_it(tmp_path: Path) -> None:
    missing = str(tmp_path / "missing.ngc")
    after = runner.invoke(app, ["learn", missing, "--profile", str(MILL), "--out", str(tmp_path / "o.ngc"), "--debug"])
    before = runner.invoke(app, ["--debug", "learn", missing, "--profile", str(MILL), "--out", str(tmp_path / "o.ngc")])
    for res in (after, before):
        assert isinstance(res.exception, InputError), res.output
        assert str(res.exception.format()) == f"{missing}: file not found"
    plain = runner.invoke(app, ["learn", missing, "--profile", str(MILL), "--out", str(tmp_path / "o.ngc")])
    assert plain.exit_code == 1 and isinstance(plain.exception, SystemExit)  # --debug does not stick to the process
    assert cli_output(plain).strip() == f"error: {missing}: file not found"


def test_debug_after_the_command_prints_the_traceback(tmp_path: Path) -> None:
    missing = str(tmp_path / "missing.ngc")
    cp = subprocess.run([sys.executable, "-m", "ilcnc", "inspect", missing, "--debug"], capture_output=True, text=True,
                        timeout=120)
    assert cp.returncode != 0
    assert "Traceback" in cp.stderr and f"InputError: {missing}: file not found" in cp.stderr


# --------------------------------------------------------------------------- renamed options


def test_renamed_args_rewrites_only_option_words() -> None:
    vals = {"--profile", "--log-out"}
    assert renamed_args("simulate", ["p.ngc", "--out", "x.csv"], vals) == (
        ["p.ngc", "--log-out", "x.csv"], ["warning: --out of simulate is deprecated, use --log-out"])
    assert renamed_args("simulate", ["p.ngc", "--out=x.csv"], vals)[0] == ["p.ngc", "--log-out=x.csv"]
    assert renamed_args("simulate", ["p.ngc", "--profile", "--out"], vals) == (["p.ngc", "--profile", "--out"], [])
    assert renamed_args("simulate", ["--", "--out"], vals) == (["--", "--out"], [])
    assert renamed_args("learn", ["p.ngc", "--out", "o.ngc"], vals) == (["p.ngc", "--out", "o.ngc"], [])


def test_every_renamed_option_has_its_new_name_on_its_command() -> None:
    by_name = dict(COMMANDS_BY_NAME)
    for (command, old), new in RENAMED_OPTIONS.items():
        opts = {o for p in by_name[command].params for o in p.opts}  # type: ignore[attr-defined]
        assert new in opts and old not in opts, (command, old, new)


def _warned(res: object, old: str, command: str, new: str) -> None:
    lines = [ln for ln in cli_output(res).splitlines() if ln.startswith("warning: ") and "deprecated" in ln]
    assert lines == [f"warning: {old} of {command} is deprecated, use {new}"]


def test_simulate_out_still_writes_the_log_and_warns(tmp_path: Path) -> None:
    old = runner.invoke(app, ["simulate", str(STAR), "--profile", str(MILL), "--out", str(tmp_path / "a.csv"), "--json"])
    new = runner.invoke(app, ["simulate", str(STAR), "--profile", str(MILL), "--log-out", str(tmp_path / "b.csv"),
                              "--json"])
    assert old.exit_code == 0 and new.exit_code == 0, old.output
    _warned(old, "--out", "simulate", "--log-out")
    assert "deprecated" not in new.output
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    assert json.loads(old.stdout) == json.loads(new.stdout)


def test_linuxcnc_run_log_still_names_the_log_to_write_and_warns(tmp_path: Path) -> None:
    """A missing program fails before LinuxCNC starts: exit 1 (the file named), not 2 (a missing --log-out)."""
    missing = tmp_path / "missing.ngc"
    res = runner.invoke(app, ["linuxcnc", "run", str(missing), "--log", str(tmp_path / "run.csv")])
    assert res.exit_code == 1, res.output
    _warned(res, "--log", "linuxcnc run", "--log-out")
    assert cli_output(res).splitlines()[-1] == f"error: {missing}: file not found"
    assert not (tmp_path / "run.csv").exists()


@pytest.mark.parametrize(("old", "new", "value", "step"), [
    ("--format", "--log-format", "tncscope", TNC_STEP),
    ("--units", "--log-units", "mm", TNC_STEP),
    ("--period-s", "--log-period", "0.001", HAL_STEP),
])
def test_identify_old_log_option_names_still_work_and_warn(old: str, new: str, value: str, step: Path) -> None:
    base = ["identify", str(step), "--axis", "x", "--json"]
    res_old = runner.invoke(app, [*base, old, value])
    res_new = runner.invoke(app, [*base, new, value])
    assert res_old.exit_code == 0 and res_new.exit_code == 0, res_old.output
    _warned(res_old, old, "identify", new)
    assert json.loads(res_old.stdout) == json.loads(res_new.stdout)


def test_an_old_name_and_its_value_in_one_word_work(tmp_path: Path) -> None:
    res = runner.invoke(app, ["identify", str(HAL_STEP), "--axis", "x", "--period-s=-1"])
    assert res.exit_code == 2
    assert cli_output(res).splitlines() == ["warning: --period-s of identify is deprecated, use --log-period",
                                            "error: --log-period must be a finite number > 0 and <= 1 s, got -1"]


# --------------------------------------------------------------------------- wording


def test_plural() -> None:
    assert plural(1, "iteration") == "1 iteration"
    assert [plural(n, "iteration") for n in (0, 2)] == ["0 iterations", "2 iterations"]
    assert plural(3, "G01 command") == "3 G01 commands" and plural(2, "axis") == "2 axes"
    assert plural(2, "child", "children") == "2 children"


_ONE_PLURAL = re.compile(r"(?<![\d.,])1 (iterations|commands|lines|files|parts|programs|samples|moves|kernels|numbers"
                         r"|G01 commands)\b")


def test_one_iteration_on_square_says_what_happened_once(tmp_path: Path) -> None:
    """square.ngc on the example mill: iteration 1 improves the RMS error by less than 1 % (its error is the
    planner's rounding of the G64 P0.05 corners, which no end point of the unrefined square shapes), so the run
    stops. The status line says "stopped" once (it said "status: stopped: iteration 1 did not improve ...:
    stopped")."""
    res = runner.invoke(app, ["learn", str(OWN / "square.ngc"), "--profile", str(MILL), "--iterations", "1", "--out",
                              str(tmp_path / "sq.ngc")], env=WIDE)
    assert res.exit_code == 0, res.output
    out = cli_output(res)
    status = [ln for ln in out.splitlines() if ln.startswith("status: ")]
    assert status == ["status: stopped: iteration 1 improved the RMS contour error by less than 1% (4.849 → 4.830 µm)"]
    assert not _ONE_PLURAL.search(out), out


def test_one_iteration_that_runs_out_says_iteration(tmp_path: Path) -> None:
    res = runner.invoke(app, ["learn", str(OWN / "circle.ngc"), "--profile", str(MILL), "--iterations", "1", "--out",
                              str(tmp_path / "c.ngc"), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert (data["status"], data["message"]) == ("max_iterations", "ran 1 iteration; the output is iteration 1")
