"""What continuing a learning run means (issue 25 item 8).

Before: a second ``learn --state S`` with another profile kept the old iterations' files but wrote
its new statistics and ``kept: true`` over the record of the iteration it started from; the
profile's hash was recorded and never checked; a continuation started from the last kept
iteration, not the best. Now: a run goes on with the profile it was made with, or, with
``--new-profile``, a new branch starts from its best iteration (its records carry the new
profile's hash, the guard compares one profile's iterations); every continuation appends, and
no iteration's record is ever written again.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.shop.state import IterationEntry, LearnState, sha256_bytes

from .conftest import cli_output

REPO = Path(__file__).resolve().parents[1]
MILL = REPO / "configs" / "example-mill.yaml"
COMPASS = REPO / "samples" / "compass.ngc"
runner = CliRunner()


@pytest.fixture
def part(tmp_path: Path) -> Path:
    p = tmp_path / "compass-head.ngc"  # compass's first 60 lines: its iterations move 49 commands
    p.write_text("\n".join(COMPASS.read_text().splitlines()[:60]) + "\nG0 Z5\nM2\n")
    return p


def _learn(part: Path, profile: Path, state: Path, out: Path, *extra: str) -> dict:
    res = runner.invoke(app, ["learn", str(part), "--profile", str(profile), "--state", str(state), "--out", str(out),
                              "--iterations", "2", "--json", *extra])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


def _records(state: Path) -> list[dict]:
    return json.loads((state / "state.json").read_text())["iterations"]


def test_a_run_goes_on_with_its_profile_or_branches_with_new_profile(part: Path, tmp_path: Path) -> None:
    state = tmp_path / "st"
    _learn(part, MILL, state, tmp_path / "o1.ngc")
    before = (state / "state.json").read_bytes()
    first = _records(state)
    other = tmp_path / "other.yaml"
    other.write_bytes(MILL.read_bytes() + b"# edited: another profile\n")
    res = runner.invoke(app, ["learn", str(part), "--profile", str(other), "--state", str(state), "--out",
                              str(tmp_path / "o2.ngc")])
    assert res.exit_code == 1
    assert cli_output(res).startswith(f"error: {other}: is not the profile this learning run goes on with (sha256 "), \
        res.output
    assert "--new-profile" in cli_output(res) and len(cli_output(res).strip().splitlines()) == 1
    assert (state / "state.json").read_bytes() == before and not (tmp_path / "o2.ngc").exists()
    # a new branch: the old records stay as they were, the new ones name the new profile
    _learn(part, other, state, tmp_path / "o2.ngc", "--new-profile")
    now = _records(state)
    assert now[: len(first)] == first
    st = LearnState.load(state)
    new = now[len(first):]
    assert new and all(r["profile_sha256"] == sha256_bytes(other.read_bytes()) for r in new)
    assert [r["iteration"] for r in now] == list(range(len(now)))
    # the branch starts by measuring the run's best program again
    best_before = min((r for r in reversed(first) if r["kept"]), key=lambda r: r["stats"]["rms"])
    assert new[0]["measured_from"]["rerun_of"] == best_before["iteration"]
    assert (state / new[0]["program"]).read_bytes() == (state / best_before["program"]).read_bytes()
    assert st.current_profile_sha256 == sha256_bytes(other.read_bytes())
    # and the new profile is the one the run now goes on with: the first is refused
    res = runner.invoke(app, ["learn", str(part), "--profile", str(MILL), "--state", str(state), "--out",
                              str(tmp_path / "o3.ngc")])
    assert res.exit_code == 1 and "is not the profile this learning run goes on with" in res.output


def test_a_continuation_appends_and_never_writes_a_record_again(part: Path, tmp_path: Path) -> None:
    state = tmp_path / "st"
    _learn(part, MILL, state, tmp_path / "o1.ngc")
    first = _records(state)
    files = {p.name: p.read_bytes() for p in state.iterdir() if p.name != "state.json"}
    _learn(part, MILL, state, tmp_path / "o2.ngc")
    now = _records(state)
    assert now[: len(first)] == first
    assert len(now) > len(first)
    assert all(r.get("profile_sha256") is None for r in now)  # the run's own profile throughout
    for name, data in files.items():
        assert (state / name).read_bytes() == data, name


def test_the_best_iteration_is_the_lowest_rms_kept(tmp_path: Path) -> None:
    st = LearnState(tmp_path, {}, "p", "path", "0" * 64)

    def entry(i: int, rms: float, kept: bool) -> IterationEntry:
        return IterationEntry(i, f"iter-{i:03d}.ngc", "", "", stats={"max": 1.0, "mean": 0.0, "rms": rms}, kept=kept)

    # iteration 2 was kept within the guard's allowance, a hair worse than iteration 1
    st.iterations = [entry(0, 3.0, True), entry(1, 1.0, True), entry(2, 1.02, True), entry(3, 0.5, False)]
    best = st.best()
    assert best is not None and best.iteration == 1
    st.iterations.append(entry(4, 1.0, True))  # equal: the later one
    best = st.best()
    assert best is not None and best.iteration == 4
