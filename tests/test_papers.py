"""Paper acceptance cases of the learning loop (seeds 000 and 003; docs/papers.md has the table).

Both papers learn on a reference sampled at the servo period, r(t) -> r(t) + u(t). ilcnc learns on G01 end
points, so the paper's reference is written as one G01 per servo period in inverse-time mode (G93, F = 60/T =
60000 /min): every block lasts one period whatever a correction does to its length, and command k *is* the
reference sample k + 1. (With G94 and one feed word the corrected blocks change their durations, so the same law
acts at other instants than the ones it measured: docs/papers.md has the numbers.)

Overrides of the configs, all because the papers' simulations have no such thing: ``machine.resolution_mm`` 1e-6 and
``output.decimals`` 6 (µm-level corrections of 1-ms blocks), ``max_velocity_mm_min`` 1e6 on every axis (a corrected
1-ms block may ask for metres per second; the placeholder 10000 mm/min would stretch it and shift the time index), and
for seed 000 ``learning.correction_bound_mm`` 10 (the derivative term kicks mm-size single-period corrections).

Stand-ins for patches outside the files these tests may change (both in docs/papers.md), each with a strict xfail
that shows what the product does without it (and fails once the patch lands, to remove the stand-in):

* ``desired_direction`` -- the cross-coupled controller takes θ from the desired contour (as in seed 003's Fig. 2,
  where the CCC sees x_r, y_r and the ILC input is added after it) instead of from the corrected reference it runs,
  whose 1-ms steps the corrections tilt by tens of degrees (:func:`test_seed003_ccc_with_theta_of_the_corrected_reference`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from ilcnc.errors import ProfileError
from ilcnc.learning.laws import SecondOrderLaw, ccc_error_map, first_markov_per_s, make_law
from ilcnc.learning.learner import CLIP_BOUND, CLIP_MOVE_LENGTH, LearnResult, learn_virtual, program_with_corrections
from ilcnc.profile.load import load_profile, profile_from_dict
from ilcnc.profile.sections import MachineProfile
from ilcnc.program import Program, read_program
from ilcnc.vcnc.command_error import signal_of_simulation
from ilcnc.vcnc.discrete import discrete_model
from ilcnc.vcnc.simulate import simulate_program
from tests.conftest import REPO

CONFIGS = REPO / "configs"
SEED000 = "seed000-hendrawan-mass-damper-pid.yaml"
SEED003 = "seed003-li-cross-coupled.yaml"
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


def _time_indexed_program(path: Path, points_mm: NDArray[np.float64]) -> Program:
    """One G01 per servo period from X0 Y0 through ``points_mm`` (K, 2), inverse-time feed (G93)."""
    f = 60.0 / PERIOD_S
    lines = ["G21 G90 G94", "G00 X0 Y0", "G93"]
    lines += [f"G01 X{x:.4f} Y{y:.4f} F{f:.0f}" for x, y in points_mm]
    lines.append("M30")
    text = "\n".join(lines) + "\n"
    path.write_text(text)
    return read_program(path, data=text.encode())


def _corner_points() -> NDArray[np.float64]:
    """Seed 000: X0 Y0 -> X10 -> Y10 at 150 mm/min, 0.0025 mm per 1-ms period: 4000 blocks per leg."""
    s = np.arange(1, 4001) * 0.0025
    return np.vstack([np.column_stack([s, np.zeros_like(s)]), np.column_stack([np.full_like(s, 10.0), s])])


def _line_points() -> NDArray[np.float64]:
    """Seed 003: x = y = t mm for 5 s (G01 X5 Y5 F84.853 from rest), 1 µm per axis per 1-ms period."""
    s = np.arange(1, 5001) * 0.001
    return np.column_stack([s, s])


def _profile(config: str, *, ccc: bool | None = None, gains: dict[str, object] | None = None,
             **learning: object) -> MachineProfile:
    """The seed's config with the overrides of the module docstring."""
    d = load_profile(CONFIGS / config).to_dict()
    d["machine"]["resolution_mm"] = 1e-6
    d.setdefault("output", {})["decimals"] = 6
    for axis in d["axes"].values():
        axis["max_velocity_mm_min"] = 1e6
    if ccc is False:
        d["controller"] = {"type": "independent"}
    if gains:
        d["learning"]["gains"].update(gains)
    d["learning"].update(learning)
    return profile_from_dict(d)


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


def _desired_normals(direction: tuple[float, float]) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """``path_normals`` of a CCC that takes θ from a desired straight contour of the given direction."""
    t = np.asarray(direction, dtype=np.float64) / math.hypot(*direction)

    def normals(ref_2d: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.tile([-t[1], t[0]], (np.asarray(ref_2d).shape[0], 1))

    return normals


@contextmanager
def _desired_direction() -> Iterator[None]:
    """Stand-in for the drives.py patch: the CCC's θ of seed 003's desired 45° line (docstring)."""
    import ilcnc.vcnc.drives as drives

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(drives, "path_normals", _desired_normals((1.0, 1.0)))
        yield


@pytest.fixture
def desired_direction() -> Iterator[None]:
    with _desired_direction():
        yield


# ---------------------------------------------------------------------------------------------
# seed 000: Hendrawan & Uchiyama, EILCC with the actual contour error
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def corner(tmp_path_factory: pytest.TempPathFactory) -> Program:
    return _time_indexed_program(tmp_path_factory.mktemp("s000") / "corner.nc", _corner_points())


def _s000(**learning: object) -> MachineProfile:
    return _profile(SEED000, correction_bound_mm=10.0, **learning)


@pytest.fixture(scope="module")
def s000_ace(corner: Program) -> LearnResult:
    """The paper's gains (K_Pl 0.468, K_Il 0, K_Dl 0.0443, η 0), ACE, 3 updates as printed (no guard)."""
    return learn_virtual(corner, _s000(error="contour"), iterations=3, guard=False, stop_on_stall=False)


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
    # the stand-in search finds the exact nearest point of every sample
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
    # measured: 0.10897 -> 0.05783 -> 0.03248 -> 0.02015 mm (paper: 0.1082 -> 0.0198 mm)
    assert all(b < a for a, b in itertools.pairwise(m))
    red = _reduction(s000_ace, 3)
    # §III.B: 81.7 % after 3 updates; measured 81.5 % (79.2 % without learn.py's keep_moves_forward)
    assert abs(red - S000_ACE_REDUCTION) <= S000_REDUCTION_TOL, f"reduction {red:.1%}"
    # the 10 mm bound never clips the paper's law; the move limiter (learn.py keep_moves_forward) changes it, and
    # says so (issue 22 item 1: it did so silently). Measured 2026-12-02: 68, 109, 116 commands of the three
    # updates, up to 4.92 mm each; it acts on G93 blocks still, where it protects nothing (issue 22, open)
    assert not [c for c in s000_ace.clips if c.cause == CLIP_BOUND]
    per_update = [len({c.k for c in r.clipped if c.cause == CLIP_MOVE_LENGTH}) for r in s000_ace.iterations[1:]]
    # a command whose wanted change sits within rounding of half its length may flip across toolchains: +-2
    assert all(abs(n - want) <= 2 for n, want in zip(per_update, (68, 109, 116), strict=True)), per_update
    assert max(abs(c.wanted_mm - c.applied_mm) for c in s000_ace.clips) == pytest.approx(4.918, abs=0.001)
    # Table I: mean 0.0149 -> 0.012 mm; over ilcnc's stand-in path 0.0338 -> 0.0051 mm
    assert s000_ace.iterations[3].stats["mean"] < s000_ace.iterations[0].stats["mean"]


def test_seed000_ace_beats_the_tangent_estimate(s000_ace: LearnResult, s000_tangent: LearnResult) -> None:
    ace, tan = _max(s000_ace), _max(s000_tangent)
    assert ace[0] == tan[0]
    # measured: ACE 0.05783, 0.03248, 0.02015 mm; tangent 0.06191, 0.07934, 0.10199 mm
    for i in (1, 2, 3):
        assert ace[i] < tan[i], f"update {i}: ACE {ace[i]:.5f} mm, tangent {tan[i]:.5f} mm"
    # not reproduced: the paper's EILCC without ACE reaches 80.22 %; in ilcnc the tangent estimate helps once
    # (43.2 %) and then grows: its error jumps at the corner and K_Dl turns the jump into a kick (docs/papers.md)
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
    prof = _s000(error="contour", gains=gains)
    for a in ("x", "y"):
        # on the whole band, not just 0-100 Hz: 0.019 (x), 0.031 (y)
        assert _epsilon(prof, a, gains["kp"][a], gains["kd"][a], 1, 499.99) < 0.05
    r = learn_virtual(corner, prof, iterations=3)  # the product's defaults: guarded
    # measured: 0.10897 -> 0.00296 mm (97.3 %); the 2nd update jumps to 0.07065 mm (the ACE is not linear in q at
    # the corner: the law's gain of ~110 at the Nyquist frequency turns the µm jump left at the bisector into a
    # kick of tens of µm) and is rejected, the halved retry too (0.00541 mm): diverged, the output is update 1.
    # Unguarded the 3 updates give 0.00296, 0.07065, 0.04189 mm (61.6 % after the 3rd).
    assert _reduction(r, 1) > S000_ACE_REDUCTION
    assert r.reduction("max") > S000_ACE_REDUCTION


def test_seed000_tune_gains(corner: Program) -> None:
    """Issue 7's ``tune`` finds the optimum of eq. (28); its gains beat the paper at every one of 3 updates."""
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
    r = learn_virtual(corner, _s000(error="contour", gains=gains), iterations=3, guard=False, stop_on_stall=False)
    # measured: 0.10897 -> 0.00337, 0.00917, 0.01360 mm (96.9 %, 91.6 %, 87.5 %)
    assert all(_reduction(r, i) > S000_ACE_REDUCTION for i in (1, 2, 3))


def test_seed000_guarded_run(corner: Program, s000_ace: LearnResult) -> None:
    r = learn_virtual(corner, _s000(error="contour"), iterations=5, guard=True, stop_on_stall=False)
    # the guard keeps the paper's three updates unchanged ...
    assert [rec.kept for rec in r.iterations[:4]] == [True] * 4
    assert _max(r)[:4] == pytest.approx(_max(s000_ace), abs=1e-12)
    # ... the 4th grows the max (0.02015 -> 0.02901 mm: the printed law has ε > 1 above 180 Hz), the retry with the
    # gain halved too (0.02213 mm): diverged, the output is the 3rd update (81.5 %)
    assert not r.iterations[4].kept and r.iterations[5].gain_scale == 0.5 and not r.iterations[5].kept
    assert r.status == "diverged" and r.best_record.iteration == 3


# ---------------------------------------------------------------------------------------------
# seed 003: Li, Zhou, Chen, ILC + cross-coupled control
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> Program:
    return _time_indexed_program(tmp_path_factory.mktemp("s003") / "line.nc", _line_points())


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


def test_seed003_printed_law_on_the_program_without_the_ccc_map_diverges(
    line: Program, desired_direction: None
) -> None:
    """Why ``make_law`` gives the law the CCC's error map: without it the correction meets D·M, not D."""
    prof = _profile(SEED003)
    law = make_law(prof, line)
    law.coupling = None
    r = learn_virtual(line, prof, iterations=3, guard=False, stop_on_stall=False, law=law)
    # measured: 0.0204, 0.0562, 0.3962, 1.8619 mm (2.4 mm after 10 iterations; with the map: 0.0204 -> 0.0139 mm)
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
def test_seed003_d_type_learns_on_the_error_change_its_correction_causes(
    line: Program, desired_direction: None, ccc: bool
) -> None:
    """The forward difference over the command time stamps is the right derivative (eq. 4).

    A correction δ of command k moves reference sample k + 1; with the drives' ZOH the position answers from the
    next sample on, so E(k) does not see it and E(k + 1) moves by -h1·M·δ (h1 ≈ CB·T). The law's forward difference
    (E(k+1) - E(k))/T is what U(k) drives: one update leaves (I - Q1·h1/T)·M·δ of it, the diagonal of the lifted
    learning matrix -- 1 - 0.5·2 = 0 on x and 1 - 0.6·1.5 = 0.1 on y by condition (3). A backward difference would
    see nothing of it at k (diagonal 1: no convergence).
    """
    prof = _profile(SEED003, ccc=ccc)
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
    with _desired_direction():
        return {name: learn_virtual(line, _profile(SEED003, ccc=ccc), iterations=10, guard=False, stop_on_stall=False)
                for name, ccc in (("ccc", True), ("independent", False))}


@pytest.mark.slow
def test_seed003_ccc_is_smaller_at_every_iteration_and_does_not_oscillate(s003_runs: dict[str, LearnResult]) -> None:
    ccc, ind = _max(s003_runs["ccc"]), _max(s003_runs["independent"])
    assert len(ccc) == len(ind) == 11
    # measured: CCC 0.02044 -> 0.01392 mm, independent 0.37007 -> 0.04967 mm
    for i, (a, b) in enumerate(zip(ccc, ind, strict=True)):
        assert a < b, f"iteration {i}: CCC {a:.5f} mm, independent {b:.5f} mm"
    # "no oscillation": the max (and RMS) contour error never grows from one iteration to the next
    rms = [rec.stats["rms"] for rec in s003_runs["ccc"].iterations]
    assert all(b <= a for a, b in itertools.pairwise(ccc))
    assert all(b <= a for a, b in itertools.pairwise(rms))
    # the bound never clips; the move limiter defers the law's first 0.5 mm step along the line and says so
    # (measured 2026-12-02: 134 commands at the first update, 471 at the tenth, up to 0.551 mm; issue 22 item 1)
    clips = s003_runs["ccc"].clips
    assert not [c for c in clips if c.cause == CLIP_BOUND]
    assert len({c.k for c in s003_runs["ccc"].iterations[1].clipped if c.cause == CLIP_MOVE_LENGTH}) >= 100
    assert max(abs(c.wanted_mm - c.applied_mm) for c in clips) == pytest.approx(0.551, abs=0.001)
    # ILC still learns under the CCC (-32 % in 10 iterations); without CCC it learns faster from 18x higher
    assert ccc[-1] < 0.75 * ccc[0] and ind[-1] < 0.2 * ind[0]


def test_seed003_second_order_law(line: Program, desired_direction: None) -> None:
    # P1 + P2 = I, Q1 = P1·D⁻¹: ‖P1 - Q1 D‖ + ‖P2 - Q2 D‖ = 0 + 0.2 (a "momentum" of -0.2 on U_{i-1})
    gains = {"p1": 1.2, "p2": -0.2, "q1": {"x": 0.6, "y": 0.8}, "q2": 0.0}
    prof = _profile(SEED003, gains=gains)
    law = make_law(prof, line)
    d = [first_markov_per_s(prof, a) if a in prof.axes else 0.0 for a in ("x", "y", "z")]
    ok, _reason, value = law.condition(d, ("x", "y"))
    assert ok and value == pytest.approx(0.2)
    r = learn_virtual(line, prof, iterations=10, guard=False, stop_on_stall=False)
    m = _max(r)
    # measured: 0.02044 -> 0.00861 mm (the P-type law: 0.01392 mm)
    assert all(b <= a for a, b in itertools.pairwise(m))
    assert m[-1] < 0.5 * m[0]


@pytest.mark.xfail(strict=True, reason="drives.py: the CCC takes θ from the corrected reference, whose 1-ms steps the"
                   " corrections tilt; remove this xfail and the desired_direction stand-in with the fix")
def test_seed003_ccc_with_theta_of_the_corrected_reference(line: Program) -> None:
    r = learn_virtual(line, _profile(SEED003), iterations=3, guard=False, stop_on_stall=False)
    m = _max(r)
    # measured: 0.02044, 0.01953, 0.05550, 0.25619 mm (1.12 mm by iteration 7)
    assert all(b <= a for a, b in itertools.pairwise(m))
