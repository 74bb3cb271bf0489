"""Command line: thin typer commands that parse options, call the library and print.

Exit codes: 0 success, 1 bad input (one line naming file, line and problem),
2 bad usage; ``check`` over many programs also 3 for a program it cannot read
(its --help). ``--debug`` shows the traceback of an error.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated

import typer

from ilcnc import __version__
from ilcnc.cli_linuxcnc import linuxcnc_app
from ilcnc.cli_options import DebugOption, IlcncApp, debug_on, set_debug
from ilcnc.cli_output import console as _console
from ilcnc.cli_output import fail as _fail
from ilcnc.cli_output import finite as _finite
from ilcnc.cli_output import table as _table
from ilcnc.errors import IlcncError, InputError, UsageError
from ilcnc.units import AXIS_NAMES, LENGTH_UNITS
from ilcnc.wording import plural

app = IlcncApp(
    no_args_is_help=True,
    help="ilcnc: make CNC machines cut what was programmed (iterative learning control on G01 end points).",
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"ilcnc {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")] = False,
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks of errors.")] = False,
) -> None:
    set_debug(debug)


#: Help of ``--log-columns`` (learn, simulate --compare).
_LOG_COLUMNS_HELP = ("what each column of a halsampler log holds, in file order: names from n line x_ref y_ref z_ref"
                     " x_act y_act z_act, '-' for a column to skip (default: the ilcnc simulation's"
                     " 'n line x_ref y_ref z_ref x_act y_act z_act'; docs/linuxcnc.md).")


#: Help of ``--log-offset`` (learn, simulate --compare).
_LOG_OFFSET_HELP = ("work offset 'X,Y,Z' subtracted from the log's commanded and actual positions, in --log-units:"
                    " a log of machine coordinates brought into the program's (active G5x + G92 + tool length offset;"
                    " docs/linuxcnc.md 5.3).")


def _parse_offset(text: str | None) -> tuple[float, float, float] | None:
    """``--log-offset 'X,Y,Z'`` as three floats (a usage error, exit 2, names the option)."""
    if text is None:
        return None
    parts = [t for t in text.replace(",", " ").split() if t]
    try:
        vals = tuple(float(t) for t in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        typer.echo(f"error: --log-offset must be three numbers X,Y,Z (e.g. 100,50,-20), got {text!r}", err=True)
        raise typer.Exit(2)
    return vals  # type: ignore[return-value]


@app.command()
def inspect(
    program: Annotated[Path, typer.Argument(help="Part program (.nc/.ngc/.tap/.gcode or Heidenhain .h).")],
    moves: Annotated[Path | None, typer.Option("--moves", help="Write the command table k,line,x,y,z,f (mm, mm/min).")] = None,
    profile: Annotated[Path | None, typer.Option("--profile", help="Machine profile YAML (units, rapid speed).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Dialect, units, lines, G01 commands, extents, path length and cycle time of a program."""
    from ilcnc.shop import inspect as inspect_mod
    try:
        report = inspect_mod.inspect_program(program, profile_path=profile, moves_out=moves)
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps(report.to_json()))
        return
    inspect_mod.print_report(report, _console())


@app.command()
def export(
    program: Annotated[Path, typer.Argument(help="Part program to write out.")],
    out: Annotated[Path, typer.Option("--out", help="Output file; its suffix picks the dialect (.nc .ngc .tap .gcode .h).")],
    corrections: Annotated[Path | None, typer.Option("--corrections", help="Corrections CSV k,dx,dy,dz (mm).")] = None,
    profile: Annotated[Path | None, typer.Option("--profile", help="Machine profile (resolution, default units).")] = None,
    decimals: Annotated[int | None, typer.Option("--decimals", min=0, max=8, help="Least decimals of rewritten numbers.")] = None,
    state: Annotated[
        Path | None, typer.Option("--state", help="Learning state of PROGRAM: write the program of one of its iterations.")
    ] = None,
    iteration: Annotated[
        int | None, typer.Option("--iteration", min=0, help="With --state: which iteration (default: the run's output).")
    ] = None,
    debug: DebugOption = False,
) -> None:
    """Write the program (optionally corrected) in the dialect of OUT's suffix.

    With no corrections and the same dialect the output is byte-identical to the input; with --state, the
    program of an iteration of the run, byte for byte as the run wrote it (refined lines included).
    """
    from ilcnc.shop import export as export_mod
    try:
        if state is not None:
            if corrections is not None:
                raise InputError(corrections, None, "--corrections and --state: the state holds each iteration's"
                                 " corrections already; give one of them")
            result = export_mod.export_iteration(program, out, state, iteration=iteration, profile_path=profile)
        elif iteration is not None:
            raise InputError(None, None, "--iteration needs --state")
        else:
            result = export_mod.export_program(program, out, corrections_path=corrections, profile_path=profile,
                                               min_decimals=decimals)
    except IlcncError as exc:
        _fail(exc)
    if result.note:
        typer.echo(f"note: {result.note}", err=True)
    typer.echo(f"wrote {result.path} ({result.mode}; {plural(result.changed_commands, 'command')} corrected, "
               f"{plural(result.edits, 'number')} rewritten)")


@app.command()
def diff(
    original: Annotated[Path, typer.Argument(help="The original part program.")],
    output: Annotated[Path, typer.Argument(help="An ilcnc output of it (learn --out, export --corrections).")],
    profile: Annotated[
        Path | None, typer.Option("--profile", help="Machine profile (units of a G-code program without G20/G21).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object (numbers in full).")] = False,
    debug: DebugOption = False,
) -> None:
    """List what OUTPUT changed in ORIGINAL: each changed line with its end point's correction in µm (ΔX ΔY ΔZ,
    output minus original, as the interpreter reads both) and the coordinate, arc centre and feed words that
    changed; the lines refinement inserted; a summary.

    Lines are matched through the program model (inserted lines by their 'ilcnc refine' marker, Klartext
    block numbers renumbered by refinement are no change). Anything changed besides coordinate numbers, arc
    centres, feeds and marked inserted lines breaks ilcnc's rewriting contract and is printed after a line
    starting CONTRACT BREACH. Exit 0 when the diff was computed (also with a breach), 1 for a program that
    cannot be read, 2 for bad usage.
    """
    from ilcnc.shop import diff as diff_mod

    try:
        units = "mm"
        if profile is not None:
            from ilcnc.profile.load import load_profile

            units = load_profile(profile).machine.units
        result = diff_mod.diff_files(original, output, default_units=units)
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps(result.to_json()))
        return
    typer.echo("\n".join(diff_mod.format_diff(result)))


_CUTTING_BELOW_Z_HELP = ("Stock top, mm in program coordinates: feed moves entirely above it are air moves, reported"
                         " apart and not corrected (default: the profile's cutting.top_z_mm, else work Z0 where the"
                         " program cuts below it).")


_CORNERS_HELP = ("List the N cutting corners with the largest error, each split into the planner's rounding"
                 " (within the program's G64 P / cycle 32 or the profile's tolerance) and the drives' lag; 0: none.")
_SIM_CORNERS = (" simulate: off by default (it plans the drawing twice more: Gates_combined_R12 2.4 s instead of"
                 " 1.3 s); 5 with --target-um or --tighter-out.")
_TARGET_UM_HELP = ("With --corners: the rounding (µm) a tighter G64 P / cycle 32 should bound the corners that are"
                   " mostly rounding to (default: half their tolerance); its cycle time is planned.")


@app.command()
def simulate(
    program: Annotated[Path, typer.Argument(help="Part program to run on the virtual CNC.")],
    profile: Annotated[Path, typer.Option("--profile", help="Machine profile YAML (limits, planner, drives).")],
    log_out: Annotated[
        Path | None, typer.Option("--log-out", help="Write the axis log CSV (t_s,k,line,x_ref,...,z_act); formerly --out.")
    ] = None,
    against: Annotated[
        Path | None, typer.Option("--against", help="Measure the contour error against this program's path.")
    ] = None,
    schedule: Annotated[
        Path | None, typer.Option("--schedule", help="Gain schedule CSV t_s,kp ((m/min)/mm) from `ilcnc tune --method"
                                  " schedule`, applied to --schedule-axis.")
    ] = None,
    schedule_axis: Annotated[str, typer.Option("--schedule-axis", help="Axis the schedule drives (x, y or z).")] = "z",
    compare: Annotated[
        Path | None, typer.Option("--compare", help="Axis log of the machine running PROGRAM: report how well the"
                                  " virtual CNC predicts it (per-command error correlation and difference).")
    ] = None,
    log_format: Annotated[
        str, typer.Option("--log-format", help="Format of --compare: auto, ilcnc, halsampler or tncscope.")
    ] = "auto",
    log_units: Annotated[str, typer.Option("--log-units", help="Unit of --compare's positions: mm or inch.")] = "mm",
    log_columns: Annotated[str | None, typer.Option("--log-columns", help="With --compare: " + _LOG_COLUMNS_HELP)] = None,
    log_offset: Annotated[str | None, typer.Option("--log-offset", help="With --compare: " + _LOG_OFFSET_HELP)] = None,
    cutting_below_z: Annotated[float | None, typer.Option("--cutting-below-z", help=_CUTTING_BELOW_Z_HELP)] = None,
    corners: Annotated[int | None, typer.Option("--corners", min=0, max=100, help=_CORNERS_HELP + _SIM_CORNERS)] = None,
    target_um: Annotated[float | None, typer.Option("--target-um", help=_TARGET_UM_HELP)] = None,
    tighter_out: Annotated[
        Path | None, typer.Option("--tighter-out", help="Write PROGRAM with the suggested G64 P before those corners'"
                                  " lines and its own path control after them (LinuxCNC G-code; lines marked"
                                  " '(ilcnc tighter ...)').")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Run PROGRAM on the virtual CNC: planned reference, drive models, contour error."""
    from ilcnc.profile.load import load_profile
    from ilcnc.program import read_program
    from ilcnc.vcnc import simulate as sim_mod

    if compare is not None:
        bad = [o for o, v in (("--log-out", log_out), ("--against", against), ("--schedule", schedule),
                              ("--tighter-out", tighter_out)) if v is not None]
        if bad:
            _fail(UsageError("--compare", f"judges the virtual CNC on PROGRAM as it is: it does not go with {bad[0]}"))
        _compare(program, profile, compare, log_format, log_units, log_columns, _parse_offset(log_offset), as_json)
        return
    try:
        _finite("--target-um", target_um, lo=0.0, open_lo=True, hi=10000.0, unit="µm")
        prof = load_profile(profile).with_cutting_top(cutting_below_z)
        prog = read_program(program, default_units=prof.machine.units)
        orig = read_program(against, default_units=prof.machine.units) if against is not None else None
        console = _console()
        if corners is None:  # off unless a tighter tolerance is asked for: it plans the drawing twice more
            corners = 5 if (tighter_out is not None or target_um is not None) else 0
        vm = _vertices(orig or prog, corners)
        gains = None
        if schedule is not None:
            from ilcnc.vcnc.schedule import read_schedule

            if schedule_axis not in prof.axes:
                raise InputError(schedule, None, f"--schedule-axis {schedule_axis!r} is not an axis of the profile"
                                                 f" ({', '.join(prof.axes)})")
            gains = {schedule_axis: read_schedule(schedule)}
        if gains is not None:
            result = sim_mod.simulate_program(prog, prof, against=orig, gain_schedule=gains, vertices=vm)
        elif as_json:
            result = _simulate(prog, prof, orig, log_out is not None, vertices=vm)
        else:
            result = _simulate_with_progress(prog, prof, orig, console, log_out is not None, vertices=vm)
        if log_out is not None:
            from ilcnc.axislog.log import write_axis_log

            protect = (program, profile) + ((against,) if against is not None else ())
            write_axis_log(log_out, result.axis_log(), protect=protect)
        rep = None
        if vm is not None:
            from ilcnc.shop.corners import corner_report

            rep = corner_report(orig or prog, prof, vm, top=corners, target_um=target_um,
                                cycle_time_s=None if orig is not None else result.cycle_time_s)
        if tighter_out is not None:
            from ilcnc.shop.corners import write_tightened

            written = write_tightened(prog, prof, rep, tighter_out, drawing=orig,
                                      protect=(profile,) + ((against,) if against is not None else ()))
            rep.add_written(tighter_out, written)
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps(result.to_json(prog) | ({"corners": rep.to_json()} if rep is not None else {})))
        return
    _print_simulation(result, prog, console, log_out)
    _print_corners(rep, console)


def _vertices(drawing, corners: int):
    """What collects the error near each end point of ``drawing`` for ``--corners`` (None: not asked)."""
    if corners <= 0:
        return None
    from ilcnc.vcnc.rounding import VertexMax

    return VertexMax.empty(len(drawing.moves))


def _print_corners(rep, console) -> None:
    """The corner report (:mod:`ilcnc.shop.corners`) under a run's figures."""
    if rep is None:
        return
    if rep.judged:
        console.print(rep.judged, markup=False)
    if rep.corners:
        t = _table("worst cutting corners: the planner's rounding and the rest (µm)")
        for col in ("lines", "max at", "max", "rounding", "rest", "tolerance"):
            t.add_column(col, justify="left" if col == "tolerance" else "right", overflow="fold")
        for row in rep.rows():
            t.add_row(*row)
        console.print(t)
    console.print(rep.summary(), markup=False)
    if rep.tightening is not None:
        console.print(f"tighter: {rep.tightening.text()}", markup=False)
    for n in rep.notes:
        console.print(n, markup=False)


def _check_log_options(log_format: str, log_units: str, log_columns: str | None = None) -> None:
    """Refuse an unknown ``--log-format``, ``--log-units`` or ``--log-columns`` name (a usage error: exit 2, as
    typer's own)."""
    from ilcnc.axislog.detect import LOG_FORMATS
    from ilcnc.axislog.halsampler import halsampler_column_map

    if log_columns is not None:
        try:
            halsampler_column_map(None, log_columns)
        except InputError as exc:
            _fail(UsageError("--log-columns", f"names the columns of a halsampler log: {exc.problem}"))

    if log_format not in LOG_FORMATS:
        _fail(UsageError("--log-format", f"must be {', '.join(LOG_FORMATS[:-1])} or {LOG_FORMATS[-1]}, got {log_format!r}"))
    if log_units not in LENGTH_UNITS:
        _fail(UsageError("--log-units", f"must be {' or '.join(LENGTH_UNITS)}, got {log_units!r}"))


def _compare(program: Path, profile: Path, log_path: Path, log_format: str, log_units: str, log_columns: str | None,
             log_offset: tuple[float, float, float] | None, as_json: bool) -> None:
    """``simulate --compare``: the virtual CNC's E(k) against the one measured from a log (:mod:`ilcnc.shop.fidelity`)."""
    from ilcnc.axislog.detect import read_log
    from ilcnc.profile.load import load_profile
    from ilcnc.program import read_program
    from ilcnc.shop.fidelity import TARGET_CORRELATION, TARGET_DIFFERENCE, fidelity_of_log

    _check_log_options(log_format, log_units, log_columns)
    try:
        prof = load_profile(profile)
        prog = read_program(program, default_units=prof.machine.units)
        log = read_log(log_path, fmt=log_format, period_s=prof.machine.servo_period_s, units=log_units,
                       columns=log_columns, offset=log_offset)
        fid = fidelity_of_log(prog, log, prof, source=log_path, units=log_units)
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps({"program": str(program), "log": str(log_path), "fidelity": fid.to_json()}))
        return

    def um(x: float) -> str:
        return f"{x * 1e3:.2f}"

    t = _table(f"virtual CNC against {log_path.name}: {prog.path.name}", show_header=False)
    t.add_column("what", overflow="fold")
    t.add_column("value", overflow="fold")
    t.add_row("commands measured by both", str(fid.commands))
    t.add_row("correlation of |E(k)|", f"{fid.correlation:.3f} (target ≥ {TARGET_CORRELATION:g})")
    t.add_row("  per axis", " / ".join(f"{a} {c:.3f}" for a, c in fid.axis_correlation.items()))
    t.add_row("RMS |E(k)| measured / predicted (µm)", f"{um(fid.rms_measured_mm)} / {um(fid.rms_predicted_mm)}")
    t.add_row("RMS of E measured − predicted (µm)",
              f"{um(fid.rms_difference_mm)} ({fid.relative_difference:.0%} of measured; target ≤ {TARGET_DIFFERENCE:.0%})")
    for key in ("rms", "max"):
        t.add_row(f"contour error {key} measured / predicted (µm)",
                  f"{um(fid.contour_measured_mm[key])} / {um(fid.contour_predicted_mm[key])}")
    if fid.worst:
        w = fid.worst[0]
        t.add_row("largest difference", f"k={w['k']} (line {w['line']})")
    t.add_row("verdict", "the virtual CNC predicts this machine: virtual learning can be trusted" if fid.trusted else
              "the virtual CNC does not predict this machine well enough: learn from logs (learn --log)")
    _console().print(t)


def _simulate(prog, prof, orig, samples: bool, progress=None, vertices=None):
    """A run of the virtual CNC: every sample when they are written (``samples``), else only its figures
    (chunk by chunk where the profile allows: bounded memory, :mod:`ilcnc.vcnc.stream`)."""
    from ilcnc.vcnc.run import simulate_figures
    from ilcnc.vcnc.simulate import simulate_program

    if samples:
        return simulate_program(prog, prof, against=orig, progress=progress, vertices=vertices)
    return simulate_figures(prog, prof, against=orig, progress=progress, vertices=vertices)


def _compile_column():
    """A progress-bar column that shows what numba is compiling on the first run after install (else nothing)."""
    from rich.progress import ProgressColumn
    from rich.text import Text

    from ilcnc._jit import compiling_now

    class CompileColumn(ProgressColumn):
        max_refresh = 0.5

        def render(self, task):
            now = compiling_now()
            return Text("" if now is None else now, style="dim")

    return CompileColumn()


def _simulate_with_progress(prog, prof, orig, console, samples: bool, vertices=None):
    """Run the virtual CNC with a progress bar over its stages (shown on a terminal only)."""
    if not console.is_terminal:  # a live display off a terminal leaves a blank line before any error or table
        return _simulate(prog, prof, orig, samples, vertices=vertices)
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    stages = ("plan", "drives", "errors", "contour")
    with Progress(TextColumn("simulating: {task.description:<8}"), BarColumn(bar_width=24), TimeElapsedColumn(),
                  _compile_column(),
                  console=console, transient=True) as bar:
        task = bar.add_task("plan", total=len(stages))

        def advance(stage: str) -> None:
            bar.update(task, completed=stages.index(stage), description=stage)

        result = _simulate(prog, prof, orig, samples, progress=advance, vertices=vertices)
        bar.update(task, completed=len(stages))
    return result


def _print_simulation(result, prog, console, log_out: Path | None) -> None:

    t = _table(f"virtual CNC: {prog.path.name}", show_header=False)
    t.add_column("what", overflow="fold")
    t.add_column("value", overflow="fold")
    t.add_row("samples", f"{result.n_samples} at {result.period_s * 1e3:g} ms")
    t.add_row("cycle time (s)", f"{result.cycle_time_s:.2f}")
    for key in ("max", "mean", "rms"):
        t.add_row(f"cutting moves: contour error {key} (µm)", f"{result.stats[key] * 1e3:.2f}")
    air = result.air_stats
    t.add_row("air moves: max / RMS (µm)", f"{air['max'] * 1e3:.2f} / {air['rms'] * 1e3:.2f}")
    t.add_row("air moves are", result.cutting.describe())
    worst = result.worst(prog)
    t.add_row("worst command", f"k={worst['k']} (line {worst['line']})")
    for name, st in result.shares.items():
        t.add_row(f"  {name} share rms / max (µm)", f"{st['rms'] * 1e3:.2f} / {st['max'] * 1e3:.2f}")
    if log_out is not None:
        t.add_row("axis log", str(log_out))
    console.print(t)


@app.command()
def learn(
    program: Annotated[Path, typer.Argument(help="Part program (the drawing), or an output of the run given by --state.")],
    out: Annotated[Path, typer.Option("--out", help="Compensated program to write (.nc/.ngc/.tap/.gcode or .h).")],
    profile: Annotated[
        Path | None, typer.Option("--profile", help="Machine profile YAML (drives, planner, learning law); not needed"
                                  " with a probe height map.")
    ] = None,
    iterations: Annotated[
        int | None, typer.Option("--iterations", min=1, max=1000, help="Largest number of iterations (profile default).")
    ] = None,
    log: Annotated[Path | None, typer.Option("--log", help="Axis log of the last program run on the machine: one step.")] = None,
    points: Annotated[
        Path | None, typer.Option("--points", help="Measured points k,dx,dy,dz or x,y,z,dx,dy,dz (mm): one step; or a"
                                  " sender's probe height map (bCNC, Candle, OpenCNCPilot, cncjs): level the program.")
    ] = None,
    state: Annotated[
        Path | None, typer.Option("--state", help="Learning-state directory (default for virtual learning: OUT.state).")
    ] = None,
    report: Annotated[Path | None, typer.Option("--report", help="Write plots and tables into this directory.")] = None,
    stamp: Annotated[bool, typer.Option("--stamp", help="Add a provenance comment to the output (no line moves).")] = False,
    log_format: Annotated[
        str, typer.Option("--log-format", help="auto, ilcnc, halsampler or tncscope.")
    ] = "auto",
    log_units: Annotated[str, typer.Option("--log-units", help="Unit of the log's positions: mm or inch.")] = "mm",
    log_period: Annotated[
        float | None,
        typer.Option("--log-period", min=1e-6, help="Sample period of the log (s) when it has no time column"
                     " (halsampler without -t); default: the profile's servo period."),
    ] = None,
    log_columns: Annotated[str | None, typer.Option("--log-columns", help=_LOG_COLUMNS_HELP)] = None,
    log_offset: Annotated[str | None, typer.Option("--log-offset", help=_LOG_OFFSET_HELP)] = None,
    points_reach: Annotated[
        float | None,
        typer.Option("--points-reach", min=0.0, help="With --points: longest path gap (mm) between measured commands"
                     " bridged by interpolation (default: 3x their median spacing)."),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Virtual learning: replace an earlier run's OUT and state (never an input).")
    ] = False,
    refine: Annotated[
        bool, typer.Option("--refine", help="Insert straight-feed points on the path at corners and after rapids where"
                           " the first run shows error no end point can shape (learning.refine in the profile).")
    ] = False,
    cutting_below_z: Annotated[float | None, typer.Option("--cutting-below-z", help=_CUTTING_BELOW_Z_HELP)] = None,
    relearn: Annotated[
        bool, typer.Option("--relearn", help="Start a new run on a program that is an output of an earlier run"
                           " (refused by default: its corrections would be corrected again).")
    ] = False,
    new_profile: Annotated[
        bool, typer.Option("--new-profile", help="Continue a --state run with another profile than it was made with:"
                           " a new branch from its best iteration (refused by default; docs/learning.md).")
    ] = False,
    corners: Annotated[int, typer.Option("--corners", min=0, max=100, help=_CORNERS_HELP + " Virtual learning: one"
                                         " more run of the output, judged against the original.")] = 5,
    target_um: Annotated[float | None, typer.Option("--target-um", help=_TARGET_UM_HELP)] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Learn corrections of the G01 end points and write the compensated program.

    Without --log/--points it learns on the virtual CNC of the profile. With a
    measured log or probe points it makes one learning step and keeps its
    state in --state for the next run on the machine.
    """
    from ilcnc.shop.workflow import LearnRequest, learn_part

    if points is not None and _is_height_map(points):
        given = [name for name, v in (("--log", log), ("--state", state), ("--report", report), ("--iterations", iterations),
                                      ("--refine", refine), ("--force", force), ("--relearn", relearn),
                                      ("--new-profile", new_profile), ("--stamp", stamp)) if v]
        if given:
            _fail(UsageError(given[0], f"does not go with a probe height map ({points}): levelling is one rewrite of"
                                       " the program, not a learning step"))
        _level(program, points, out, as_json)
        return
    if profile is None:
        _fail(UsageError("--profile", "is required: the machine profile YAML (only a probe height map given to --points"
                                      " needs none)"))
    _check_log_options(log_format, log_units, log_columns)
    try:
        _finite("--log-period", log_period, lo=0.0, open_lo=True, hi=1.0, unit="s")  # a sample period: µs to ms
        _finite("--points-reach", points_reach, lo=0.0, open_lo=True, unit="mm")
        _finite("--target-um", target_um, lo=0.0, open_lo=True, hi=10000.0, unit="µm")
    except UsageError as exc:
        _fail(exc)
    req = LearnRequest(program, profile, out, iterations, log, points, state, report, stamp, log_format, log_units,
                       log_period_s=log_period, points_reach_mm=points_reach, log_columns=log_columns,
                       log_offset=_parse_offset(log_offset), force=force,
                       cutting_below_z_mm=cutting_below_z, refine=refine, relearn=relearn,
                       new_profile=new_profile)
    console = _console()
    try:
        if as_json or log is not None or points is not None:
            outcome = learn_part(req)
        else:
            outcome = _learn_with_progress(learn_part, req, console)
    except IlcncError as exc:
        _fail(exc)
    if report is not None:
        try:  # the visual diff and report.html, read back from the state the run just wrote
            from ilcnc.shop.state_report import write_state_report

            done = write_state_report(outcome.state_dir, report, profile_path=profile,
                                      cutting_below_z_mm=cutting_below_z, images=list(outcome.report_files))
        except IlcncError as exc:
            _fail(exc)
        outcome.report_files.extend(done.files)
    rep = None
    if corners > 0 and outcome.mode == "virtual" and outcome.output is not None:
        try:  # the output's worst corners: rounding and lag (ilcnc.shop.corners)
            from ilcnc.profile.load import load_profile
            from ilcnc.shop.corners import learned_corner_report

            prof = load_profile(profile).with_cutting_top(cutting_below_z)
            rep = learned_corner_report(outcome.state_dir, outcome.output, prof, top=corners, target_um=target_um)
        except IlcncError as exc:
            _fail(exc)
    if as_json:
        typer.echo(json.dumps(outcome.to_json() | ({"corners": rep.to_json()} if rep is not None else {})))
        return
    _print_learning(outcome, console)
    _print_corners(rep, console)


@app.command()
def report(
    state: Annotated[Path, typer.Argument(help="A learning state directory (learn's OUT.state or --state).")],
    out: Annotated[
        Path | None, typer.Option("--out", help="Report folder (default: NAME.report beside NAME.state).")
    ] = None,
    profile: Annotated[
        Path | None, typer.Option("--profile", help="The run's machine profile: its units and cutting rule.")
    ] = None,
    cutting_below_z: Annotated[float | None, typer.Option("--cutting-below-z", help=_CUTTING_BELOW_Z_HELP)] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Draw what a learning run changed and write report.html, from its state directory.

    Writes corrections.png (original and rewritten path, corrections as arrows magnified by the factor in
    the title; cutting moves solid, air moves dashed), corrections-zoom.png (the worst cutting spot with
    program line numbers), corrections-along-path.png, and report.html: one self-contained page with the
    figures, the iteration table, the worst commands with their source lines and the program diff.
    """
    from ilcnc.shop.state_report import default_report_dir, write_state_report

    try:
        _finite("--cutting-below-z", cutting_below_z, unit="mm")
        done = write_state_report(state, out if out is not None else default_report_dir(state), profile_path=profile,
                                  cutting_below_z_mm=cutting_below_z)
    except IlcncError as exc:
        _fail(exc)
    f = done.figures
    if as_json:
        typer.echo(json.dumps(done.to_json()))
        return
    typer.echo(f"iteration {done.shown_iteration} against the original: corrections ×{f.magnify:g} in"
               f" {done.files[0].name}, {f.arrows_drawn} of {f.arrows_total} corrected end points drawn; zoom on line"
               f" {done.worst_line} (±{f.zoom_half_mm:.3g} mm, ×{f.zoom_magnify:g})")
    typer.echo(f"wrote {len(done.files)} files in {done.files[0].parent}")


def _is_height_map(points: Path) -> bool:
    """True when --points names a sender's probe height map (by content and suffix) rather than a points CSV."""
    from ilcnc.axislog.heightmap import detect_height_map

    try:
        return detect_height_map(points) is not None
    except IlcncError as exc:
        _fail(exc)


def _level(program: Path, points: Path, out: Path, as_json: bool) -> None:
    """``learn --points MAP``: level the program on a probe height map (docs/probemaps.md)."""
    from ilcnc.shop.levelling import level_program

    try:
        res = level_program(program, points, out)
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps(res.to_json()))
        return
    console = _console()
    t = _table(f"levelled: {program.name} on {points.name} ({res.map_format})", show_header=False)
    t.add_column("what", overflow="fold")
    t.add_column("value", overflow="fold")
    for row in res.rows():
        t.add_row(*row)
    console.print(t)
    for line, reason in res.split_refused[:20]:
        console.print(f"not split: line {line}: {reason}")
    for n in res.notes:
        console.print(n)
    console.print(f"wrote {res.output}")


def _learn_with_progress(learn_part, req, console):
    """Virtual learning with a progress bar over the iterations on a terminal; piped, one line per iteration on
    stderr (a live display off a terminal leaves a blank line before any error or table)."""
    if not console.is_terminal:
        seen: set[int] = set()

        def line(it: int, total: int, stage: str) -> None:
            if it not in seen:
                seen.add(it)
                typer.echo(f"learning: iteration {it}/{total}", err=True)

        return learn_part(req, progress=line)
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("learning: {task.description:<22}"), BarColumn(bar_width=24), TimeElapsedColumn(),
                  _compile_column(),
                  console=console, transient=True) as bar:
        task = bar.add_task("iteration 0", total=None)

        def advance(it: int, total: int, stage: str) -> None:
            bar.update(task, total=total + 1, completed=it, description=f"iteration {it}/{total} {stage}")

        return learn_part(req, progress=advance)


def _print_learning(outcome, console) -> None:

    t = _table(f"learning: {outcome.program.name} ({outcome.mode}): cutting moves' contour error")
    for col in ("iteration", "max (µm)", "mean (µm)", "RMS (µm)", "air max (µm)", "cycle (s)", "clipped", "kept"):
        t.add_column(col, justify="right", overflow="fold")
    for it in outcome.iterations:
        ce = it.get("contour_error_mm")
        if ce is None:
            t.add_row(str(it["iteration"]), "-", "-", "-", "-", "-", str(it["clipped"]), "waiting for a measurement")
            continue
        air = it.get("air_error_mm")
        cyc = it.get("cycle_time_s")
        t.add_row(str(it["iteration"]), f"{ce['max'] * 1e3:.2f}", f"{ce['mean'] * 1e3:.2f}", f"{ce['rms'] * 1e3:.2f}",
                  "-" if air is None else f"{air['max'] * 1e3:.2f}", "-" if cyc is None else f"{cyc:.2f}",
                  str(it["clipped"]), "yes" if it["kept"] else "no")
    console.print(t)
    if outcome.cutting_rule:
        console.print(f"air moves: {outcome.cutting_rule}")
    if outcome.air_commands:
        n_air = outcome.air_commands
        console.print(f"{plural(n_air, 'G01 command')} in the air or ending there (retracts, approaches)"
                      f" {'is' if n_air == 1 else 'are'} kept as"
                      " programmed (learning.air_moves: keep)")
    for c in outcome.clips[:20]:
        console.print(f"clipped ({c.cause}): k={c.k} line {c.line} {c.axis.upper()} {c.wanted_mm:+.4f} →"
                      f" {c.applied_mm:+.4f} mm")
    if len(outcome.clips) > 20:
        console.print(f"clipped: {len(outcome.clips) - 20} more (see --json or --report)")
    if outcome.frozen:
        why = "; ".join(f"{n} {reason}" for reason, n in outcome.frozen_reasons.items())
        console.print(f"{plural(outcome.frozen, 'command')} {'is' if outcome.frozen == 1 else 'are'} never corrected"
                      f" ({why or 'repeated, parametric, polar or machine moves'})")
    for n in outcome.notes:
        console.print(n)
    console.print(f"status: {outcome.status}: {outcome.message}")
    if outcome.output is not None:
        console.print(f"wrote {outcome.output} (state in {outcome.state_dir})")
    if outcome.report_files:
        console.print(f"report: {plural(len(outcome.report_files), 'file')} in {outcome.report_files[0].parent}")


@app.command()
def identify(
    step: Annotated[Path, typer.Argument(help="Step response: t_s,u,y CSV, or an axis log (ilcnc, halsampler, TNCscope).")],
    axis: Annotated[str, typer.Option("--axis", help="Axis the step was recorded on (x, y or z).")],
    profile: Annotated[
        Path | None, typer.Option("--profile", help="Machine profile (known PID, servo period; --write).")
    ] = None,
    model: Annotated[str, typer.Option("--model", help="sopdt, mass_damper or first_order_delay.")] = "sopdt",
    signal: Annotated[str | None, typer.Option("--signal", help="velocity or position (default: from the data).")] = None,
    step_size: Annotated[float | None, typer.Option("--step", help="Step size when the file has no u column.")] = None,
    step_time: Annotated[float | None, typer.Option("--step-time", help="When the step happens, s (default: found).")] = None,
    fmt: Annotated[str, typer.Option("--log-format", help="Format of STEP: auto, step, ilcnc, halsampler or tncscope"
                                     " (formerly --format).")] = "auto",
    units: Annotated[str, typer.Option("--log-units", help="Unit of the log's positions: mm or inch (formerly"
                                       " --units).")] = "mm",
    period: Annotated[float | None, typer.Option("--log-period", help="Sample period of a halsampler log, s (formerly"
                                                 " --period-s).")] = None,
    write: Annotated[
        bool, typer.Option("--write", help="Store the fitted drive in the profile (keeps its comments).")
    ] = False,
    out: Annotated[Path | None, typer.Option("--out", help="With --write: write the updated profile here instead.")] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="Plot measurement vs fit into this PNG.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Fit a drive model to a measured step response; print parameters, confidence intervals and fit quality."""
    from ilcnc.axislog.detect import LOG_FORMATS
    from ilcnc.learning.identification import MODEL_ALIASES, MODELS, SIGNALS
    from ilcnc.learning.step_files import identify_file

    for name, value, allowed in (("--model", model, (*MODELS, *MODEL_ALIASES)), ("--signal", signal, (None, *SIGNALS)),
                                 ("--log-format", fmt, ("auto", "step", *(f for f in LOG_FORMATS if f != "auto"))),
                                 ("--log-units", units, LENGTH_UNITS), ("--axis", axis.lower(), AXIS_NAMES)):
        if value not in allowed:
            typer.echo(f"error: {name} must be one of {', '.join(a for a in allowed if a)}, got {value!r}", err=True)
            raise typer.Exit(2)
    if write and profile is None:
        typer.echo("error: --write needs --profile (the profile to update)", err=True)
        raise typer.Exit(2)
    try:
        _finite("--step", step_size)
        _finite("--step-time", step_time, lo=0.0)
        _finite("--log-period", period, lo=0.0, open_lo=True, hi=1.0, unit="s")  # a servo period: µs to ms
        ident = identify_file(step, axis=axis.lower(), model=model, signal=signal, step=step_size, fmt=fmt, units=units,
                              profile=profile, period_s=period, step_time_s=step_time)
        if plot is not None:
            ident.plot(plot, protect=(step,))
        written = ident.write_profile(profile, out=out) if write else None
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps(ident.to_json()))
        return

    console = _console()
    t = _table(f"identify: {step.name}, axis {axis.upper()}, model {ident.model} ({ident.signal})")
    for col in ("parameter", "value", "± std. error", "95 % interval", "unit"):
        t.add_column(col, overflow="fold")
    for r in ident.parameter_rows():
        t.add_row(str(r["name"]), f"{r['value']:.6g}", f"{r['stderr']:.3g}", f"[{r['ci_low']:.6g}, {r['ci_high']:.6g}]",
                  str(r.get("unit", "")))
    console.print(t)
    line = (f"fit RMS {ident.fit_rms:.3g} {ident.y_unit}, R² {ident.r2:.6f}, {plural(len(ident.t_s), 'sample')} at "
            f"{ident.period_s * 1e3:g} ms")
    if ident.fixed:
        line += "; known: " + ", ".join(f"{k} = {v:g}" for k, v in ident.fixed.items())
    console.print(line)
    for w in ident.warnings:
        console.print(f"warning: {w}")
    if written is not None:
        extra = f" (fitted gain {ident.parameters['gain']:.4f} written as 1)" if ident.written_gain == 1.0 else ""
        console.print(f"wrote {written}: axes.{axis.lower()}.drive{extra}")


@app.command()
def tune(
    profile: Annotated[Path, typer.Option("--profile", help="Machine profile YAML (drives, learning law).")],
    program: Annotated[
        Path | None, typer.Argument(help="Part program (lifted-model check of law p; gain schedule).")
    ] = None,
    method: Annotated[str, typer.Option("--method", help="auto, time (pid_ace: H-inf design), lifted (p) or schedule.")] = "auto",
    f_max: Annotated[float, typer.Option("--f-max", min=0.1, help="Upper end of the band for the time method, Hz.")] = 100.0,
    f_min: Annotated[float, typer.Option("--f-min", min=0.0, help="Lower end of the band (> 0 frees K_Il), Hz.")] = 0.0,
    lead_max: Annotated[int, typer.Option("--lead-max", min=0, max=100, help="Largest lead eta tried, servo periods.")] = 3,
    axis: Annotated[
        str | None, typer.Option("--axis", help="Axis of the gain schedule (default: tuning.schedule.axis, else z).")
    ] = None,
    horizon: Annotated[
        int | None, typer.Option("--horizon", min=1, max=10000,
                                 help="Schedule: prediction horizon Np, servo periods (default: tuning.schedule).")
    ] = None,
    lam: Annotated[
        float | None, typer.Option("--lambda", min=0.0, max=1e6,
                                   help="Schedule: weight lambda of the gain increment (default: tuning.schedule).")
    ] = None,
    write: Annotated[bool, typer.Option("--write", help="Store converging gains in the profile (keeps comments).")] = False,
    out: Annotated[Path | None, typer.Option("--out", help="With --write: write the profile here instead.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Design learning gains and say whether learning converges (per axis: epsilon, peak frequency)."""
    from ilcnc.learning.tune import tune_profile

    if method not in ("auto", "time", "lifted", "schedule"):
        typer.echo(f"error: --method must be auto, time, lifted or schedule, got {method!r}", err=True)
        raise typer.Exit(2)
    try:
        report = tune_profile(profile, method=method, program=program, write=write, out=out, f_min_hz=f_min,
                              f_max_hz=f_max, lead_max=lead_max, fix_ki=f_min <= 0.0,
                              axis=axis.lower() if axis is not None else None, horizon=horizon, lam=lam)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    except IlcncError as exc:
        _fail(exc)
    if as_json:
        typer.echo(json.dumps(report.to_json()))
        return

    console = _console()
    t = _table(f"tune: {profile.name} ({report.method})")
    for col in report.columns():
        t.add_column(col, overflow="fold")
    for row in report.rows():
        t.add_row(*[str(c) for c in row])
    console.print(t)
    if report.note:
        console.print(report.note)
    if report.written is not None:
        console.print(f"wrote {report.written}")
    if report.schedule_csv is not None:
        console.print(f"wrote {report.schedule_csv}")


_CHECK_HELP = "\n\n".join((
    "Gate programs in CI: exit non-zero when the simulated contour error of a program's cutting moves exceeds a"
    " threshold or regressed against a stored baseline.",
    "PROGRAMS are files (shell globs expand to many) or folders: a folder's program files by the rule of ilcnc"
    " batch (.nc .ngc .tap .gcode .gc .cnc .h, sorted). Each runs once on the virtual CNC of --profile; its"
    " cutting moves' max and RMS contour error and its cycle time are judged against --max-error / --max-rms"
    " and, with --baseline, against the figures stored there: a figure regresses when it grew by more than"
    " --tolerance-um (errors; default the profile's machine.resolution_mm, the least step the control makes) or"
    " --tolerance-s (cycle time; default one servo period, the step of the run's clock).",
    "--update-baseline writes this run's figures to the baseline (atomically; regressions are then reported,"
    " not failed). --junit FILE writes JUnit XML: one testcase per program, a failure naming each figure that"
    " failed or regressed.",
    "Exit codes: 0 every program passed; 1 a program failed a threshold or regressed against the baseline;"
    " 2 bad usage; 3 a program could not be read (the others are still judged and reported), or the profile or"
    " the baseline could not be read. One program with --max-error alone is the single-program gate of earlier"
    " releases, unchanged: there a program that cannot be read exits 1. Example for CI: docs/ci.md.",
))


@app.command(help=_CHECK_HELP)
def check(
    ctx: typer.Context,
    programs: Annotated[list[Path], typer.Argument(help="Part programs or folders of them to check.")],
    profile: Annotated[Path, typer.Option("--profile", help="Machine profile YAML.")],
    max_error: Annotated[
        float | None, typer.Option("--max-error", min=0.0, help="Largest allowed contour error, mm (needed"
                                   " unless --baseline is given).")
    ] = None,
    max_rms: Annotated[float | None, typer.Option("--max-rms", min=0.0, help="Largest allowed RMS contour error, mm.")] = None,
    cutting_below_z: Annotated[float | None, typer.Option("--cutting-below-z", help=_CUTTING_BELOW_Z_HELP)] = None,
    baseline: Annotated[
        Path | None, typer.Option("--baseline", help="Baseline JSON: each program's max, RMS and cycle time of an"
                                  " earlier run to compare against.")
    ] = None,
    update_baseline: Annotated[
        bool, typer.Option("--update-baseline", help="Write this run's figures to --baseline (atomically).")
    ] = False,
    tolerance_um: Annotated[
        float | None, typer.Option("--tolerance-um", min=0.0, help="How much a program's max or RMS contour error"
                                   " may grow over the baseline, µm (default: the profile's machine.resolution_mm).")
    ] = None,
    tolerance_s: Annotated[
        float | None, typer.Option("--tolerance-s", min=0.0, help="How much a program's cycle time may grow over"
                                   " the baseline, s (default: the profile's machine.servo_period_s).")
    ] = None,
    junit: Annotated[Path | None, typer.Option("--junit", help="Write a JUnit XML report here.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    if max_error is None and baseline is None:
        from typer._click.exceptions import MissingParameter

        param = next(p for p in ctx.command.params if p.name == "max_error")
        raise MissingParameter(ctx=ctx, param=param)
    gate = (baseline is not None or junit is not None or update_baseline or tolerance_um is not None
            or tolerance_s is not None or len(programs) != 1 or programs[0].is_dir())
    if gate:
        _check_gate(programs, profile, max_error, max_rms, cutting_below_z, baseline, update_baseline, tolerance_um,
                    tolerance_s, junit, as_json)
        return
    program = programs[0]
    from ilcnc.profile.load import load_profile
    from ilcnc.program import read_program

    try:
        prof = load_profile(profile).with_cutting_top(cutting_below_z)
        prog = read_program(program, default_units=prof.machine.units)
        result = _simulate(prog, prof, None, False)
    except IlcncError as exc:
        _fail(exc)
    st = result.stats
    worst = result.worst(prog)
    over = []
    if result.worst_sample < 0:
        over.append(f"no cutting move: {result.cutting.describe()}; nothing to judge")
    if st["max"] > max_error:
        over.append(f"cutting moves' max contour error {st['max']:.4f} mm > {max_error:g} mm (k={worst['k']}, line"
                    f" {worst['line']})")
    if max_rms is not None and st["rms"] > max_rms:
        over.append(f"cutting moves' RMS contour error {st['rms']:.4f} mm > {max_rms:g} mm")
    if as_json:
        out = result.to_json(prog)
        out.update({"max_error_mm": max_error, "max_rms_mm": max_rms, "passed": not over})
        typer.echo(json.dumps(out))
    elif over:
        typer.echo(f"error: {program}:{worst['line']}: " + "; ".join(over), err=True)
    else:
        air = result.air_stats
        typer.echo(f"ok: {program.name}: cutting moves max {st['max']:.4f} mm <= {max_error:g} mm, RMS {st['rms']:.4f} mm"
                   f" (air moves apart: max {air['max']:.4f} mm; {result.cutting.describe()})")
    if over:
        raise typer.Exit(1)


#: ``ilcnc check``'s exit code when a program (or the profile or baseline) could not be read.
CHECK_UNREADABLE_EXIT = 3


def _check_gate(programs: list[Path], profile: Path, max_error: float | None, max_rms: float | None,
                cutting_below_z: float | None, baseline: Path | None, update_baseline: bool,
                tolerance_um: float | None, tolerance_s: float | None, junit: Path | None, as_json: bool) -> None:
    """``ilcnc check`` over many programs, against a baseline, with a JUnit report (:mod:`ilcnc.shop.gate`)."""
    import textwrap

    from ilcnc.fileio import same_file, write_atomic
    from ilcnc.outcomes import CheckStatus
    from ilcnc.profile.load import load_profile
    from ilcnc.shop import gate as gate_mod
    from ilcnc.shop.state import sha256_file

    try:
        if update_baseline and baseline is None:
            raise UsageError("--update-baseline", "needs --baseline FILE (the file to write)")
        for opt, val in (("--max-error", max_error), ("--max-rms", max_rms), ("--tolerance-um", tolerance_um),
                         ("--tolerance-s", tolerance_s)):
            _finite(opt, val, lo=0.0)
    except IlcncError as exc:
        _fail(exc)
    try:
        prof = load_profile(profile).with_cutting_top(cutting_below_z)
        paths = gate_mod.expand_programs(programs)
        for opt, dest in (("--junit", junit), ("--baseline", baseline if update_baseline else None)):
            if dest is None:
                continue
            if any(same_file(dest, p) for p in (*paths, profile)):
                raise UsageError(opt, f"{dest} is an input of this check; choose another file")
            if not (dest.parent if str(dest.parent) else Path(".")).is_dir():
                raise UsageError(opt, f"{dest}: folder {dest.parent} does not exist")
        old = None
        if baseline is not None and (not update_baseline or baseline.exists()):
            old = gate_mod.read_baseline(baseline)
    except IlcncError as exc:
        if debug_on():
            raise
        typer.echo(f"error: {exc.format()}", err=True)
        raise typer.Exit(exc.exit_code if isinstance(exc, UsageError) else CHECK_UNREADABLE_EXIT) from None
    tol_mm = prof.machine.resolution_mm if tolerance_um is None else tolerance_um * 1e-3
    tol_s = prof.machine.servo_period_s if tolerance_s is None else tolerance_s
    results = []
    for p in paths:
        r = gate_mod.check_program(p, prof)
        entry = None if old is None else old.programs.get(r.name)
        gate_mod.judge(r, max_error_mm=max_error, max_rms_mm=max_rms, baseline=entry, tolerance_mm=tol_mm,
                       tolerance_s=tol_s)
        if old is not None and entry is None and r.status is not CheckStatus.UNREADABLE:
            r.notes.append("not in the baseline" + ("" if update_baseline else " (--update-baseline adds it)"))
        if update_baseline:  # the new baseline is this run: a regression is reported, not failed
            kept = [f for f in r.failures if "regressed" not in f]
            r.notes += [f"{f} (baseline updated)" for f in r.failures if "regressed" in f]
            r.failures = kept
        results.append(r)
    protect = (*paths, profile)
    try:
        if update_baseline:
            assert baseline is not None
            gate_mod.write_baseline(baseline, results, previous=old, profile=profile, profile_sha256=sha256_file(profile),
                                    protect=protect)
        if junit is not None:
            write_atomic(junit, gate_mod.junit_xml(results), protect=protect)
    except IlcncError as exc:
        _fail(exc)
    n_bad = sum(r.status is CheckStatus.UNREADABLE for r in results)
    n_fail = sum(r.status is CheckStatus.FAILED for r in results)
    code = CHECK_UNREADABLE_EXIT if n_bad else (1 if n_fail else 0)
    if as_json:
        typer.echo(json.dumps({"programs": [r.to_json() for r in results], "passed": code == 0, "exit_code": code,
                               "baseline": None if baseline is None else str(baseline),
                               "baseline_updated": update_baseline, "tolerance_mm": tol_mm, "tolerance_s": tol_s,
                               "max_error_mm": max_error, "max_rms_mm": max_rms,
                               "junit": None if junit is None else str(junit)}))
    else:
        word = {CheckStatus.PASSED: "pass", CheckStatus.FAILED: "FAIL", CheckStatus.UNREADABLE: "ERROR"}
        for r in results:
            head = f"{word[r.status]:<5} " + ("" if r.status is CheckStatus.UNREADABLE else f"{r.name}: ")
            body = gate_mod.figures_line(r).split("\n")
            lines = [head + body[0], *body[1:], *r.failures]
            for i, ln in enumerate(lines):
                typer.echo("\n".join(textwrap.wrap(ln, 80, initial_indent="" if i == 0 else "      ",
                                                   subsequent_indent="      ", break_on_hyphens=False)))
        n = len(results)
        summary = (f"check: {plural(n, 'program')}: {n - n_fail - n_bad} passed, {n_fail} failed,"
                   f" {n_bad} unreadable (tolerance {tol_mm * 1e3:g} µm, {tol_s:g} s)")
        if update_baseline:
            summary += f"; wrote baseline {baseline}"
        if junit is not None:
            summary += f"; wrote {junit}"
        typer.echo("\n".join(textwrap.wrap(summary, 80, subsequent_indent="  ")))
    if code:
        raise typer.Exit(code)


@app.command()
def batch(
    source: Annotated[Path, typer.Argument(help="Folder of part programs, or a manifest YAML (programs x profiles).")],
    out: Annotated[Path, typer.Option("--out", help="Folder for the compensated programs, states and summary.csv.")],
    profile: Annotated[
        Path | None, typer.Option("--profile", help="Profile of every part (a manifest may name its own).")
    ] = None,
    workers: Annotated[int, typer.Option("--workers", min=1, max=256, help="Local worker processes.")] = 1,
    scheduler: Annotated[
        str | None, typer.Option("--scheduler", help="Dask distributed scheduler address (tcp://host:8786).")
    ] = None,
    iterations: Annotated[int | None, typer.Option("--iterations", min=1, max=1000, help="Largest number of iterations.")] = None,
    allow_outside: Annotated[
        bool, typer.Option("--allow-outside", help="Learn manifest programs outside the manifest's folder (refused"
                           " by default).")
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Learn every part of a folder or manifest; exit 1 if any part failed or regressed."""
    from ilcnc.shop import batch as batch_mod
    try:
        if scheduler is not None and "://" not in scheduler:
            raise UsageError("--scheduler", f"must be a Dask scheduler address such as tcp://host:8786, got {scheduler!r}")
        if profile is not None and not profile.is_file():
            raise InputError(profile, None, "file not found" if not profile.exists() else "is not a file")
        if out.exists() and not out.is_dir():
            raise InputError(out, None, "exists and is not a folder")
        jobs = batch_mod.jobs_from_path(source, profile, out, iterations=iterations, allow_outside=allow_outside)
        out.mkdir(parents=True, exist_ok=True)  # after the jobs are checked: a refused manifest makes nothing
    except IlcncError as exc:
        _fail(exc)
    console = _console()
    try:
        results = _run_batch(batch_mod, jobs, workers, scheduler, console, as_json)
        batch_mod.write_summary(out, results)
    except IlcncError as exc:
        _fail(exc)
    failed = [r for r in results if r.failed]
    if as_json:
        typer.echo(json.dumps({"parts": [r.to_json() for r in results], "retried": len(batch_mod.retried(results))}))
    else:
        _print_batch(results, console, out)
    if failed:
        raise typer.Exit(1)


def _run_batch(batch_mod, jobs, workers: int, scheduler: str | None, console, as_json: bool) -> list:
    """The batch's parts learned, with a progress bar and a line per part unless ``as_json``."""
    if as_json:
        results = batch_mod.run_batch(jobs, workers=workers, scheduler=scheduler)
    else:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        with Progress(TextColumn("batch"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console,
                      transient=True) as bar:
            task = bar.add_task("parts", total=len(jobs))

            def done(r) -> None:
                bar.advance(task)
                ce = r.contour_error_mm
                mx = r.max_error_mm
                fig = (f"cutting max {mx['before'] * 1e3:.2f} -> {mx['after'] * 1e3:.2f} µm, RMS {ce['before'] * 1e3:.2f} ->"
                       f" {ce['after'] * 1e3:.2f} µm" if ce["before"] is not None and ce["after"] is not None else "")
                bar.console.print(f"{r.status:>14}  {Path(r.program).name}  {Path(r.profile).name}  {fig}"
                                  + (f"  {r.error}" if r.error else ""))

            results = batch_mod.run_batch(jobs, workers=workers, scheduler=scheduler, on_result=done)
    return results


def _print_batch(results, console, out: Path) -> None:
    profiles = sorted({Path(r.profile).name for r in results})
    one = len(profiles) == 1
    title = f"batch: {plural(len(results), 'part')}" + (f" on {profiles[0]}" if one else "")
    t = _table(title + " (cutting moves' contour error, µm)")
    cols = ("part",) + (() if one else ("profile",)) + ("G01", "it.", "max", "RMS", "clipped", "status")
    for col in cols:
        t.add_column(col, overflow="fold", justify="left" if col in ("part", "profile", "status") else "right")

    def um(x) -> str:
        return "-" if x is None else f"{x * 1e3:.2f}"

    for r in results:
        ce, mx = r.contour_error_mm, r.max_error_mm
        row = [Path(r.program).name] + ([] if one else [Path(r.profile).name])
        row += [str(r.g01_commands), str(r.iterations), f"{um(mx['before'])}→{um(mx['after'])}",
                f"{um(ce['before'])}→{um(ce['after'])}", str(r.clipped), str(r.status)]
        t.add_row(*row)
    console.print(t)
    again = [r for r in results if r.attempts > 1]
    if again:
        import textwrap

        # a Dask worker lost mid-run costs its parts only: Dask ran them again on the others (issue 24 item 5)
        names = ", ".join(f"{Path(r.program).name} ({r.attempts} attempts)" for r in again[:5])
        more = f" and {len(again) - 5} more" if len(again) > 5 else ""
        console.print("\n".join(textwrap.wrap(f"retried: {len(again)} part{'' if len(again) == 1 else 's'} whose worker"
                                               f" was lost or whose task failed, run again: {names}{more}", 80,
                                               subsequent_indent="  ")))
    console.print(f"summary: {out / 'summary.csv'}")


@app.command()
def selftest(
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    debug: DebugOption = False,
) -> None:
    """Compile and cache the kernels of the usual commands, once after install (20-40 s; then ~1 s).

    The first run after an install compiles ilcnc's numba kernels; run this as an install step so that no
    real command pays for it. It simulates and learns a small built-in program on the built-in machine and
    checks the figures are finite (exit 1 if not). Kernels of other drive models (friction, cross-coupled)
    are compiled by their profile's first run.
    """
    import time

    from ilcnc.shop.selftest import run_selftest

    t0 = time.perf_counter()

    def say(step: str) -> None:
        if not as_json:
            typer.echo(f"selftest: {step} ...", err=True)

    res = run_selftest(progress=say)
    wall = time.perf_counter() - t0
    if as_json:
        typer.echo(json.dumps({"ok": res.ok, "wall_s": wall, "compiled": res.compiled, "compile_s": res.compile_s,
                               "steps": [{"step": n, "wall_s": s, "figure": f} for n, s, f in res.steps]}))
    else:
        for name, secs, figure in res.steps:
            typer.echo(f"{name:28s} {secs:6.2f} s   {figure}")
        cached = ("kernels were cached already" if not res.compiled else
                  f"compiled {plural(res.compiled, 'kernel')} in {res.compile_s:.1f} s (cached for the next runs)")
        typer.echo(f"selftest {'ok' if res.ok else 'FAILED'} in {wall:.1f} s: {cached}")
    if not res.ok:
        raise typer.Exit(1)


app.add_typer(linuxcnc_app, name="linuxcnc")


#: Gen-0 threshold of Python's cycle collector while a command runs (Python's default: 700).
GC_THRESHOLD = 50_000


def main() -> None:
    """Console-script entry point (also of ``python -m ilcnc``: named ilcnc in usage lines and completion scripts).

    The cycle collector runs less often while a command runs, and not over the objects alive at the end (issue
    24): a simulate imports ~250,000 long-lived objects (typer and pydantic, numpy, numba's registries); at
    Python's default threshold that is ~320 collections (0.15-0.25 s), and the interpreter's last collections
    at exit walk them all again (0.3-0.5 s once numba is loaded, longer than most runs). The commands make
    little cyclic garbage (numpy arrays hold none): at 50,000 objects it stays a few MB between collections.
    """
    import gc

    gc.set_threshold(GC_THRESHOLD, 10, 10)
    try:
        app(prog_name="ilcnc")
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
        sys.exit(130)
    finally:
        gc.freeze()  # the process ends: nothing alive now needs collecting
