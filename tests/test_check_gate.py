"""ilcnc check over many programs: a baseline, its tolerance, JUnit XML and the exit codes, end to end."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from ilcnc.profile.load import load_profile

from .conftest import OWN, REPO

MILL = REPO / "configs" / "example-mill.yaml"
PROGRAMS = ("square.h", "square.ngc", "star.ngc")


def _cli(cwd: Path, *args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ilcnc", *map(str, args)], capture_output=True, text=True,
                          timeout=600, cwd=cwd)


@pytest.fixture()
def repo(tmp_path: Path) -> Path:
    """A repository as a post-processor change leaves it: posts/out/ with its programs, the machine's profile,
    a copy of it whose X/Y/Z drives are slower (omega0 95.6 -> 60 rad/s: larger errors), and one whose X/Y
    jerk is a tenth (50 -> 5 m/s³: longer cycles)."""
    out = tmp_path / "posts" / "out"
    out.mkdir(parents=True)
    for name in PROGRAMS:
        shutil.copy(OWN / name, out / name)
    shutil.copy(MILL, tmp_path / "machine.yaml")
    text = MILL.read_text()
    slow = text.replace("omega0_rad_s: 95.6", "omega0_rad_s: 60.0")
    gentle = text.replace("max_jerk_m_s3: 50", "max_jerk_m_s3: 5")
    assert slow != text and gentle.count("max_jerk_m_s3: 5\n") == 2
    (tmp_path / "slow.yaml").write_text(slow)
    (tmp_path / "gentle.yaml").write_text(gentle)
    return tmp_path


def _single(cwd: Path, program: str, profile: str) -> dict:
    """The figures of the single-program gate (``check PROG --json``), which the many-program gate must equal."""
    r = _cli(cwd, "check", program, "--profile", profile, "--max-error", "1", "--json")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def _junit(path: Path) -> dict[str, ET.Element]:
    """Parse a JUnit report and check what GitLab, GitHub (test-reporter actions) and Jenkins read: the
    JUnit XSD's required structure (testsuites > testsuite > testcase; tests/failures/errors counts; testcase
    name, classname and a numeric time; failure/error with a message and a type) and the counts agreeing with
    the test cases. Returns the test cases by name."""
    root = ET.parse(path).getroot()
    assert root.tag == "testsuites"
    suites = root.findall("testsuite")
    assert len(suites) == 1
    suite = suites[0]
    for el in (root, suite):
        for attr in ("name", "tests", "failures", "errors", "time"):
            assert attr in el.attrib, (el.tag, attr)
        assert math.isfinite(float(el.get("time")))
    assert "timestamp" in suite.attrib and "hostname" in suite.attrib
    cases = suite.findall("testcase")
    assert int(suite.get("tests")) == len(cases) == int(root.get("tests"))
    n_fail = sum(c.find("failure") is not None for c in cases)
    n_err = sum(c.find("error") is not None for c in cases)
    assert int(suite.get("failures")) == n_fail == int(root.get("failures"))
    assert int(suite.get("errors")) == n_err == int(root.get("errors"))
    for c in cases:
        assert c.get("name") and c.get("classname") == "ilcnc.check"
        assert float(c.get("time")) >= 0
        assert len([ch for ch in c if ch.tag in ("failure", "error")]) <= 1
        for ch in c:
            assert ch.tag in ("failure", "error", "system-out")
            if ch.tag in ("failure", "error"):
                assert ch.get("message") and ch.get("type")
    return {c.get("name"): c for c in cases}


def test_a_baseline_made_then_kept_then_regressed_by_a_slower_drive(repo: Path) -> None:
    progs = [f"posts/out/{n}" for n in PROGRAMS]
    # 1. make the baseline
    r = _cli(repo, "check", *progs, "--profile", "machine.yaml", "--baseline", "check.json", "--update-baseline")
    assert r.returncode == 0, r.stdout + r.stderr
    base = json.loads((repo / "check.json").read_text())
    assert sorted(base["programs"]) == progs
    for p in progs:  # the very figures the single-program gate prints
        one = _single(repo, p, "machine.yaml")
        assert base["programs"][p] == {"max_mm": one["contour_error_mm"]["max"],
                                       "rms_mm": one["contour_error_mm"]["rms"], "cycle_s": one["cycle_time_s"]}
    assert not list(repo.glob(".check.json.*"))  # written atomically: no temporary left
    # 2. the same programs on the same machine pass (given as a folder: batch's rule finds the same names)
    r = _cli(repo, "check", "posts/out", "--profile", "machine.yaml", "--baseline", "check.json", "--junit",
             "report.xml")
    assert r.returncode == 0, r.stdout + r.stderr
    cases = _junit(repo / "report.xml")
    assert sorted(cases) == progs and all(c.find("failure") is None for c in cases.values())
    assert max(map(len, r.stdout.splitlines())) <= 80
    # 3. a slower drive: every program's error regresses beyond the tolerance (the profile's 1 µm resolution)
    r = _cli(repo, "check", *progs, "--profile", "slow.yaml", "--baseline", "check.json", "--junit", "report.xml")
    assert r.returncode == 1, r.stdout + r.stderr
    cases = _junit(repo / "report.xml")
    tol_um = load_profile(MILL).machine.resolution_mm * 1e3
    for p in progs:
        slow = _single(repo, p, "slow.yaml")
        grew_um = (slow["contour_error_mm"]["max"] - base["programs"][p]["max_mm"]) * 1e3
        assert grew_um > tol_um
        fail = cases[p].find("failure")
        assert fail is not None and fail.get("type") == "regression"
        assert f"max contour error regressed: {slow['contour_error_mm']['max'] * 1e3:.3f} µm > baseline" \
               f" {base['programs'][p]['max_mm'] * 1e3:.3f} µm + tolerance {tol_um:g} µm" in fail.get("message")
        if slow["cycle_time_s"] > base["programs"][p]["cycle_s"] + 0.001:
            assert "cycle time regressed" in fail.get("message")
    # a gentler jerk limit: the cycle times regress by more than one servo period
    r = _cli(repo, "check", *progs, "--profile", "gentle.yaml", "--baseline", "check.json", "--junit", "report.xml")
    assert r.returncode == 1
    cases = _junit(repo / "report.xml")
    n_cycle = 0
    for p in progs:
        cycle = _single(repo, p, "gentle.yaml")["cycle_time_s"]
        if cycle > base["programs"][p]["cycle_s"] + load_profile(MILL).machine.servo_period_s:
            assert f"cycle time regressed: {cycle:.3f} s > baseline {base['programs'][p]['cycle_s']:.3f} s" \
                   in cases[p].find("failure").get("message")
            n_cycle += 1
    assert n_cycle >= 2
    # 4. a tolerance above the largest growth lets the errors pass (the cycle time has its own)
    growth_um = max((_single(repo, p, "slow.yaml")["contour_error_mm"][k] - base["programs"][p][f"{k}_mm"]) * 1e3
                    for p in progs for k in ("max", "rms"))
    r = _cli(repo, "check", *progs, "--profile", "slow.yaml", "--baseline", "check.json", "--tolerance-um",
             f"{growth_um + 0.01:.3f}", "--tolerance-s", "1000", "--json")
    assert r.returncode == 0, r.stdout
    assert json.loads(r.stdout)["passed"] is True
    # 5. the slower machine accepted: --update-baseline rewrites the baseline, then it passes
    r = _cli(repo, "check", *progs, "--profile", "slow.yaml", "--baseline", "check.json", "--update-baseline")
    assert r.returncode == 0 and "(baseline updated)" in r.stdout
    assert _cli(repo, "check", *progs, "--profile", "slow.yaml", "--baseline", "check.json").returncode == 0


def test_an_unreadable_program_has_its_own_exit_code_and_the_others_are_judged(repo: Path) -> None:
    progs = [f"posts/out/{n}" for n in PROGRAMS]
    assert _cli(repo, "check", *progs, "--profile", "machine.yaml", "--baseline", "check.json",
                "--update-baseline").returncode == 0
    # a post-processor that now writes a spline the reader does not model
    (repo / "posts" / "out" / "broken.ngc").write_text("G21 G90\nG1 X10 F1000\nG5 X3 Y4 I1 J1 P1 Q1\nM2\n")
    r = _cli(repo, "check", "posts/out", "--profile", "slow.yaml", "--baseline", "check.json", "--junit",
             "report.xml", "--json")
    assert r.returncode == 3, r.stdout + r.stderr
    out = json.loads(r.stdout)
    assert out["exit_code"] == 3
    status = {p["program"]: p["status"] for p in out["programs"]}
    assert status == {"posts/out/broken.ngc": "unreadable", **dict.fromkeys(progs, "failed")}
    cases = _junit(repo / "report.xml")
    err = cases["posts/out/broken.ngc"].find("error")
    assert err is not None and err.get("type") == "unreadable" and "broken.ngc:3" in err.get("message")
    # --update-baseline keeps no entry for a program it could not read
    r = _cli(repo, "check", "posts/out", "--profile", "machine.yaml", "--baseline", "check.json",
             "--update-baseline")
    assert r.returncode == 3
    assert "posts/out/broken.ngc" not in json.loads((repo / "check.json").read_text())["programs"]
    # a missing program file is unreadable too
    r = _cli(repo, "check", "posts/out/square.ngc", "posts/out/gone.nc", "--profile", "machine.yaml",
             "--max-error", "1")
    assert r.returncode == 3 and "ERROR posts/out/gone.nc: file not found" in r.stdout


def test_thresholds_usage_and_bad_inputs(repo: Path) -> None:
    progs = [f"posts/out/{n}" for n in PROGRAMS]
    # --max-error over many programs: the one above 30 µm fails with the line of its largest error (square 44.0 µm,
    # star 20.7 µm on example-mill)
    r = _cli(repo, "check", *progs, "--profile", "machine.yaml", "--max-error", "0.03", "--junit", "r.xml")
    assert r.returncode == 1
    cases = _junit(repo / "r.xml")
    fail = cases["posts/out/square.ngc"].find("failure")
    assert fail is not None and fail.get("type") == "threshold" and "> --max-error 30 µm" in fail.get("message")
    assert cases["posts/out/star.ngc"].find("failure") is None
    # usage: exit 2
    assert _cli(repo, "check", *progs, "--profile", "machine.yaml").returncode == 2  # neither gate nor baseline
    r = _cli(repo, "check", *progs, "--profile", "machine.yaml", "--max-error", "1", "--update-baseline")
    assert r.returncode == 2 and "--update-baseline needs --baseline" in r.stderr
    assert _cli(repo, "check", *progs, "--profile", "machine.yaml", "--baseline", "b.json", "--tolerance-um",
                "-1").returncode == 2
    # a baseline that is missing or not one: exit 3, one line
    r = _cli(repo, "check", *progs, "--profile", "machine.yaml", "--baseline", "missing.json")
    assert r.returncode == 3 and r.stderr.startswith("error: missing.json: ")
    (repo / "bad.json").write_text('{"format": "something else"}')
    r = _cli(repo, "check", *progs, "--profile", "machine.yaml", "--baseline", "bad.json")
    assert r.returncode == 3 and "not an ilcnc check baseline" in r.stderr
    # the report never replaces an input
    r = _cli(repo, "check", *progs, "--profile", "machine.yaml", "--max-error", "1", "--junit", progs[0])
    assert r.returncode == 2 and "--junit posts/out/square.h is an input of this check" in r.stderr
    assert (repo / progs[0]).read_bytes() == (OWN / PROGRAMS[0]).read_bytes()


def test_the_single_program_gate_is_unchanged() -> None:
    r = _cli(REPO, "check", OWN / "square.ngc", "--profile", MILL, "--max-error", "0.05")
    assert r.returncode == 0
    assert r.stdout.startswith("ok: square.ngc: cutting moves max 0.0440 mm <= 0.05 mm, RMS 0.0048 mm (air moves")
    r = _cli(REPO, "check", OWN / "square.h", "--profile", MILL, "--max-error", "0.0001")
    assert r.returncode == 1 and r.stderr.startswith(f"error: {OWN / 'square.h'}:11: cutting moves' max contour")
