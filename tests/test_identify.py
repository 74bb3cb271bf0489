"""Drive identification from step responses (``ilcnc.learning.identify``).

Synthetic data come from closed-form continuous-time responses (not from the
fitter's own model) or from the simulator (:func:`ilcnc.vcnc.drives.axis_response`)
with Gaussian noise from ``numpy.random.RandomState`` (a frozen stream, so the
seeds give the same noise on every numpy version).

Figures measured with these tests (1 kHz sampling, noise σ = 1 % of the step):

* SOPDT ζ = 0.7 (ω0 = 95.6 rad/s, Td = 6.6 ms), one 1000 mm/min velocity step,
  0.5 s, seeds 0–19: largest errors K 0.25 %, ω0 1.6 %, ζ 2.1 %, Td 3.7 %;
  spread (std) 0.11 / 0.91 / 0.83 / 2.0 %, as the reported standard errors
  predict (0.14 / 1.0 / 0.74 / 2.1 %): the fit is at the Cramér–Rao bound, the
  dead time is the hardest parameter. A move (step up, step down 0.25 s
  later): 0.14 / 1.0 / 1.2 / 2.1 %.
* The paper's ζ = 1.0, one step: largest errors K 0.25 %, ω0 3.7 %, ζ 2.9 %,
  Td 5.3 %; std 0.12 / 1.8 / 1.3 / 3.0 % (reported 0.14 / 2.2 / 1.6 / 3.2 %):
  with critical damping the slow start of the response trades against the
  dead time. A move: largest 0.16 / 2.3 / 1.6 / 3.6 %.
* mass_damper, seed 000's x axis (m = 0.45, c = 0.144 under K_P = 0.96,
  K_I = 0.01, K_D = 8), 1 mm position step, 1 s: m within 0.73 %, c within
  13.5 % (std 6.0 %, reported 7.6 %): only c + K_D = 8.144 shapes the response,
  so c carries 57× the relative error of that sum. Noise-free data give both
  to 1e-6.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import InputError, ProfileError
from ilcnc.learning.identification import GAIN_TOLERANCE, PARAMETERS, Identification
from ilcnc.learning.identify import identify_step, sopdt_velocity_response
from ilcnc.learning.step_files import identify_file, read_step_csv
from ilcnc.profile.load import load_profile
from ilcnc.profile.sections import FirstOrderDelayDrive, MassDamperPidDrive, SopdtDrive
from ilcnc.vcnc.drives import axis_response

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data" / "identify"
CONFIGS = REPO / "configs"
T = 1e-3
V = 1000.0 / 60.0  # seed 004's 1000 mm/min velocity step, mm/s
W0, TD = 95.6, 0.0066


# --------------------------------------------------------------------------
# Closed-form continuous responses (independent of the fitter's discretisation)
# --------------------------------------------------------------------------


def sopdt_step_velocity(t: np.ndarray, t_step: float, size: float, w: float, z: float, td: float) -> np.ndarray:
    """Velocity of K·w²e^{-s·td}/(s² + 2zw s + w²) after a velocity step ``size`` at ``t_step`` (K = 1)."""
    tau = np.maximum(t - t_step - td, 0.0)
    if z < 1.0:
        wd = w * math.sqrt(1.0 - z * z)
        s = 1.0 - np.exp(-z * w * tau) * (np.cos(wd * tau) + z / math.sqrt(1.0 - z * z) * np.sin(wd * tau))
    elif z == 1.0:
        s = 1.0 - (1.0 + w * tau) * np.exp(-w * tau)
    else:
        r = math.sqrt(z * z - 1.0)
        p1, p2 = -w * (z - r), -w * (z + r)
        s = 1.0 + (p2 * np.exp(p1 * tau) - p1 * np.exp(p2 * tau)) / (p1 - p2)
    return size * s


def sopdt_step_position(t: np.ndarray, t_step: float, size: float, w: float, z: float, td: float) -> np.ndarray:
    """Position (the integral of the velocity above) after a velocity step ``size`` at ``t_step``."""
    tau = np.maximum(t - t_step - td, 0.0)
    if z < 1.0:
        wd = w * math.sqrt(1.0 - z * z)
        p = tau - 2 * z / w + np.exp(-z * w * tau) * ((2 * z / w) * np.cos(wd * tau) + ((2 * z * z - 1) / wd) * np.sin(wd * tau))
    else:
        assert z == 1.0
        p = tau - 2.0 / w + np.exp(-w * tau) * (2.0 / w + tau)
    return size * p


def velocity_step_record(z: float, seed: int | None, *, move: bool = False, noise: float = 0.01, td: float = TD):
    """0.5 s (move: 0.6 s) at 1 kHz: velocity step V at 50 ms (and back to 0 at 300 ms), noise σ = noise·V."""
    t = np.arange(0.0, 0.6 if move else 0.5, T)
    u = np.where(t >= 0.05 - 1e-12, V, 0.0)
    y = sopdt_step_velocity(t, 0.05, V, W0, z, td)
    if move:
        u = u - np.where(t >= 0.3 - 1e-12, V, 0.0)
        y = y - sopdt_step_velocity(t, 0.3, V, W0, z, td)
    if seed is not None:
        y = y + np.random.RandomState(seed).normal(0.0, noise * V, t.size)
    return t, u, y


def rel_errors(ident: Identification, truth: dict[str, float]) -> dict[str, float]:
    return {k: ident.parameters[k] / v - 1.0 for k, v in truth.items()}


# --------------------------------------------------------------------------
# The models
# --------------------------------------------------------------------------


@pytest.mark.parametrize("zeta", [0.3, 0.7, 1.0, 1.6])
@pytest.mark.parametrize("delay", [0.0, 0.003, 0.0066, 0.0123])
def test_velocity_model_is_exact(zeta: float, delay: float) -> None:
    """The sampled SOPDT velocity (ZOH, fractional dead time) equals the continuous response at the samples."""
    t = np.arange(0.0, 0.3, T)
    u = np.where(t >= 0.02 - 1e-12, V, 0.0)
    exact = sopdt_step_velocity(t, 0.02, V, W0, zeta, delay)
    model = sopdt_velocity_response(u, W0, zeta, delay, T)
    assert np.max(np.abs(model - exact)) < 1e-10 * V


def test_velocity_model_starts_at_rest_at_first_command() -> None:
    u = np.full(50, 3.0)
    assert np.allclose(sopdt_velocity_response(u, W0, 0.7, TD, T, gain=2.0), 6.0)
    assert sopdt_velocity_response(np.zeros(0), W0, 0.7, TD, T).shape == (0,)


def test_position_convention_matches_the_simulator() -> None:
    """A commanded ramp r with (r[k] − r[k−1])/T = v from t_k is a velocity step at t_k (the simulator's convention)."""
    t = np.arange(0.0, 0.4, T)
    ks = 40
    v = np.where(np.arange(t.size) >= ks, V, 0.0)
    r = np.cumsum(v) * T
    for z in (0.7, 1.0):
        q = axis_response(SopdtDrive(omega0_rad_s=W0, zeta=z, gain=1.0, delay_s=TD), r, T)
        assert np.max(np.abs(q - sopdt_step_position(t, ks * T, V, W0, z, TD))) < 1e-10
        ident = identify_step(t, r, sopdt_step_position(t, ks * T, V, W0, z, TD), model="sopdt", signal="position")
        for k, e in rel_errors(ident, {"gain": 1.0, "omega0_rad_s": W0, "zeta": z, "delay_s": TD}).items():
            assert abs(e) < 1e-6, (z, k, e)


@pytest.mark.parametrize("zeta", [0.7, 1.0])
def test_noise_free_velocity_step_is_recovered_exactly(zeta: float) -> None:
    t, u, y = velocity_step_record(zeta, None)
    ident = identify_step(t, u, y, model="sopdt", signal="velocity")
    for k, e in rel_errors(ident, {"gain": 1.0, "omega0_rad_s": W0, "zeta": zeta, "delay_s": TD}).items():
        assert abs(e) < 1e-6, (k, e)
    assert ident.r2 > 1 - 1e-12
    assert ident.warnings == ()


# --------------------------------------------------------------------------
# Acceptance: SOPDT with 1 % noise over 20 seeds
# --------------------------------------------------------------------------


def _seed_study(zeta: float, *, move: bool) -> tuple[np.ndarray, np.ndarray]:
    truth = {"gain": 1.0, "omega0_rad_s": W0, "zeta": zeta, "delay_s": TD}
    errs, ses = [], []
    for seed in range(20):
        t, u, y = velocity_step_record(zeta, seed, move=move)
        ident = identify_step(t, u, y, model="sopdt", signal="velocity")
        errs.append([ident.parameters[k] / v - 1.0 for k, v in truth.items()])
        ses.append([ident.stderr[k] / v for k, v in truth.items()])
        assert ident.r2 > 0.99
    return np.array(errs), np.array(ses)


def _spread(errs: np.ndarray) -> str:
    names = ("K", "ω0", "ζ", "Td")
    mx = np.max(np.abs(errs), axis=0) * 100
    sd = np.std(errs, axis=0) * 100
    return ", ".join(f"{n}: max {a:.2f} %, std {b:.2f} %" for n, a, b in zip(names, mx, sd, strict=True))


@pytest.mark.parametrize("move", [False, True], ids=["one-step", "move"])
def test_sopdt_zeta_07_recovered_over_20_noise_seeds(move: bool) -> None:
    """Issue 7: ζ = 0.7, 1 % noise: K within 1 %, ω0, ζ, Td within 5 %, for every one of 20 seeds.

    One step (0.5 s): largest errors K 0.25 %, ω0 1.6 %, ζ 2.1 %, Td 3.7 %;
    a move (step up and down, 0.6 s): 0.14 / 1.0 / 1.2 / 2.1 %. The spread
    agrees with the reported standard errors (the fit is at the Cramér–Rao
    bound), checked below.
    """
    errs, ses = _seed_study(0.7, move=move)
    print(f"\nζ = 0.7 ({'move' if move else 'one step'}): {_spread(errs)}")
    assert np.all(np.abs(errs[:, 0]) < 0.01), errs[:, 0]
    assert np.all(np.abs(errs[:, 1:]) < 0.05), errs[:, 1:]
    # the reported standard errors describe the spread
    ratio = np.std(errs, axis=0) / np.mean(ses, axis=0)
    assert np.all((ratio > 0.5) & (ratio < 1.6)), ratio
    assert np.all(np.abs(errs) < 4.5 * ses)


@pytest.mark.parametrize("move", [False, True], ids=["one-step", "move"])
def test_sopdt_paper_zeta_1_spread(move: bool) -> None:
    """Seed 004's ζ = 1.0: the dead time is harder to separate from the slow start of a critically damped drive.

    One step, seeds 0–19: largest errors K 0.25 %, ω0 3.7 %, ζ 2.9 %, Td 5.3 %
    (std 0.12 / 1.8 / 1.3 / 3.0 %; reported standard errors 0.14 / 2.2 / 1.6 /
    3.2 %). Asserted: K 1 %, ω0 and ζ 10 %, Td 15 % (about 5 standard errors).
    A move (step up and down): 0.16 / 2.3 / 1.6 / 3.6 %, within 5 % like ζ = 0.7.
    """
    errs, ses = _seed_study(1.0, move=move)
    print(f"\nζ = 1.0 ({'move' if move else 'one step'}): {_spread(errs)}")
    assert np.all(np.abs(errs[:, 0]) < 0.01)
    if move:
        assert np.all(np.abs(errs[:, 1:]) < 0.05)
    else:
        assert np.all(np.abs(errs[:, 1:3]) < 0.10)
        assert np.all(np.abs(errs[:, 3]) < 0.15)
    assert np.all(np.abs(errs) < 5.0 * ses)


def test_confidence_intervals_cover_the_truth() -> None:
    hits = 0
    for seed in range(20):
        t, u, y = velocity_step_record(0.7, seed)
        ident = identify_step(t, u, y, model="sopdt", signal="velocity")
        lo, hi = ident.ci95["delay_s"]
        hits += lo <= TD <= hi
        assert ident.ci95["gain"][0] < ident.parameters["gain"] < ident.ci95["gain"][1]
    assert hits >= 16  # 95 % intervals: 19 of 20 expected


# --------------------------------------------------------------------------
# Position and velocity signals, step sizes
# --------------------------------------------------------------------------


def test_position_and_velocity_signals_agree() -> None:
    """The same drive measured as velocity (1 % noise) and as position (1 µm encoder noise) gives the same fit."""
    drive = SopdtDrive(omega0_rad_s=120.0, zeta=0.8, gain=1.0, delay_s=0.004)
    n, ks = 500, 50
    v = np.where(np.arange(n) >= ks, V, 0.0)
    v = v - np.where(np.arange(n) >= 300, V, 0.0)
    t = np.arange(n) * T
    rs = np.random.RandomState(11)
    vel = sopdt_velocity_response(v, drive.omega0_rad_s, drive.zeta, drive.delay_s, T) + rs.normal(0, 0.01 * V, n)
    r = 5.0 + np.cumsum(v) * T
    pos = axis_response(drive, r, T) + rs.normal(0, 0.001, n)
    a = identify_step(t, v, vel, model="sopdt", signal="velocity")
    b = identify_step(t, r, pos, model="sopdt", signal="position")
    for k in PARAMETERS["sopdt"]:
        truth = getattr(drive, {"gain": "gain"}.get(k, k))
        for ident in (a, b):
            assert abs(ident.parameters[k] - truth) < 4.5 * ident.stderr[k], (k, ident.signal, ident.parameters[k])
        assert abs(a.parameters[k] - b.parameters[k]) < 4.5 * math.hypot(a.stderr[k], b.stderr[k])
    assert a.y_unit == "mm/s" and b.y_unit == "mm"
    assert b.offset == pytest.approx(5.0, abs=1e-3)


def test_step_size_instead_of_a_command_column() -> None:
    t, u, y = velocity_step_record(0.7, 3)
    full = identify_step(t, u, y, model="sopdt")
    sized = identify_step(t, V, y, model="sopdt", step_time_s=0.05)
    for k in full.parameters:
        assert sized.parameters[k] == pytest.approx(full.parameters[k], rel=1e-8)
    # default step time: t = 0 when the record covers it
    shifted = identify_step(t - 0.05, V, y, model="sopdt")
    assert shifted.step_time_s == pytest.approx(0.0, abs=1e-12)
    assert shifted.parameters["delay_s"] == pytest.approx(full.parameters["delay_s"], rel=1e-8)
    # a position signal with a step size: the ramp a velocity step of that size commands
    n = 400
    tt = np.arange(n) * T
    pos = sopdt_step_position(tt, 0.05, V, W0, 0.7, TD)
    ident = identify_step(tt, V, pos, model="sopdt", signal="position", step_time_s=0.05)
    assert ident.parameters["omega0_rad_s"] == pytest.approx(W0, rel=1e-6)
    assert ident.parameters["delay_s"] == pytest.approx(TD, rel=1e-6)


def test_sopdt_with_the_profiles_position_loop() -> None:
    """A sopdt axis with position_gain_1_s in the profile: a position signal is fitted inside that loop."""
    prof = load_profile(CONFIGS / "example-mill.yaml")
    data = prof.to_dict()
    data["axes"]["x"]["drive"]["position_gain_1_s"] = 40.0
    from ilcnc.profile.load import profile_from_dict

    prof = profile_from_dict(data)
    drive = SopdtDrive(omega0_rad_s=150.0, zeta=0.9, gain=1.0, delay_s=0.002, position_gain_1_s=40.0)
    n = 600
    t = np.arange(n) * T
    r = np.where(np.arange(n) >= 30, 2.0, 0.0)
    y = axis_response(drive, r, T) + np.random.RandomState(5).normal(0, 0.0005, n)
    ident = identify_step(t, r, y, model="sopdt", signal="position", profile=prof, axis="x")
    assert ident.fixed == {"position_gain_1_s": 40.0}
    assert ident.parameters["omega0_rad_s"] == pytest.approx(150.0, rel=0.05)
    assert ident.parameters["zeta"] == pytest.approx(0.9, rel=0.05)
    upd = ident.profile_updates()["axes.x.drive"]
    assert upd["position_gain_1_s"] == 40.0  # type: ignore[index]


# --------------------------------------------------------------------------
# mass_damper and first_order_delay
# --------------------------------------------------------------------------


def test_mass_damper_recovers_seed000_x() -> None:
    """Seed 000's x axis (m = 0.45, c = 0.144) under its known PID from a 1 mm step.

    1 % noise, seeds 0–19: m within 0.73 %, c within 13.5 % (std 6.0 %; the
    reported standard error is 7.6 %). c is hard: only c + K_D = 8.144 shapes the
    response, so c carries 57× the relative error of that sum. Asserted: m 2 %,
    c 30 % (4σ); noise-free data: both 1e-6; 0.1 % noise: c within 3 %.
    """
    prof = load_profile(CONFIGS / "seed000-hendrawan-mass-damper-pid.yaml")
    drive = prof.axes["x"].drive
    assert isinstance(drive, MassDamperPidDrive)
    t = np.arange(0.0, 1.0, T)
    u = np.where(t >= 0.05 - 1e-12, 1.0, 0.0)
    y0 = axis_response(drive, u, T)
    exact = identify_step(t, u, y0, model="mass_damper", signal="position", profile=prof, axis="x")
    assert exact.parameters["mass_v_s2_mm"] == pytest.approx(0.45, rel=1e-6)
    assert exact.parameters["damping_v_s_mm"] == pytest.approx(0.144, rel=1e-6)
    assert exact.fixed == {"kp": 0.96, "ki": 0.01, "kd": 8.0}
    errs = []
    for seed in range(20):
        y = y0 + np.random.RandomState(seed).normal(0.0, 0.01, t.size)
        ident = identify_step(t, u, y, model="mass_damper", signal="position", profile=prof, axis="x")
        errs.append((ident.parameters["mass_v_s2_mm"] / 0.45 - 1, ident.parameters["damping_v_s_mm"] / 0.144 - 1))
    e = np.array(errs)
    print(f"\nmass_damper, 1 % noise: m max {np.max(np.abs(e[:, 0])) * 100:.2f} %, c max {np.max(np.abs(e[:, 1])) * 100:.1f} %"
          f" (std {np.std(e[:, 1]) * 100:.1f} %)")
    assert np.all(np.abs(e[:, 0]) < 0.02)
    assert np.all(np.abs(e[:, 1]) < 0.30)
    quiet = identify_step(t, u, y0 + np.random.RandomState(0).normal(0.0, 0.001, t.size), model="mass_damper",
                          profile=prof, axis="x", signal="position")
    assert quiet.parameters["damping_v_s_mm"] == pytest.approx(0.144, rel=0.03)
    # the profile update keeps the known PID and names the profile's model
    upd = quiet.profile_updates()["axes.x.drive"]
    assert upd["model"] == "mass_damper_pid" and upd["kd"] == 8.0  # type: ignore[index]


def test_mass_damper_needs_the_pid() -> None:
    t = np.arange(0.0, 0.5, T)
    u = np.where(t >= 0.05, 1.0, 0.0)
    y = axis_response(MassDamperPidDrive(0.45, 0.144, 0.96, 0.01, 8.0), u, T)
    with pytest.raises(InputError, match="mass_damper needs the known PID"):
        identify_step(t, u, y, model="mass_damper", signal="position")
    prof = load_profile(CONFIGS / "seed004-ward-sopdt.yaml")
    with pytest.raises(InputError, match="it is sopdt"):
        identify_step(t, u, y, model="mass_damper", signal="position", profile=prof, axis="x")
    ident = identify_step(t, u, y, model="mass_damper_pid", signal="position", pid=(0.96, 0.01, 8.0))
    assert ident.model == "mass_damper"
    assert ident.parameters["mass_v_s2_mm"] == pytest.approx(0.45, rel=1e-5)


def test_first_order_delay_recovered() -> None:
    drive = FirstOrderDelayDrive(time_constant_s=0.033, delay_s=0.0042, gain=1.0)
    t = np.arange(0.0, 0.5, T)
    u = np.where(t >= 0.05 - 1e-12, 1.0, 0.0)
    y0 = axis_response(drive, u, T)
    exact = identify_step(t, u, y0, model="first_order_delay", signal="position")
    assert exact.parameters == pytest.approx({"gain": 1.0, "time_constant_s": 0.033, "delay_s": 0.0042}, rel=1e-6)
    for seed in range(10):
        y = y0 + np.random.RandomState(seed).normal(0.0, 0.01, t.size)
        ident = identify_step(t, u, y, model="first_order_delay", signal="position")
        assert ident.parameters["gain"] == pytest.approx(1.0, abs=0.01)
        assert ident.parameters["time_constant_s"] == pytest.approx(0.033, rel=0.03)
        assert ident.parameters["delay_s"] == pytest.approx(0.0042, rel=0.2)
        assert abs(ident.parameters["delay_s"] - 0.0042) < 4.5 * ident.stderr["delay_s"]
    # a velocity signal: the same transfer function from commanded to actual velocity
    vel = identify_step(t, 10.0 * u, 10.0 * y0, model="first_order_delay", signal="velocity")
    assert vel.parameters["time_constant_s"] == pytest.approx(0.033, rel=1e-6)


# --------------------------------------------------------------------------
# Warnings and refusals
# --------------------------------------------------------------------------


def test_no_step_is_refused() -> None:
    t, u, y = velocity_step_record(0.7, 0)
    with pytest.raises(InputError, match="no step in the data: the command u does not change") as exc:
        identify_step(t, np.zeros_like(t), y, model="sopdt", source="run.csv")
    assert exc.value.file == "run.csv"
    flat = np.random.RandomState(1).normal(0.0, 0.01, t.size)
    with pytest.raises(InputError, match="does not follow the command"):
        identify_step(t, u, flat, model="sopdt")
    with pytest.raises(InputError, match="no step in the data"):
        identify_step(t, 0.0, y, model="sopdt")


def test_log_without_a_step_names_the_file() -> None:
    path = DATA / "no_step_x.csv"
    with pytest.raises(InputError) as exc:
        identify_file(path, axis="x", model="sopdt")
    assert str(exc.value) == f"{path}: no step in the data: the command x_ref does not change"
    ident = identify_file(path, axis="y", model="sopdt")  # Y does move
    assert ident.parameters["omega0_rad_s"] == pytest.approx(W0, rel=1e-3)


def test_warnings() -> None:
    t, u, y = velocity_step_record(0.7, 0)
    assert identify_step(t, u, y, model="sopdt").warnings == ()
    clipped = identify_step(t, u, np.minimum(y, V), model="sopdt")
    assert any(w.startswith("saturated: y sits exactly at its maximum") for w in clipped.warnings)
    short = identify_step(t[:90], u[:90], y[:90], model="sopdt")
    assert any(w.startswith("too short:") for w in short.warnings)
    t2, u2, noisy_y = velocity_step_record(0.7, 0, noise=0.1)
    noisy = identify_step(t2, u2, noisy_y, model="sopdt")
    assert any(w.startswith("noisy:") for w in noisy.warnings)
    assert any(w.startswith("poor fit:") and "too noisy" in w for w in noisy.warnings)
    wrong = identify_step(t, u, y, model="first_order_delay", signal="velocity")
    assert any(w.startswith(("systematic misfit:", "poor fit:")) for w in wrong.warnings)
    scaled = identify_step(t, u, 0.8 * y, model="sopdt")
    assert any(w.startswith("gain: K = 0.79") and "not 1 ± 5%" in w for w in scaled.warnings), scaled.warnings
    no_delay = identify_step(t, u, sopdt_step_velocity(t, 0.05, V, W0, 0.7, 0.0), model="sopdt")
    assert any(w.startswith("at bound: delay_s ended on its lower bound 0") for w in no_delay.warnings)


def test_bad_arguments() -> None:
    t, u, y = velocity_step_record(0.7, 0)
    with pytest.raises(ValueError, match="unknown model"):
        identify_step(t, u, y, model="pid")
    with pytest.raises(ValueError, match="unknown signal"):
        identify_step(t, u, y, model="sopdt", signal="torque")
    with pytest.raises(InputError, match="too few samples"):
        identify_step(t[:10], u[:10], y[:10], model="sopdt")
    with pytest.raises(InputError, match="time does not increase"):
        identify_step(t[::-1], u, y, model="sopdt")
    with pytest.raises(InputError, match="NaN"):
        identify_step(t, u, np.where(t > 0.2, np.nan, y), model="sopdt")


# --------------------------------------------------------------------------
# Files: step CSV, TNCscope, halsampler (LinuxCNC)
# --------------------------------------------------------------------------


def test_step_csv(tmp_path: Path) -> None:
    ident = identify_file(DATA / "step_velocity_seed004.csv", model="sopdt")
    assert ident.signal == "velocity"
    assert ident.parameters["gain"] == pytest.approx(1.0, abs=0.01)
    for k, v in {"omega0_rad_s": W0, "zeta": 1.0, "delay_s": TD}.items():
        assert abs(ident.parameters[k] - v) < 4.5 * ident.stderr[k]
    assert ident.source_sha256 is not None and len(ident.source_sha256) == 64
    # t_s,y only: the step size is given instead
    t, u, y = read_step_csv(DATA / "step_velocity_seed004.csv")
    assert u is not None
    p = tmp_path / "y_only.csv"
    p.write_text("t_s,y\n" + "".join(f"{a:.3f},{c:.6f}\n" for a, c in zip(t, y, strict=True)))
    with pytest.raises(InputError, match="no u column"):
        identify_file(p, model="sopdt")
    sized = identify_file(p, model="sopdt", step=V, step_time_s=0.05)
    assert sized.parameters["delay_s"] == pytest.approx(ident.parameters["delay_s"], rel=1e-6)
    both = identify_file(DATA / "step_velocity_seed004.csv", model="sopdt", step=V, step_time_s=0.05)
    assert both.warnings[0].startswith("input: the file's u column is ignored")
    # inch data are converted (the gain and the time constants do not change)
    pin = tmp_path / "inch.csv"
    pin.write_text("t_s,u,y\n" + "".join(f"{a:.3f},{b / 25.4:.9f},{c / 25.4:.9f}\n" for a, b, c in zip(t, u, y, strict=True)))
    inch = identify_file(pin, model="sopdt", units="inch")
    assert inch.parameters["omega0_rad_s"] == pytest.approx(ident.parameters["omega0_rad_s"], rel=1e-5)
    assert inch.fit_rms == pytest.approx(ident.fit_rms, rel=1e-3)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty step-response file"),
        ("t_s,u\n0,1\n", "lacks y"),
        ("t_s,u,y\n", "no samples"),
        ("t_s,u,y\n0,0,0\n0.001,1,x\n", r":3: 'x' is not a number"),
        ("t_s,u,y\n0,0,0\n0.001,1\n", r":3: expected 3 columns"),
        ("t_s,u,y\n0,0,0\n0,1,1\n", r":3: time does not increase"),
        ("# c\nt_s,u,y\n0,0,0\n0.001,1,nan\n", r":4: not a finite number"),
    ],
)
def test_step_csv_errors(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        read_step_csv(p)


def test_tncscope_export() -> None:
    """A TNCscope export (X from rest at 1000 mm/min on seed 004's drive, 0.1 µm resolution, 0.5 µm noise)."""
    ident = identify_file(DATA / "tncscope_x_sopdt.csv", axis="x", model="sopdt")
    assert ident.signal == "position"
    for k, v in {"gain": 1.0, "omega0_rad_s": W0, "zeta": 1.0, "delay_s": TD}.items():
        assert ident.parameters[k] == pytest.approx(v, rel=0.03), k
    assert ident.r2 > 0.9999
    assert ident.warnings == ()
    with pytest.raises(InputError, match="use the position signal"):
        identify_file(DATA / "tncscope_x_sopdt.csv", axis="x", model="sopdt", signal="velocity")
    with pytest.raises(InputError, match="say which one"):
        identify_file(DATA / "tncscope_x_sopdt.csv", model="sopdt")
    with pytest.raises(InputError, match="a step size applies to t_s,u,y files"):
        identify_file(DATA / "tncscope_x_sopdt.csv", axis="x", model="sopdt", step=V)

def test_log_without_the_axis(tmp_path: Path) -> None:
    p = tmp_path / "xy.csv"
    rows = "".join(f"{k * T:.3f},0,1,{k * 0.01:.4f},0,{k * 0.01:.4f},0\n" for k in range(100))
    p.write_text("t_s,k,line,x_ref,y_ref,x_act,y_act\n" + rows)
    with pytest.raises(InputError, match="the log has no z axis"):
        identify_file(p, axis="z", model="sopdt")
    with pytest.raises(InputError, match="unknown axis 'a'"):
        identify_file(p, axis="a", model="sopdt")


def test_halsampler_log_from_linuxcnc() -> None:
    """A step recorded on the LinuxCNC simulation (configs/linuxcnc-sim: P loop KV = 30 1/s, 5 ms velocity lag).

    ``G1 X60 F3000`` from rest (``linuxcnc_x_step.ngc``), raw halsampler output.
    A first-order lag with dead time describes the loop closely; T + Td is the
    loop's lag behind a ramp, 1/KV = 33.3 ms, within a sample or two.
    """
    ident = identify_file(DATA / "linuxcnc_x_step.hal.log", axis="x", model="first_order_delay")
    assert ident.r2 > 0.99999
    assert ident.fit_rms < 0.002  # mm, against a 1.67 mm following error
    assert ident.parameters["gain"] == pytest.approx(1.0, abs=1e-3)
    lag = ident.parameters["time_constant_s"] + ident.parameters["delay_s"]
    assert lag == pytest.approx(1.0 / 30.0, abs=0.002)
    assert ident.warnings == ()
    sop = identify_file(DATA / "linuxcnc_x_step.hal.log", axis="x", model="sopdt")
    assert sop.r2 > 0.99999 and sop.fit_rms < ident.fit_rms


# --------------------------------------------------------------------------
# Output: JSON, profile updates, notes, plots
# --------------------------------------------------------------------------


def test_json_object_is_designs() -> None:
    t, u, y = velocity_step_record(0.7, 0)
    ident = identify_step(t, u, y, model="sopdt", axis="x")
    obj = ident.to_json()
    assert list(obj) == ["axis", "model", "parameters", "stderr", "fit_rms", "r2", "warnings"]
    assert obj["axis"] == "x" and obj["model"] == "sopdt"
    assert list(obj["parameters"]) == ["gain", "omega0_rad_s", "zeta", "delay_s"]
    assert set(obj["stderr"]) == set(obj["parameters"])
    json.dumps(obj, allow_nan=False)
    full = ident.to_dict()
    json.dumps(full, allow_nan=False)
    lo, hi = full["ci95"]["zeta"]
    assert lo < ident.parameters["zeta"] < hi
    assert hi - lo == pytest.approx(2 * 1.96 * ident.stderr["zeta"], rel=0.01)
    rows = ident.parameter_rows()
    assert rows[1]["name"] == "omega0_rad_s" and rows[1]["unit"] == "rad/s"


def test_profile_updates_normalise_the_gain() -> None:
    t, u, y = velocity_step_record(0.7, 0)
    near = identify_step(t, u, 0.98 * y, model="sopdt", axis="y")
    assert near.parameters["gain"] == pytest.approx(0.98, abs=0.005)
    upd = near.profile_updates()
    assert list(upd) == ["axes.y.drive"]
    drive = upd["axes.y.drive"]
    assert drive["model"] == "sopdt" and drive["gain"] == 1.0  # type: ignore[index]
    assert drive["omega0_rad_s"] == float(f"{near.parameters['omega0_rad_s']:.5g}")  # type: ignore[index]
    assert "written as 1" in near.profile_note("2026-01-02")
    far = identify_step(t, u, (1 - 2 * GAIN_TOLERANCE) * y, model="sopdt", axis="x")
    assert far.profile_updates()["axes.x.drive"]["gain"] == pytest.approx(0.9, abs=0.005)  # type: ignore[index]
    with pytest.raises(ValueError, match="needs the axis"):
        identify_step(t, u, y, model="sopdt").profile_updates()


def test_write_profile_keeps_comments_and_other_axes(tmp_path: Path) -> None:
    prof_path = tmp_path / "seed004.yaml"
    shutil.copy(CONFIGS / "seed004-ward-sopdt.yaml", prof_path)
    before = prof_path.read_text()
    ident = identify_file(DATA / "step_velocity_seed004.csv", model="sopdt", axis="y")
    ident.write_profile(prof_path, date="2026-05-01")
    after = prof_path.read_text()
    prof = load_profile(prof_path)
    assert prof.axes["x"].drive == SopdtDrive(omega0_rad_s=95.6, zeta=1.0, gain=1.0, delay_s=0.0066)
    y = prof.axes["y"].drive
    assert isinstance(y, SopdtDrive)
    assert y.omega0_rad_s == float(f"{ident.parameters['omega0_rad_s']:.5g}") and y.gain == 1.0
    assert "# ilcnc: identified 2026-05-01 by ilcnc identify from step_velocity_seed004.csv (sha256 " in after
    assert "# ilcnc alias: was *sopdt_seed004" in after
    # every original comment line is still there
    for line in before.splitlines():
        if line.strip().startswith("#"):
            assert line in after
    # the data file is never written over
    with pytest.raises(InputError, match="refusing to write over an input file"):
        ident.write_profile(prof_path, out=DATA / "step_velocity_seed004.csv")


def test_write_profile_refuses_an_invalid_result(tmp_path: Path) -> None:
    prof_path = tmp_path / "seed000.yaml"
    shutil.copy(CONFIGS / "seed000-hendrawan-mass-damper-pid.yaml", prof_path)
    raw = prof_path.read_bytes()
    t, u, y = velocity_step_record(0.7, 0)
    ident = identify_step(t, u, y, model="sopdt", axis="x")
    bad = Identification(**{**ident.__dict__, "parameters": {**ident.parameters, "zeta": 25.0}})
    with pytest.raises(ProfileError, match=r"axes\.x\.drive\.zeta: must be > 0 and <= 10"):
        bad.write_profile(prof_path)
    assert prof_path.read_bytes() == raw


def test_plot(tmp_path: Path) -> None:
    ident = identify_file(DATA / "linuxcnc_x_step.hal.log", axis="x", model="first_order_delay")
    out = ident.plot(tmp_path / "fit.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = ident.plot(tmp_path / "fit.svg")
    assert b"<svg" in svg.read_bytes()[:2000]
    with pytest.raises(InputError, match="refusing to write over an input file"):
        ident.plot(DATA / "linuxcnc_x_step.hal.log")
