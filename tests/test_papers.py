"""Paper acceptance cases of the learning loop (seeds 000 and 003; docs/papers.md has the table).

Both papers learn on a reference sampled at the servo period, r(t) -> r(t) + u(t). ilcnc learns on G01 end
points, so the paper's reference is written as one G01 per servo period in inverse-time mode (G93, F = 60/T =
60000 /min): every block lasts one period whatever a correction does to its length, and command k *is* the
reference sample k + 1. The programs are shipped (``samples/own/seed000_corner.ngc``, ``seed003_line.ngc``,
written by ``python bench/seed_programs.py``; a test checks they are its output), and so are the profiles that
run them as the papers do (``configs/seed000-paper-corner.yaml``, ``configs/seed003-paper-line.yaml``,
``...-independent.yaml``; a test checks they differ from the seeds' machine profiles only in the keys their
headers list). So every case here is what ``ilcnc learn`` does with them; ``python bench/papers.py`` prints
the same figures through the CLI. No product code is patched.
"""

from __future__ import annotations

import importlib.util
import itertools
import json
from typing import Any

import numpy as np
import pytest
import yaml
from numpy.typing import NDArray

from ilcnc.errors import ProfileError
from ilcnc.learning.laws import SecondOrderLaw, ccc_error_map, first_markov_per_s, make_law
from ilcnc.learning.learner import LearnResult, learn_virtual, program_with_corrections
from ilcnc.profile.load import load_profile, profile_from_dict
from ilcnc.profile.sections import MachineProfile
from ilcnc.program import Program, read_program
from ilcnc.vcnc.command_error import signal_of_simulation
from ilcnc.vcnc.discrete import discrete_model
from ilcnc.vcnc.simulate import simulate_program
from tests.conftest import REPO

CONFIGS = REPO / "configs"
OWN = REPO / "samples" / "own"
#: the paper's case (program and profile, shipped) and the seed's machine profile the case profile is made from
SEED000 = "seed000-paper-corner.yaml"
SEED000_BASE = "seed000-hendrawan-mass-damper-pid.yaml"
SEED003 = "seed003-paper-line.yaml"
SEED003_IND = "seed003-paper-line-independent.yaml"
SEED003_BASE = "seed003-li-cross-coupled.yaml"
PERIOD_S = 0.001

# seed 000 §III: max contour error of the feedback controller and of the EILCC with ACE after 3 updates
S000_BASELINE_MM = 0.1082
S000_ACE_REDUCTION = 0.817
S000_TANGENT_REDUCTION = 0.8022
#: Tolerance on the reduction, in percentage points: the paper prints no servo period, path length or feed, and its
#: ACE interpolation (eq. 14) is defective, so the last few points of a reduction are not the paper's to give.
S000_REDUCTION_TOL = 0.05


# ---------------------------------------------------------------------------------------------
# programs, profiles, stand-ins
# ---------------------------------------------------------------------------------------------


def _generator() -> Any:
    """``bench/seed_programs.py``, the script that writes the shipped programs."""
    spec = importlib.util.spec_from_file_location("seed_programs", REPO / "bench" / "seed_programs.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _profile(config: str, *, gains: dict[str, object] | None = None, **learning: object) -> MachineProfile:
    """A shipped profile, with learning keys and gains changed for a variant (the test says which)."""
    d = load_profile(CONFIGS / config).to_dict()
    if gains:
        d["learning"]["gains"].update(gains)
    d["learning"].update(learning)
    return profile_from_dict(d, path=CONFIGS / config)


def _flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _differences(config: str, base: str) -> set[str]:
    """The keys two profile files set differently (as written: the loader's derived keys aside)."""
    a, b = (_flat(yaml.safe_load((CONFIGS / c).read_text(encoding="utf-8"))) for c in (config, base))
    return {k for k in a.keys() | b.keys() if k != "machine.name" and a.get(k) != b.get(k)}


def _polyline_distance(q: NDArray[np.float64], vertices: NDArray[np.float64]) -> NDArray[np.float64]:
    """Exact distance of points (N, 2) to a polyline (independent of :mod:`ilcnc.contour.search`)."""
    best = np.full(q.shape[0], np.inf)
    for a, b in itertools.pairwise(vertices):
        d = b - a
        t = np.clip(((q - a) @ d) / (d @ d), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(q - (a + t[:, None] * d), axis=1))
    return best


def _max(r: LearnResult) -> list[float]:
    return [rec.stats["max"] for rec in r.iterations]


def _reduction(r: LearnResult, iteration: int) -> float:
    return 1.0 - r.iterations[iteration].stats["max"] / r.iterations[0].stats["max"]


def _epsilon(profile: MachineProfile, axis: str, kp: float, kd: float, eta: int, f_max_hz: float) -> float:
    """Seed 000 eq. (28): ``max |1 - z^η G(z) K_l(z)|`` on (0, f_max] with ``K_l = K_Pl + K_Dl (1 - z⁻¹)/T``."""
    f = np.linspace(0.01, f_max_hz, 5000)
    z = np.exp(2j * np.pi * f * PERIOD_S)
    g = discrete_model(profile.axes[axis].drive, PERIOD_S).frequency_response(f)
    k = kp + kd * (1.0 - 1.0 / z) / PERIOD_S
    return float(np.max(np.abs(1.0 - z**eta * g * k)))


# ---------------------------------------------------------------------------------------------
# seed 000: Hendrawan & Uchiyama, EILCC with the actual contour error
# ---------------------------------------------------------------------------------------------


def test_the_shipped_programs_are_the_generators_output() -> None:
    gen = _generator()
    for name, make in gen.PROGRAMS.items():
        assert (OWN / name).read_bytes() == make().encode(), f"{name}: rerun python bench/seed_programs.py"
    corner, line = read_program(OWN / "seed000_corner.ngc"), read_program(OWN / "seed003_line.ngc")
    assert corner.n_commands == 8000 and line.n_commands == 5000
    # every command lasts one servo period (G93 F60000)
    for prog in (corner, line):
        assert np.all(prog.moves.block_time_s[prog.command_moves] == pytest.approx(PERIOD_S))


def test_the_paper_profiles_change_only_what_their_headers_list() -> None:
    res = {"machine.resolution_mm", "output.decimals"} | {f"axes.{a}.max_velocity_mm_min" for a in "xyz"}
    assert _differences(SEED000, SEED000_BASE) == res | {"learning.error", "learning.iterations",
                                                         "learning.correction_bound_mm"}
    assert _differences(SEED003, SEED003_BASE) == (res - {"axes.z.max_velocity_mm_min"}) | {"controller.theta"}
    # the independent profile: the whole controller section is {type: independent}
    assert {k.split(".")[0] for k in _differences(SEED003_IND, SEED003)} == {"controller"}
    assert load_profile(CONFIGS / SEED003_IND).controller.type == "independent"


@pytest.fixture(scope="module")
def corner() -> Program:
    return read_program(OWN / "seed000_corner.ngc")


def _s000(**learning: object) -> MachineProfile:
    return _profile(SEED000, **learning)


@pytest.fixture(scope="module")
def s000_ace(corner: Program) -> LearnResult:
    """The paper's gains (K_Pl 0.468, K_Il 0, K_Dl 0.0443, η 0), ACE, 3 updates as printed (no guard)."""
    return learn_virtual(corner, _s000(), iterations=3, guard=False, stop_on_stall=False)


@pytest.fixture(scope="module")
def s000_tangent(corner: Program) -> LearnResult:
    """The same with the Frenet-frame estimate (the paper's "EILCC without ACE")."""
    return learn_virtual(corner, _s000(error="tangent"), iterations=3, guard=False, stop_on_stall=False)


def test_seed000_contour_error_reaches_the_lagging_machine_at_the_corner(corner: Program) -> None:
    prof = _s000()
    sim = simulate_program(corner, prof)
    exact = _polyline_distance(sim.actual_mm[:, :2], np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]))
    # the machine lags ~90 one-ms blocks; a search window of 3 segments found 0.19223 mm, the exact is 0.10897 mm
    assert sim.stats["max"] == pytest.approx(float(exact.max()), abs=1e-6)


def test_seed000_feedback_only_matches_the_paper(corner: Program) -> None:
    prof = _s000()
    sim = simulate_program(corner, prof)
    exact = _polyline_distance(sim.actual_mm[:, :2], np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]))
    # the search finds the exact nearest point of every sample
    assert sim.stats["max"] == pytest.approx(float(exact.max()), abs=1e-9)
    assert sim.stats["mean"] == pytest.approx(float(exact[sim.feed_mask].mean()), abs=1e-9)
    # §III.B: "the feedback controller ... produces the largest contour error of 0.1082 mm" (measured 0.10897 mm)
    assert sim.stats["max"] == pytest.approx(S000_BASELINE_MM, rel=0.03)


def test_seed000_paper_gains_epsilon() -> None:
    prof = _s000()
    # §III.A: ε = 0.6025 for 0 < Ω < 100 Hz; with K_Dl = 0.0443, η = 0 and the backward difference ilcnc finds
    # 0.579 (x) and 0.642 (y) on 0-100 Hz -- and 1.79 / 1.55 at the Nyquist frequency: the printed law converges
    # only in the band the paper looked at
    eps_x = _epsilon(prof, "x", 0.468, 0.0443, 0, 100.0)
    eps_y = _epsilon(prof, "y", 0.468, 0.0443, 0, 100.0)
    assert 0.55 < eps_x < 0.6025 < eps_y < 0.7
    assert _epsilon(prof, "x", 0.468, 0.0443, 0, 499.99) > 1.7
    # the printed K_Dl = 0.443 diverges in that band too (high-frequency limit |1 - K_D K_Dl/m| = 6.9 on x)
    assert _epsilon(prof, "x", 0.468, 0.443, 0, 100.0) > 5.0


def test_seed000_ace_with_the_paper_gains(s000_ace: LearnResult) -> None:
    m = _max(s000_ace)
    # measured: 0.10897 -> 0.05394 -> 0.02648 -> 0.02262 mm (paper: 0.1082 -> 0.0198 mm)
    assert m == pytest.approx([0.10897, 0.05394, 0.02648, 0.02262], abs=5e-6)
    red = _reduction(s000_ace, 3)
    # §III.B: 81.7 % after 3 updates; measured 79.2 %, within the ±5 points the set-up can defend (docs/papers.md)
    assert abs(red - S000_ACE_REDUCTION) <= S000_REDUCTION_TOL, f"reduction {red:.1%}"
    # nothing changes the law's output: the 10 mm bound clips nothing and the move limiter leaves G93 blocks alone
    # (their duration F fixes; until 2026-12-02 it changed 68, 109, 116 commands by up to 4.92 mm: -81.5 %)
    assert s000_ace.clips == []
    # Table I: mean 0.0149 -> 0.012 mm; over ilcnc's stand-in path 0.0338 -> 0.0051 mm
    assert s000_ace.iterations[3].stats["mean"] < s000_ace.iterations[0].stats["mean"]


def test_seed000_ace_beats_the_tangent_estimate(s000_ace: LearnResult, s000_tangent: LearnResult) -> None:
    ace, tan = _max(s000_ace), _max(s000_tangent)
    assert ace[0] == tan[0]
    # measured: ACE 0.05394, 0.02648, 0.02262 mm; tangent 0.06255, 0.12231, 0.12231 mm (3 clips at 10 mm)
    for i in (1, 2, 3):
        assert ace[i] < tan[i], f"update {i}: ACE {ace[i]:.5f} mm, tangent {tan[i]:.5f} mm"
    # not reproduced: the paper's EILCC without ACE reaches 80.22 %; in ilcnc the tangent estimate helps once
    # (42.6 %) and then grows: its error jumps at the corner and K_Dl turns the jump into a kick (docs/papers.md)
    assert _reduction(s000_tangent, 1) > 0.3
    assert _reduction(s000_tangent, 3) < S000_TANGENT_REDUCTION


def _tuned_gains(prof: MachineProfile) -> dict[str, object]:
    """The minimum of eq. (28) for η = 1, K_Il = 0, per axis: ``K_Pl = 1 + c/K_D``, ``K_Dl = m/K_D``.

    With the lead, ``K_l ≈ 1/G`` is what makes ``|1 - z G K_l|`` small, and the loop (eq. 17) is
    ``G ≈ K_D/(m s + c + K_D)`` at all but the lowest frequencies (its slow PID poles nearly cancel).
    """
    kp, kd = {}, {}
    for a in ("x", "y", "z"):
        drive = prof.axes[a].drive
        kp[a] = 1.0 + drive.damping_v_s_mm / drive.kd
        kd[a] = drive.mass_v_s2_mm / drive.kd
    return {"kp": kp, "kd": kd, "ki": 0.0, "lead_samples": 1}


def test_seed000_tuned_gains_beat_the_paper(corner: Program) -> None:
    gains = _tuned_gains(_s000())
    prof = _s000(gains=gains)
    for a in ("x", "y"):
        # on the whole band, not just 0-100 Hz: 0.019 (x), 0.031 (y)
        assert _epsilon(prof, a, gains["kp"][a], gains["kd"][a], 1, 499.99) < 0.05
    r = learn_virtual(corner, prof, iterations=3)  # the product's defaults: guarded
    # measured: 0.10897 -> 0.00098 mm (99.1 %) after one update, below the profile's 1 µm stop tolerance: converged
    assert _reduction(r, 1) > S000_ACE_REDUCTION
    assert r.status == "converged" and r.reduction("max") > S000_ACE_REDUCTION


def test_seed000_tune_gains(corner: Program) -> None:
    """Issue 7's ``tune`` finds the optimum of eq. (28); its gains contract the error by about ε every update."""
    tune = pytest.importorskip("ilcnc.learning.tune")
    design = tune.design_time_domain(_s000())
    analytic = _tuned_gains(_s000())
    assert design.lead_samples == 1
    for a in ("x", "y"):
        # tune: K_Pl 1.0047 / 1.0085, K_Dl 0.05611 / 0.08166, ε 0.0064 / 0.011 (0-100 Hz)
        assert design.axes[a].kd == pytest.approx(analytic["kd"][a], rel=0.01)
        assert design.axes[a].kp == pytest.approx(analytic["kp"][a], rel=0.03)
    gains = {"kp": {a: design.axes[a].kp for a in ("x", "y", "z")}, "kd": {a: design.axes[a].kd for a in ("x", "y", "z")},
             "ki": 0.0, "lead_samples": design.lead_samples}
    r = learn_virtual(corner, _s000(gains=gains, stop_tolerance_mm=0.0), iterations=3, guard=False,
                      stop_on_stall=False)
    m = _max(r)
    # measured: 0.10897 -> 6.81e-4 -> 4.26e-6 -> 2.0e-7 mm: each update leaves 0.62 %, 0.63 % of the max, close to
    # ε (0.64 % on x, 1.1 % on y): the law is linear in the error and the loop nearly inverted. Asserted: at most
    # 2 % (twice the larger ε) for the first two updates; the third stops at the 1e-6 mm rounding of the written
    # numbers. (With the move limiter acting on these G93 blocks, until 2026-12-02, the max grew instead:
    # 0.00340 -> 0.00384 -> 0.00392 mm -- it capped each 2.5-µm block's change at 1.25 µm.)
    assert m[1] < 0.02 * m[0] and m[2] < 0.02 * m[1]
    assert m[3] < 1e-6


def test_seed000_guarded_run(corner: Program, s000_ace: LearnResult) -> None:
    r = learn_virtual(corner, _s000(), iterations=5, guard=True, stop_on_stall=False)
    # the guard keeps the paper's three updates unchanged ...
    assert [rec.kept for rec in r.iterations[:4]] == [True] * 4
    assert _max(r)[:4] == pytest.approx(_max(s000_ace), abs=1e-12)
    # ... the 4th grows the max (0.02262 -> 0.03035 mm: the printed law has ε > 1 above 180 Hz) and is rejected; the
    # retry with the gain halved keeps the max (0.02262 mm) and lowers the RMS (7.34 -> 5.63 µm): kept
    assert not r.iterations[4].kept and r.iterations[5].gain_scale == 0.5 and r.iterations[5].kept
    assert r.iterations[5].stats["rms"] < r.iterations[3].stats["rms"]
    assert r.status == "max_iterations" and r.best_record.iteration == 5


# ---------------------------------------------------------------------------------------------
# seed 003: Li, Zhou, Chen, ILC + cross-coupled control
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def line() -> Program:
    return read_program(OWN / "seed003_line.ngc")


def test_seed003_condition_three(line: Program) -> None:
    prof = _profile(SEED003)
    d = np.array([first_markov_per_s(prof, "x"), first_markov_per_s(prof, "y"), 0.0])
    assert d[:2] == pytest.approx([2.0, 1.5])  # D = CB = diag(a1, c1), §II.C
    law = make_law(prof, line)
    assert isinstance(law, SecondOrderLaw)
    ok, reason, value = law.condition(d, ("x", "y"))
    assert ok and reason == "" and value == pytest.approx(0.1)  # |1 - 0.6·1.5| (the paper's 0.6, not 1/1.5)
    # learned on the program, the printed law meets the CCC's error map M = I + C n nᵀ too:
    # ‖I - Q1·D·M‖∞ = 20 on the 45° line (C = 20), so ilcnc learns on the paper's input M·U (laws.ccc_error_map)
    m = ccc_error_map(prof, line)
    assert m is not None and law.coupling is not None
    k = line.n_commands // 2
    raw = np.eye(2) - np.diag([0.5, 0.6]) @ np.diag(d[:2]) @ m[k][:2, :2]
    assert np.abs(raw).sum(axis=1).max() == pytest.approx(20.0)


def test_seed003_printed_law_on_the_program_without_the_ccc_map_diverges(line: Program) -> None:
    """Why ``make_law`` gives the law the CCC's error map: without it the correction meets D·M, not D."""
    prof = _profile(SEED003)
    law = make_law(prof, line)
    law.coupling = None
    r = learn_virtual(line, prof, iterations=3, guard=False, stop_on_stall=False, law=law)
    # measured: 0.0204, 0.0565, 0.4017, 1.8668 mm (with the map: 0.0204 -> 0.0139 mm after 10 iterations)
    assert _max(r)[3] > 10 * _max(r)[0]


@pytest.mark.parametrize(
    ("gains", "why"),
    [
        ({"q1": {"x": 1.5, "y": 0.6}}, r"condition \(3\) of seed 003 fails: .*2 \+ 0 = 2 is not < 1"),
        ({"p1": 0.8, "p2": 0.0}, r"condition \(3\) of seed 003 fails: P1 \+ P2 must be I"),
        ({"p1": 0.5, "p2": 0.5, "q1": 0.5, "q2": {"x": 0.0, "y": 0.9}},
         r"condition \(3\) of seed 003 fails: .*is not < 1"),
    ],
)
def test_seed003_gains_breaking_condition_three_are_refused(line: Program, gains: dict[str, object], why: str) -> None:
    with pytest.raises(ProfileError, match=why):
        make_law(_profile(SEED003, gains=gains), line)


@pytest.mark.parametrize("ccc", [False, True])
def test_seed003_d_type_learns_on_the_error_change_its_correction_causes(line: Program, ccc: bool) -> None:
    """The forward difference over the command time stamps is the right derivative (eq. 4).

    A correction δ of command k moves reference sample k + 1; with the drives' ZOH the position answers from the
    next sample on, so E(k) does not see it and E(k + 1) moves by -h1·M·δ (h1 ≈ CB·T). The law's forward difference
    (E(k+1) - E(k))/T is what U(k) drives: one update leaves (I - Q1·h1/T)·M·δ of it, the diagonal of the lifted
    learning matrix -- 1 - 0.5·2 = 0 on x and 1 - 0.6·1.5 = 0.1 on y by condition (3). A backward difference would
    see nothing of it at k (diagonal 1: no convergence).
    """
    prof = _profile(SEED003 if ccc else SEED003_IND)
    k = 2000
    delta = np.array([2e-4, -1e-4, 0.0])  # mm: well inside the move-length and resolution limits
    u = np.zeros((line.n_commands, 3))
    u[k] = delta
    _text, bumped = program_with_corrections(line, u, prof)
    s0 = signal_of_simulation(simulate_program(line, prof), line, "tracking")
    s1 = signal_of_simulation(simulate_program(bumped, prof, against=line), line, "tracking")
    de = s1.e_mm - s0.e_mm
    assert np.abs(de[: k + 1]).max() < 1e-12  # causal, one period of hold: E(k) is measured before δ acts
    law = make_law(prof, line)
    m = law.coupling[k] if law.coupling is not None else np.eye(3)
    du = law.next_correction([np.zeros_like(u)], [de], [s0.t_s])[k]
    left = (m @ (delta + du))[:2] / (m @ delta)[:2]
    d = np.array([first_markov_per_s(prof, "x"), first_markov_per_s(prof, "y")])
    assert left == pytest.approx(1.0 - np.array([0.5, 0.6]) * d, abs=0.01)


@pytest.fixture(scope="module")
def s003_runs(line: Program) -> dict[str, LearnResult]:
    """The paper's P-type law (P1 = I, Q1 = diag(0.5, 0.6)), tracking error, 10 iterations, with and without CCC."""
    return {name: learn_virtual(line, _profile(config), iterations=10, guard=False, stop_on_stall=False)
            for name, config in (("ccc", SEED003), ("independent", SEED003_IND))}


@pytest.mark.slow
def test_seed003_ccc_is_smaller_at_every_iteration_and_does_not_oscillate(s003_runs: dict[str, LearnResult]) -> None:
    ccc, ind = _max(s003_runs["ccc"]), _max(s003_runs["independent"])
    assert len(ccc) == len(ind) == 11
    # measured: CCC 0.02044 -> 0.01389 mm, independent 0.37003 -> 0.04926 mm
    for i, (a, b) in enumerate(zip(ccc, ind, strict=True)):
        assert a < b, f"iteration {i}: CCC {a:.5f} mm, independent {b:.5f} mm"
    # "no oscillation": the max (and RMS) contour error never grows from one iteration to the next
    rms = [rec.stats["rms"] for rec in s003_runs["ccc"].iterations]
    assert all(b <= a for a, b in itertools.pairwise(ccc))
    assert all(b <= a for a, b in itertools.pairwise(rms))
    # nothing changes the law's output: the 2 mm bound never clips, and the move limiter leaves the G93 blocks alone
    # (until 2026-12-02 it deferred the law's first 0.5 mm step along the line: 134 commands at the first update)
    assert s003_runs["ccc"].clips == [] and s003_runs["independent"].clips == []
    # ILC still learns under the CCC (-32 % in 10 iterations); without CCC it learns faster from 18x higher
    assert ccc[-1] < 0.75 * ccc[0] and ind[-1] < 0.2 * ind[0]


def test_seed003_ccc_with_theta_of_its_reference_grows(line: Program) -> None:
    """Why ``controller.theta: desired``: with θ from the corrected reference (what a real control knows) the run grows.

    The corrections tilt the 1.41-µm steps of the corrected reference by tens of degrees, θ leaks the ~1 mm
    tangential lag into the CCC's contour estimate and C = 20 amplifies it.
    """
    d = load_profile(CONFIGS / SEED003).to_dict()
    d["controller"]["theta"] = "reference"
    prof = profile_from_dict(d)
    r = learn_virtual(line, prof, iterations=3, guard=False, stop_on_stall=False)
    m = _max(r)
    # measured: 0.02044, 0.01987, 0.07149, 0.21695 mm (with theta: desired 0.02044, 0.01963, 0.01878, 0.01793 mm)
    assert m[1] < m[0] and m[3] > 5 * m[0]
    # the CLI's guard keeps only what improves: through ilcnc learn this profile outputs iteration 1
    g = learn_virtual(line, prof, iterations=3)
    assert g.status == "diverged" and g.best_record.iteration == 1


def test_seed003_second_order_law(line: Program) -> None:
    # P1 + P2 = I, Q1 = P1·D⁻¹: ‖P1 - Q1 D‖ + ‖P2 - Q2 D‖ = 0 + 0.2 (a "momentum" of -0.2 on U_{i-1})
    gains = {"p1": 1.2, "p2": -0.2, "q1": {"x": 0.6, "y": 0.8}, "q2": 0.0}
    prof = _profile(SEED003, gains=gains)
    law = make_law(prof, line)
    d = [first_markov_per_s(prof, a) if a in prof.axes else 0.0 for a in ("x", "y", "z")]
    ok, _reason, value = law.condition(d, ("x", "y"))
    assert ok and value == pytest.approx(0.2)
    r = learn_virtual(line, prof, iterations=10, guard=False, stop_on_stall=False)
    m = _max(r)
    # measured: 0.02044 -> 0.00856 mm (the P-type law: 0.01389 mm)
    assert all(b <= a for a, b in itertools.pairwise(m))
    assert m[-1] < 0.5 * m[0]


@pytest.mark.parametrize(("program", "config", "iterations", "want_mm"), [
    ("seed000_corner.ngc", SEED000, 3, [0.10897, 0.05394, 0.02648, 0.02262]),
    ("seed003_line.ngc", SEED003, 2, [0.02044, 0.01963, 0.01878]),
])
def test_the_papers_cases_through_ilcnc_learn(tmp_path, program: str, config: str, iterations: int,
                                               want_mm: list[float]) -> None:
    """What a user runs (docs/papers.md): the shipped program and profile through the CLI, guarded."""
    from typer.testing import CliRunner

    from ilcnc.cli import app

    res = CliRunner().invoke(app, ["learn", str(OWN / program), "--profile", str(CONFIGS / config), "--out",
                                   str(tmp_path / program), "--iterations", str(iterations), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    got = [it["contour_error_mm"]["max"] for it in data["iterations"]]
    # measured as bench/papers.py prints them (5e-6 mm: the last digit docs/papers.md gives)
    assert got == pytest.approx(want_mm, abs=5e-6)
    assert all(it["kept"] and it["clipped"] == 0 for it in data["iterations"])
