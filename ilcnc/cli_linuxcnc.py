"""``ilcnc linuxcnc``: run programs on LinuxCNC headless and log them, a profile from a machine's INI, what a log
run needs (docs/linuxcnc.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from ilcnc.cli_options import DebugOption, IlcncApp
from ilcnc.cli_output import console as _console
from ilcnc.cli_output import fail as _fail
from ilcnc.cli_output import table as _table
from ilcnc.errors import IlcncError, UsageError
from ilcnc.wording import plural

__all__ = ["linuxcnc_app"]

linuxcnc_app = IlcncApp(help="Run programs on LinuxCNC's own motion controller (headless) and log them.",
                           no_args_is_help=True)


@linuxcnc_app.command("run")
def linuxcnc_run(
    program: Annotated[Path, typer.Argument(help="G-code program (RS-274NGC) to run.")],
    log_out: Annotated[Path, typer.Option("--log-out", help="Axis log to write (ilcnc CSV: t_s,k,line,x_ref,...,z_act);"
                                              " formerly --log.")],
    config: Annotated[
        Path | None, typer.Option("--config", help="LinuxCNC configuration folder or INI (default: configs/linuxcnc-sim).")
    ] = None,
    raw: Annotated[Path | None, typer.Option("--raw", help="Also keep the raw halsampler output here.")] = None,
    time_scale: Annotated[int, typer.Option("--time-scale", min=1, max=8, help="Run k times faster (same log).")] = 1,
    settle_s: Annotated[float, typer.Option("--settle", min=0.0, max=10.0, help="Log this long after motion ends, s.")] = 0.2,
    timeout_s: Annotated[float, typer.Option(
        "--timeout", min=1.0, help="Limit of the program's run, s of machine time (at --time-scale k: this / k of wall time)."
    )] = 600.0,
    lock_timeout_s: Annotated[float, typer.Option(
        "--lock-timeout", min=0.0,
        help="How long to wait for the machine, s, while another run holds ilcnc's LinuxCNC lock or a LinuxCNC"
             " not started by ilcnc is running (0: do not wait). Says on stderr whom it waits for.",
    )] = 600.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Run PROGRAM on LinuxCNC headlessly and write its axis log (commanded and actual, per servo cycle).

    The log (--log-out LOG) feeds `ilcnc learn PROGRAM --log LOG`. Runs are serialised by a
    machine-wide lock (LinuxCNC is one instance per machine): a run that has
    to wait prints on stderr who holds it (pid, user, program, since when) and
    waits up to --lock-timeout, then fails naming the holder. A LinuxCNC not
    started by ilcnc is waited for the same way, never stopped. The leftovers
    of a crashed run are cleaned up.
    """
    from ilcnc.shop.linuxcnc import record_run

    try:
        res = record_run(program, config, log_out, raw, time_scale=time_scale, settle_s=settle_s, timeout_s=timeout_s,
                         lock_timeout_s=lock_timeout_s, on_wait=lambda line: typer.echo(line, err=True))
        alog = res.log
    except IlcncError as exc:
        _fail(exc)
    info = {"program": str(program), "log": str(log_out), "samples": alog.n_samples, "program_s": res.program_s,
            "time_scale": res.time_scale, "wall_s": res.wall_s, "messages": res.messages}
    if as_json:
        typer.echo(json.dumps(info))
        return
    typer.echo(f"ran {program.name} on LinuxCNC: {res.program_s:.2f} s of motion at time scale {res.time_scale} "
               f"in {res.wall_s:.1f} s; wrote {log_out} ({plural(alog.n_samples, 'sample')})")
    for m in res.messages:
        typer.echo(f"LinuxCNC: {m}")


@linuxcnc_app.command("profile")
def linuxcnc_profile(
    ini: Annotated[Path, typer.Argument(help="The machine's LinuxCNC INI (its HAL files are read too).")],
    out: Annotated[Path | None, typer.Option("--out", help="Profile YAML to write (default: print it).")] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --out file.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object (with the profile text).")] = False,
    debug: DebugOption = False,
) -> None:
    """Write a machine profile from a LinuxCNC INI: units, limits, servo period, path control, drives.

    Every value carries a comment naming its INI key or HAL line; values the configuration cannot give are
    ilcnc defaults, marked 'not from the INI' with what to measure (docs/linuxcnc.md 3).
    """
    from ilcnc.shop.linuxcnc_profile import profile_from_ini, write_ini_profile

    try:
        res = profile_from_ini(ini)
        if out is not None:
            write_ini_profile(res, out, force=force)
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps({**res.to_json(), "out": str(out) if out else None, "text": res.text}))
        return
    if out is None:
        typer.echo(res.text, nl=False)
        return
    typer.echo(f"wrote {out} from {ini.name}: {res.units}, servo period {res.servo_period_s * 1e3:g} ms,"
               f" path control {res.path_control} (corner tolerance {res.corner_tolerance_mm:g} mm)")
    t = _table("axes")
    for col in ("axis", "joints", "velocity mm/min", "accel m/s²", "drive"):
        t.add_column(col, overflow="fold")
    for a in res.axes:
        t.add_row(a.name, " ".join(map(str, a.joints)) or "-", f"{a.max_velocity_mm_s * 60:g}",
                  f"{a.max_acceleration_mm_s2 / 1000:g}", str(a.drive))
    _console().print(t)
    typer.echo("not from the INI (measure or set by hand): " + ", ".join(res.defaults))
    for n in res.notes:
        typer.echo(f"note: {n}")


@linuxcnc_app.command("prepare")
def linuxcnc_prepare(
    program: Annotated[Path, typer.Argument(help="The G-code program to run on the machine.")],
    profile: Annotated[Path, typer.Option("--profile", help="The machine's profile (corner tolerance, units).")],
    ini: Annotated[Path | None, typer.Option("--ini", help="The machine's INI: joints, start-up path control,"
                                             " servo period and log units from it.")] = None,
    write_hal: Annotated[Path | None, typer.Option("--write-hal", help="Write the HAL lines to this file.")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write the program with the path-control edits made"
                                             " (each marked '(ilcnc prepare)'): run, log and learn that one.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --write-hal or --out file.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Say what a log run of PROGRAM on a LinuxCNC machine needs, before the run.

    The path control per line range and the edits that keep corners within the profile's tolerance (G64 P Q0),
    the HAL lines that record the axes with halsampler, and the commands that record and learn. With --out, the
    program with those edits made; nothing else of it changes.
    """
    from ilcnc.fileio import same_file, write_atomic
    from ilcnc.shop.linuxcnc_prepare import prepare_run
    from ilcnc.shop.path_control_edit import ready_program_text

    inputs = (program, profile, *((ini,) if ini else ()))
    try:
        for opt, dest in (("--write-hal", write_hal), ("--out", out)):
            if dest is not None and any(same_file(dest, p) for p in inputs if p.exists()):
                raise UsageError(opt, f"{dest} is an input of this command: choose another file")
            if dest is not None and dest.exists() and not force:
                raise UsageError(opt, f"{dest} exists: choose another file or replace it with --force")
        res = prepare_run(program, profile, ini_path=ini, run_path=out)
        if write_hal is not None:
            write_atomic(write_hal, res.hal, protect=inputs)
        if out is not None:
            write_atomic(out, ready_program_text(res.source, res.edits).encode("latin-1"), protect=inputs)
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps({**res.to_json(), "hal_file": str(write_hal) if write_hal else None,
                               "out": str(out) if out else None}))
        return
    typer.echo(res.text(write_hal), nl=False)
    if out is not None:
        typer.echo(f"wrote {out}: {len(res.edits)} path-control edit{'s' if len(res.edits) != 1 else ''} made"
                   + (" (run, log and learn this program)" if res.edits else " (none needed: a copy)"))
