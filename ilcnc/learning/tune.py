"""What ``ilcnc tune`` calls: learning gains that provably converge, from the profile's drive models.

Three methods, one per learning law of the profile: ``time`` (:mod:`ilcnc.learning.time_design`, seed 000),
``lifted`` (:mod:`ilcnc.learning.lifted_check`, seed 004) and ``schedule`` (:mod:`ilcnc.learning.gain_schedule`,
seed 001); each module's docstring gives its arithmetic.

:func:`tune_profile` is what ``ilcnc tune`` calls: it picks the method from
the profile's law, runs it and, with ``write=True``, stores the gains in the
profile with :func:`ilcnc.profile.edit.update_profile` (comments kept).

All functions take and return numpy arrays and explicit result dataclasses;
nothing here prints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike

from ilcnc.learning.gain_schedule import ScheduleResult, schedule_gains
from ilcnc.learning.lifted_check import DEFAULT_MAX_COMMANDS, LiftedCheck, check_lifted
from ilcnc.learning.time_design import DEFAULT_F_MAX_HZ, TuneResult, design_time_domain
from ilcnc.profile.sections import MachineProfile

__all__ = ["METHODS", "TuneReport", "tune_profile"]

# ---------------------------------------------------------------------------------------------
# What `ilcnc tune` calls
# ---------------------------------------------------------------------------------------------

#: Methods of :func:`tune_profile`.
METHODS = ("auto", "time", "lifted", "schedule")


def _sig(v: float, digits: int = 6) -> float:
    """``v`` rounded to ``digits`` significant digits (what is written into the profile)."""
    return float(f"{v:.{digits}g}")


def _fmt(v: float | None, spec: str = ".4g") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "∞" if v is not None and v > 0 else "–"
    return format(v, spec)


@dataclass(eq=False)
class TuneReport:
    """What ``ilcnc tune`` prints and writes.

    Attributes
    ----------
    method : str
        ``time``, ``lifted`` or ``schedule`` (``auto`` resolved).
    profile_path : Path
    program_path : Path or None
    result : TuneResult, LiftedCheck or ScheduleResult
    updates : dict
        Dotted profile keys and the values ``--write`` stores (empty for a schedule
        or when nothing converged).
    written : Path or None
        The profile written (``write=True`` and something to write).
    schedule_csv : Path or None
        The schedule CSV written (method ``schedule`` with ``write=True``).
    note : str
        One line: what was (not) written and why.
    """

    method: str
    profile_path: Path
    program_path: Path | None
    result: Any
    updates: dict[str, Any] = field(default_factory=dict)
    written: Path | None = None
    schedule_csv: Path | None = None
    note: str = ""

    @property
    def converges(self) -> bool | None:
        r = self.result
        if isinstance(r, TuneResult):
            return r.converges
        if isinstance(r, LiftedCheck):
            return r.converges
        return None

    def to_json(self) -> dict[str, Any]:
        """DESIGN.md's ``tune --json`` object plus the method's details.

        ``{"axes": {axis: {"law", "gains", "epsilon", "peak_hz", "converges", ...}}, "method", "profile",
        "program", "updates", "written", "schedule_csv", "note", ...}``. For ``time`` ``epsilon`` is ε on the
        band and ``peak_hz`` where it peaks; for ``lifted`` (law ``p``, the same entry for every axis: G couples
        them) ``epsilon`` is ``‖(I − GQΓ)B‖₂`` and ``peak_hz`` is null, details under ``"lifted"``; for
        ``schedule`` they are null and the figures are under ``"schedule"``. inf/NaN are written as null.
        """
        out = self.result.to_json()
        out.update({"method": self.method, "profile": str(self.profile_path),
                    "program": str(self.program_path) if self.program_path else None,
                    "updates": {k: v for k, v in self.updates.items()},
                    "written": str(self.written) if self.written else None,
                    "schedule_csv": str(self.schedule_csv) if self.schedule_csv else None, "note": self.note})
        return out

    def columns(self) -> tuple[str, ...]:
        """Header of :meth:`rows`."""
        if self.method == "time":
            return ("axis", "law", "K_Pl", "K_Il 1/s", "K_Dl s", "lead η", "ε", "peak Hz", "converges", "note")
        if self.method == "lifted":
            return ("Γ", "Q-filter Hz", "‖(I−GQΓ)B‖₂", "ρ", "ρ inner", "‖E₁‖/‖E₀‖", "‖Eₙ‖/‖E₀‖", "status", "")
        return ("axis", "K_p fixed", "K_p min", "K_p mean", "K_p max", "MSE before µm²", "MSE after µm²", "cut")

    def rows(self) -> list[tuple[str, ...]]:
        """Rows of strings for a table (``rich.table.Table(*report.columns())``)."""
        r = self.result
        if isinstance(r, TuneResult):
            out = []
            for a in r.axes.values():
                note = a.reason or "; ".join(a.notes)
                out.append((a.axis, "pid_ace", _fmt(a.kp), _fmt(a.ki), _fmt(a.kd), str(a.lead_samples),
                            _fmt(a.epsilon), _fmt(a.peak_hz), "yes" if a.converges else "NO", note))
            return out
        if isinstance(r, LiftedCheck):
            out = []
            for c in r.candidates:
                out.append((_fmt(c.gamma), "none" if c.q_filter_hz is None else _fmt(c.q_filter_hz), _fmt(c.norm, ".5f"),
                            _fmt(c.spectral_radius, ".6f"), _fmt(c.spectral_radius_inner, ".6f"),
                            _fmt(c.predicted_ratio, ".3f"), _fmt(c.predicted_ratio_n, ".3f"),
                            c.status, "← chosen" if c is r.chosen else ""))
            return out
        s: ScheduleResult = r
        return [(s.axis, _fmt(s.kp_fixed), _fmt(float(s.kp.min())), _fmt(float(s.kp.mean())), _fmt(float(s.kp.max())),
                 _fmt(s.mse_before_um2), _fmt(s.mse_after_um2), f"{s.reduction:.1%}")]


def _time_updates(res: TuneResult, profile: MachineProfile) -> dict[str, Any]:
    kp = {a: _sig(d.kp) for a, d in res.axes.items()}
    kd = {a: _sig(d.kd) for a, d in res.axes.items()}
    ki: Any = {a: _sig(d.ki) for a, d in res.axes.items()} if res.ki_mode == "free" else 0.0
    if profile.learning.law == "pid_ace":
        return {"learning.gains.kp": kp, "learning.gains.ki": ki, "learning.gains.kd": kd,
                "learning.gains.lead_samples": int(res.lead_samples)}
    return {"learning.law": "pid_ace",
            "learning.gains": {"kp": kp, "ki": ki, "kd": kd, "lead_samples": int(res.lead_samples)}}


def tune_profile(profile_path: str | Path, *, method: str = "auto", program: Any = None, write: bool = False,
                 out: str | Path | None = None, f_min_hz: float = 0.0, f_max_hz: float = DEFAULT_F_MAX_HZ,
                 lead_max: int = 3, fix_ki: bool = True, gamma: float | None = None, q_filter_hz: float | None = None,
                 commands: tuple[int, int] | None = None, max_commands: int = DEFAULT_MAX_COMMANDS,
                 axis: str | None = None, kp_range: tuple[float, float] | None = None, horizon: int | None = None,
                 lam: float | None = None, dk: ArrayLike | None = None, kinematics: str | None = None,
                 schedule_csv: str | Path | None = None) -> TuneReport:
    """Design or check the learning gains of a profile (``ilcnc tune``).

    Parameters
    ----------
    profile_path : str or Path
        The profile YAML.
    method : {"auto", "time", "lifted", "schedule"}
        ``auto``: ``time`` for ``learning.law: pid_ace``, ``lifted`` for ``p``
        (needs ``program``). ``schedule`` needs ``program``.
    program : str, Path or Program, optional
        The part program (``lifted``, ``schedule``).
    write : bool
        Store the result: the gains with :func:`ilcnc.profile.edit.update_profile`
        (comments kept) -- ``learning.gains.kp/ki/kd/lead_samples`` per axis
        (``time``; the law is set to ``pid_ace`` if it was another), or
        ``learning.gains.gamma`` and ``learning.q_filter_hz`` (``lifted``);
        only gains that converge are written. ``schedule`` writes the CSV
        ``t_s,kp`` instead (``schedule_csv``, default next to the program:
        ``<stem>.kp-<axis>.csv``).
    out : str or Path, optional
        Write the profile here instead of in place.
    f_min_hz, f_max_hz, lead_max, fix_ki :
        See :func:`design_time_domain`.
    gamma, q_filter_hz, commands, max_commands :
        See :func:`check_lifted`.
    axis, kp_range, horizon, lam, dk, kinematics :
        See :func:`schedule_gains`; ``None`` (the default): the profile's ``tuning.schedule`` values.
    schedule_csv : str or Path, optional
        Where ``write=True`` puts the schedule.

    Returns
    -------
    TuneReport

    Raises
    ------
    ValueError
        Unknown method, or a method that needs a program without one, or a law
        there is no method for (``second_order``: its condition (3) is checked
        by ``learn``).
    ProfileError, InputError
        From reading the profile or the program, or from writing.
    """
    from ilcnc.profile.load import load_profile

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    ppath = Path(profile_path)
    profile = load_profile(ppath)
    prog = None
    prog_path: Path | None = None
    if program is not None:
        if isinstance(program, (str, Path)):
            from ilcnc.program import read_program

            prog_path = Path(program)
            prog = read_program(prog_path, default_units=profile.machine.units)
        else:
            prog = program
            prog_path = Path(prog.path) if getattr(prog, "path", None) else None
    m = method
    if m == "auto":
        law = profile.learning.law
        if law == "pid_ace":
            m = "time"
        elif law == "p":
            m = "lifted"
        else:
            raise ValueError(f"learning.law {law}: tune has no method for it (its condition (3) is checked by learn);"
                             " use --method time to design a pid_ace law instead")
    if m in ("lifted", "schedule") and prog is None:
        raise ValueError(f"method {m} needs a part program (the lifted map and the schedule are per program)")
    report = TuneReport(m, ppath, prog_path, None)
    if m == "time":
        res = design_time_domain(profile, f_min_hz=f_min_hz, f_max_hz=f_max_hz, lead_max=lead_max, fix_ki=fix_ki)
        report.result = res
        if res.converges:
            report.updates = _time_updates(res, profile)
            eps = ", ".join(f"{a} {d.epsilon:.3g}" for a, d in res.axes.items())
            note = f"tune: time domain {res.f_min_hz:g}-{res.f_max_hz:g} Hz, lead {res.lead_samples}, eps {eps}"
        else:
            bad = ", ".join(a for a, d in res.axes.items() if not d.converges)
            report.note = f"not written: no convergent gains on axis {bad}"
    elif m == "lifted":
        chk = check_lifted(prog, profile, gamma=gamma, q_filter_hz=q_filter_hz, commands=commands,
                           max_commands=max_commands)
        report.result = chk
        c = chk.chosen
        if chk.converges:
            report.updates = {"learning.gains.gamma": _sig(c.gamma), "learning.q_filter_hz": c.q_filter_hz}
            name = prog_path.name if prog_path else "the program"
            note = (f"tune: lifted map of {name} (commands {chk.model.window[0]}-{chk.model.window[1] - 1}),"
                    f" {c.status}, norm {c.norm:.4g}, spectral radius {c.spectral_radius:.6f}")
        else:
            report.note = f"not written: {chk.reason}"
    else:
        sch = schedule_gains(prog, profile, axis=axis, kp_range=kp_range, horizon=horizon, lam=lam, dk=dk,
                             kinematics=kinematics)
        report.result = sch
        notes = []
        if sch.baseline_scan:
            n_ok = sum(ok for _k, _m, ok in sch.baseline_scan)
            notes.append(f"C1: K_p {sch.kp_fixed:g}, the best of {len(sch.baseline_scan)} fixed gains ({n_ok} keep every"
                         " axis within its V, A, J limits)")
        if not sch.within_limits_after:
            notes.append("C2 takes an axis beyond its V, A, J limits")
        if write:
            if schedule_csv is None:
                base = prog_path if prog_path is not None else Path("program")
                schedule_csv = base.with_name(f"{base.stem}.kp-{sch.axis}.csv")
            protect = [ppath] + ([prog_path] if prog_path else [])
            report.schedule_csv = sch.write_csv(schedule_csv, protect=protect)
            notes.insert(0, f"schedule written to {report.schedule_csv}")
        report.note = "; ".join(notes)
        return report
    if write and report.updates:
        from ilcnc.profile.edit import update_profile

        protect = [prog_path] if prog_path else []
        report.written = update_profile(ppath, report.updates, out=out, note=note, protect=protect)
        report.note = f"written to {report.written}"
    elif report.updates and not report.note:
        report.note = "not written (use --write)"
    return report
