"""Every option of every command, given a value out of its range: a clear refusal, never a traceback.

The options are read from the command line definition itself (a new option is covered without editing this
file). Each numeric option gets ``-1``, ``0``, ``nan``, ``inf``, ``-inf``, ``1e300`` and ``abc``; each
text option a word no command knows; each file option a path that does not exist. A command may accept a
value (exit 0; never NaN) or refuse it: exit 2 for a usage error (the option named), 1 for bad input, with one
``error:`` line. What it may never do is end in an exception that is not ilcnc's own (an "internal error":
a traceback under ``--debug``), let the value reach arithmetic that overflows (a RuntimeWarning), or hang (each
case has a 120 s alarm).
"""

from __future__ import annotations

import shutil
import signal
import types
import typing
import warnings
from collections.abc import Iterator
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from ilcnc.cli import app

from .conftest import REPO

OWN = REPO / "samples" / "own"
MILL = REPO / "configs" / "example-mill.yaml"
STEP = REPO / "tests" / "data" / "identify" / "tncscope_x_sopdt.csv"

NUMBERS = ("-1", "0", "nan", "inf", "-inf", "1e300", "abc")
#: Options whose accepted extremes would start real work far beyond a unit test (a LinuxCNC run): only the
#: values that must be refused are given.
REFUSED_ONLY = {("linuxcnc run", "--time-scale"), ("linuxcnc run", "--settle"), ("linuxcnc run", "--timeout"),
                ("linuxcnc run", "--lock-timeout")}


def _base(command: str, tmp: Path) -> list[str]:
    """A valid call of ``command`` on a small shipped program; the option under test is appended."""
    star = str(OWN / "star.ngc")
    return {
        "inspect": ["inspect", star],
        "diff": ["diff", star, star],
        "export": ["export", star, "--out", str(tmp / "x.ngc")],
        "simulate": ["simulate", star, "--profile", str(MILL)],
        "learn": ["learn", star, "--profile", str(MILL), "--out", str(tmp / "o.ngc"), "--iterations", "1"],
        "identify": ["identify", str(STEP), "--axis", "x"],
        "tune": ["tune", str(OWN / "square.ngc"), "--profile", str(MILL)],
        "check": ["check", star, "--profile", str(MILL), "--max-error", "1"],  # passes: the option under test decides
        "batch": ["batch", str(tmp / "parts"), "--out", str(tmp / "b"), "--profile", str(MILL), "--workers", "1",
                  "--iterations", "1"],
        "linuxcnc run": ["linuxcnc", "run", star, "--log-out", str(tmp / "run.csv")],
        "linuxcnc profile": ["linuxcnc", "profile", str(REPO / "configs" / "linuxcnc-sim" / "sim.ini")],
        "linuxcnc prepare": ["linuxcnc", "prepare", star, "--profile", str(REPO / "configs" / "linuxcnc-sim.yaml")],
        "report": ["report", str(tmp / "none.state"), "--out", str(tmp / "rep")],  # numbers are checked first
    }[command]


def _kind(annotation: object) -> str:
    """``number``, ``text``, ``path``, ``flag`` or ``other`` for a parameter's annotation."""
    args = typing.get_args(annotation) if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) \
        else (annotation,)
    args = tuple(a for a in args if a is not type(None))
    if args and all(a in (int, float) for a in args):
        return "number"
    if args and args[0] is bool:
        return "flag"
    if args and args[0] is str:
        return "text"
    if args and isinstance(args[0], type) and issubclass(args[0], Path):
        return "path"
    return "other"


def _cases() -> Iterator[tuple[str, str, str]]:
    root = typer.main.get_command(app)

    def walk(cmd: object, name: str) -> Iterator[tuple[str, object]]:
        subs = getattr(cmd, "commands", None)
        if subs:
            for n, sub in subs.items():
                yield from walk(sub, f"{name} {n}".strip())
        else:
            yield name, cmd

    for name, cmd in walk(root, ""):
        for p in cmd.params:  # type: ignore[attr-defined]
            opt = (p.opts or [p.name])[0]
            if not opt.startswith("--"):
                continue
            kind = _kind(p.type_descriptor.annotation)
            values: tuple[str, ...] = ()
            if kind == "number":
                values = NUMBERS
                if (name, opt) in REFUSED_ONLY:
                    values = ("-1", "nan", "-inf", "abc")
            elif kind == "text":
                values = ("no-such-choice",)
            elif kind == "path" and opt not in ("--out", "--log", "--log-out", "--report", "--moves", "--plot", "--raw"):
                values = ("/nonexistent/ilcnc-test-input",)
            for v in values:
                yield name, opt, v


CASES = list(_cases())


def test_the_cases_cover_every_numeric_option_of_every_command() -> None:
    names = {(c, o) for c, o, _v in CASES}
    for needed in [("learn", "--iterations"), ("identify", "--log-period"), ("tune", "--f-max"), ("check", "--max-error"),
                   ("simulate", "--cutting-below-z"), ("export", "--decimals"), ("batch", "--workers")]:
        assert needed in names
    assert len(CASES) > 150


class _Hang(Exception):
    pass


def _alarm(_signum: int, _frame: object) -> None:
    raise _Hang


@pytest.mark.slow
@pytest.mark.parametrize(("command", "option", "value"), CASES, ids=[f"{c}{o}={v}" for c, o, v in CASES])
def test_an_out_of_range_option_is_refused_cleanly(command: str, option: str, value: str, tmp_path: Path) -> None:
    (tmp_path / "parts").mkdir()
    shutil.copy(OWN / "star.ngc", tmp_path / "parts" / "star.ngc")
    args = _base(command, tmp_path)
    if option in args:  # the base already sets it: replace its value
        i = args.index(option)
        args = args[:i] + args[i + 2:]
    args += [option, value]
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(120)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = CliRunner().invoke(app, args)
    except _Hang:
        pytest.fail(f"ilcnc {' '.join(args)} still runs after 120 s")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    exc = res.exception
    assert exc is None or isinstance(exc, SystemExit), f"ilcnc {' '.join(args)} raised {exc!r}"
    # ilcnc check's own code for an input it cannot read (a --baseline that is not there): 3
    assert res.exit_code in (0, 1, 2) or (command == "check" and res.exit_code == 3), res.output
    out = res.output
    assert "Traceback" not in out
    # a numpy or scipy RuntimeWarning (overflow, invalid value) means the value reached arithmetic it is no input of
    runtime = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert not runtime, f"ilcnc {' '.join(args)}: {runtime[:3]}"
    if res.exit_code == 2 and value in ("-1", "nan", "-inf", "abc"):
        # typer's own refusal names the option in its box; ilcnc's names it in its one line
        assert option in out or option.lstrip("-") in out or "Invalid value" in out, out
    if res.exit_code in (1, 3):
        lines = [ln for ln in out.splitlines() if ln.startswith("error:")]
        assert len(lines) == 1, out
    if value == "nan":  # NaN is no setting of anything: refused, whatever the option
        assert res.exit_code != 0, f"ilcnc {' '.join(args)} accepted NaN"
