"""The virtual CNC chunk by chunk (ilcnc.vcnc.stream): the numbers of the whole run, bit for bit, in bounded memory.

Real CAM programs (jscut's jsdc engraving, cds.ngc with 350 groups of rapids and cuts, a Heidenhain
program) on the shipped profiles; chunks far smaller than the programs, so that every seam is crossed:
groups longer than a chunk (planned in ranges), groups shorter, chunks ending inside the stand-still
between groups.
"""

from __future__ import annotations

import itertools
import json
import tracemalloc

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.learning.learner import learn_virtual, program_with_corrections
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.vcnc.command_error import signal_of_simulation
from ilcnc.vcnc.drives import DriveStream, simulate_drives
from ilcnc.vcnc.machine_errors import ErrorSources
from ilcnc.vcnc.plan import plan_chunks, plan_program, planned_duration_s
from ilcnc.vcnc.simulate import simulate_program
from ilcnc.vcnc.stream import simulate_streamed, stream_unsupported
from tests.conftest import REPO, SAMPLES, shared_param

CONFIGS = REPO / "configs"
JSDC = SAMPLES / "gcode" / "jsdc.gcode"  # jscut engraving, 2381 G01 (MIT, samples/MANIFEST.tsv)
CDS = SAMPLES / "gcode" / "cds.ngc"  # many rapids between short cuts (samples/MANIFEST.tsv)


def _concat(chunks, name):
    return np.concatenate([getattr(c, name) for c in chunks])


@pytest.mark.parametrize(("program", "profile", "chunk"), [
    (JSDC, "example-mill.yaml", 5_000),        # one feed group of 36 k samples, planned in ranges
    (JSDC, "linuxcnc-sim.yaml", 5_000),        # LinuxCNC's planner: planned whole, handed out in chunks
    (JSDC, "seed004-ward-sopdt.yaml", 2_048),
    (CDS, "example-mill.yaml", 3_000),          # 350 groups: short ones whole, stand-stills across seams
    shared_param("heidenhain", "lk_700.h", "example-mill.yaml", 4_096),  # TEST-ONLY: ../shared
])
def test_chunks_are_the_planned_reference(program, profile, chunk) -> None:
    prog = read_program(program)
    prof = load_profile(CONFIGS / profile)
    ref = plan_program(prog, prof)
    chunks = list(plan_chunks(prog, prof, chunk_samples=chunk))
    assert len(chunks) >= 3
    assert all(c.n_samples == chunk - chunk % 1024 for c in chunks[:-1])
    assert [c.first_sample for c in chunks] == list(np.cumsum([0] + [c.n_samples for c in chunks[:-1]]))
    assert np.array_equal(_concat(chunks, "pos_mm"), ref.pos_mm)
    for col in ("move", "command", "line"):
        assert np.array_equal(_concat(chunks, col), getattr(ref, col)), col
    assert planned_duration_s(prog, prof) == ref.duration_s


@pytest.mark.parametrize("profile", ["seed004-ward-sopdt.yaml", "linuxcnc-sim.yaml", "example-mill.yaml",
                                     "seed000-hendrawan-mass-damper-pid.yaml"])
def test_drive_stream_is_the_whole_run(profile) -> None:
    prof = load_profile(CONFIGS / profile)
    ref = plan_program(read_program(JSDC), prof).pos_mm[:30_000]
    whole = simulate_drives(ref, prof)
    ds = DriveStream(prof, ref[0])
    # stretches of 1, 3 and 7 samples (shorter than the drives' delays) and long ones
    cuts = [0, 1, 4, 11, 5000, 5003, 12_000, 30_000]
    got = np.vstack([ds.step(ref[a:b]) for a, b in itertools.pairwise(cuts)])
    assert np.array_equal(got, whole)


def test_streamed_run_gives_the_figures_and_error_of_the_whole_run() -> None:
    prof = load_profile(CONFIGS / "seed004-ward-sopdt.yaml")
    prog = read_program(JSDC)
    # a compensated program judged against the drawing (the learning loop's runs after the first)
    rng = np.random.default_rng(3)
    u = rng.normal(0.0, 0.01, (prog.n_commands, 3)) * [1, 1, 0]
    _text, comp = program_with_corrections(prog, u, prof)
    for run, against in ((prog, None), (comp, prog)):
        sim = simulate_program(run, prof, against=against)
        sig = signal_of_simulation(sim, prog, "path", 2.0)
        st = simulate_streamed(run, prof, against=against, gate_mm=2.0, chunk_samples=4096)
        assert st.chunks > 5
        assert st.stats == sim.stats
        assert st.worst_sample == sim.worst_sample and st.worst(run) == sim.worst(run)
        assert st.n_samples == sim.reference.n_samples and st.cycle_time_s == sim.cycle_time_s
        assert np.array_equal(st.signal.e_mm, sig.e_mm)
        assert np.array_equal(st.signal.t_s, sig.t_s)
        assert np.array_equal(st.signal.valid, sig.valid)
        assert st.to_json(run) == sim.to_json(run)


def test_learning_streamed_equals_learning_on_whole_runs() -> None:
    prof = load_profile(CONFIGS / "seed004-ward-sopdt.yaml")
    prog = read_program(JSDC)
    streamed = learn_virtual(prog, prof, iterations=3, stop_on_stall=False)
    whole = learn_virtual(prog, prof, iterations=3, stop_on_stall=False, keep_runs=True)  # runs held: not streamed
    assert whole.iterations[0].run is not None and streamed.iterations[0].run is None
    assert [r.stats for r in streamed.iterations] == [r.stats for r in whole.iterations]
    assert [r.kept for r in streamed.iterations] == [r.kept for r in whole.iterations]
    for a, b in zip(streamed.iterations, whole.iterations, strict=True):
        assert np.array_equal(a.corrections_mm, b.corrections_mm)
        assert a.text == b.text
    assert streamed.iterations[-1].stats["rms"] < 0.8 * streamed.iterations[0].stats["rms"]


def test_a_chunk_is_all_the_run_holds() -> None:
    """Traced peak memory: a whole run grows with its samples (~150 B each), a streamed one only with the
    program's tables (the same chunk of 4096 samples is reused)."""
    prof = load_profile(CONFIGS / "seed004-ward-sopdt.yaml")
    data = JSDC.read_bytes()
    # one untraced run of each first: what a process creates once (imports, compiled kernels, caches) is not
    # the run's memory, and which test ran before this one must not decide it (seen: 11.4 MB streamed peak
    # in a full run against 34.2 / 3 MB allowed, well within it when run alone)
    warm = read_program(JSDC, data=data)
    simulate_streamed(warm, prof, chunk_samples=4096)
    simulate_program(warm, prof)
    del warm
    peaks = {}
    for copies in (1, 4):
        prog = read_program(JSDC, data=data * copies)
        n = plan_program(prog, prof).n_samples
        tracemalloc.start()
        try:
            simulate_streamed(prog, prof, chunk_samples=4096)
            stream = tracemalloc.get_traced_memory()[1]
            tracemalloc.reset_peak()
            simulate_program(prog, prof)
            whole = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        peaks[copies] = (n, stream, whole)
    (n1, s1, w1), (n4, s4, w4) = peaks[1], peaks[4]
    assert n4 > 3.9 * n1 > 30 * 4096
    assert w4 - w1 > 100 * (n4 - n1)  # every sample held
    assert s4 - s1 < (w4 - w1) / 4
    assert s4 < w4 / 3


def test_what_cannot_stream_says_why() -> None:
    assert stream_unsupported(load_profile(CONFIGS / "seed004-ward-sopdt.yaml"), "path") is None
    why = stream_unsupported(load_profile(CONFIGS / "seed001-duong-p-ff-friction.yaml"), "path")
    assert why is not None and "friction" in why
    why = stream_unsupported(load_profile(CONFIGS / "seed003-li-cross-coupled.yaml"), "path")
    assert why is not None and "cross-coupled" in why
    why = stream_unsupported(load_profile(CONFIGS / "seed004-ward-sopdt.yaml"), "crossing")
    assert why is not None and "crossing" in why
    prof = load_profile(CONFIGS / "seed002-lu-volumetric.yaml")
    why = stream_unsupported(prof, "path", sources=ErrorSources.from_profile(prof))
    assert why is not None and "geometric" in why
    with pytest.raises(ValueError, match="friction"):
        simulate_streamed(read_program(JSDC), load_profile(CONFIGS / "seed001-duong-p-ff-friction.yaml"))


def test_simulate_cli_without_samples_to_write_gives_the_figures_of_the_full_run(tmp_path) -> None:
    runner = CliRunner()
    args = ["simulate", str(JSDC), "--profile", str(CONFIGS / "seed004-ward-sopdt.yaml"), "--json"]
    figures = runner.invoke(app, args)
    full = runner.invoke(app, [*args, "--log-out", str(tmp_path / "log.csv")])
    assert figures.exit_code == 0 and full.exit_code == 0, figures.output + full.output
    assert json.loads(figures.stdout) == json.loads(full.stdout)
    check = runner.invoke(app, ["check", str(JSDC), "--profile", str(CONFIGS / "seed004-ward-sopdt.yaml"),
                                "--max-error", "10", "--json"])
    assert check.exit_code == 0 and json.loads(check.stdout)["contour_error_mm"] == json.loads(full.stdout)[
        "contour_error_mm"]


def test_in_position_wait_after_rapids_is_the_profiles() -> None:
    """planner.in_position_s: 0.1 s stand-still between rapid and feed groups by default; 0 (LinuxCNC) leaves
    only the 3-sample separation, so cds.ngc runs 0.097 s shorter per rapid-feed transition."""
    prog = read_program(CDS)
    prof = load_profile(CONFIGS / "example-mill.yaml")
    d = prof.to_dict()
    d["planner"]["in_position_s"] = 0.0
    from ilcnc.profile.load import profile_from_dict

    fast = profile_from_dict(d)
    t_wait, t_none = planned_duration_s(prog, prof), planned_duration_s(prog, fast)
    groups = (np.diff((prog.moves.kind == 0).astype(int)) != 0).sum()
    assert groups > 10
    assert t_wait - t_none == pytest.approx(groups * (0.1 - 0.003), rel=0.01)


def test_planning_ahead_hands_out_the_same_chunks_and_the_planners_error() -> None:
    """:func:`ilcnc.vcnc.stream._ahead` plans in a thread one chunk ahead: the same items in order, the planner's
    error raised in the caller after the items before it, and a caller that stops early ends the thread."""
    import threading

    from ilcnc._threads import thread_limit_scope
    from ilcnc.errors import InputError
    from ilcnc.vcnc import stream

    def planner(fail_after: int | None):
        for i in range(6):
            if fail_after is not None and i == fail_after:
                raise InputError("prog.ngc", 7, "the program's motion takes too long")
            yield np.full(3, float(i))

    with thread_limit_scope(2):
        got = list(stream._ahead(planner(None)))
        assert [float(g[0]) for g in got] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
        seen = []
        with pytest.raises(InputError, match="takes too long"):
            for g in stream._ahead(planner(2)):
                seen.append(float(g[0]))
        assert seen == [0.0, 1.0]
        it = stream._ahead(planner(None))
        assert float(next(it)[0]) == 0.0
        it.close()
    assert not any(t.name == "ilcnc-plan-ahead" for t in threading.enumerate())
    with thread_limit_scope(1):  # one thread allowed: planned in the caller's thread
        assert [float(g[0]) for g in stream._ahead(planner(None))] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
