"""Start-up (issue 24): what a command imports, numba on first use, the first run's notice, ``ilcnc selftest``.

No test here is timed (``bench/startup.py`` times the commands); they check what makes the time: which heavy
modules a command imports, that kernels wait for their first call, and that the conversions written out in
:mod:`ilcnc.vcnc.lti` give SciPy's numbers bit for bit.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.vcnc import discrete, lti

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


def _run_python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    import os

    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, **env}, timeout=300)


# ---------------------------------------------------------------------------------------------
# scipy.signal's conversions, written out (ilcnc.vcnc.lti)
# ---------------------------------------------------------------------------------------------


def _same(a: object, b: object) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b)


def test_lti_conversions_are_scipys_bit_for_bit() -> None:
    signal = pytest.importorskip("scipy.signal")
    rng = np.random.default_rng(24)
    for n in (1, 2, 3, 4, 6):
        for _ in range(20):
            den = np.concatenate([[rng.uniform(0.1, 5.0)], rng.uniform(-3.0, 3.0, n)])
            num = rng.uniform(-2.0, 2.0, rng.integers(1, n + 1))
            mine, theirs = lti.tf2ss(num, den), signal.tf2ss(num, den)
            assert all(_same(x, y) for x, y in zip(mine, theirs, strict=True))
            a, b, c, _ = theirs
            d = np.zeros((1, 1))
            for bb in (b, b[:, 0].reshape(-1, 1)):
                mn, md = lti.ss2tf(a, bb, c, d)
                tn, td = signal.ss2tf(a, bb, c, d)
                assert _same(mn, tn) and _same(md, td)
            for dt in (1e-3, 3.7e-4, 0.05):
                for bcols in (b, np.column_stack([b, rng.uniform(-1, 1, (n, 1))])):
                    ad, bd = lti.cont2discrete_zoh(a, bcols, dt)
                    sad, sbd, _, _, _ = signal.cont2discrete(
                        (a, bcols, np.zeros((1, n)), np.zeros((1, bcols.shape[1]))), dt, method="zoh")
                    assert _same(ad, sad) and _same(bd, sbd)


def test_lti_leading_zero_numerator_warns_and_trims_like_scipy() -> None:
    signal = pytest.importorskip("scipy.signal")
    num, den = np.array([0.0, 0.0, 2.0, 1.0]), np.array([1.0, 3.0, 2.0, 1.0])
    with pytest.warns(lti.BadCoefficients):
        mine = lti.tf2ss(num, den)
    with pytest.warns(signal.BadCoefficients):
        theirs = signal.tf2ss(num, den)
    assert all(_same(x, y) for x, y in zip(mine, theirs, strict=True))


@pytest.mark.parametrize("config", CONFIGS, ids=[c.stem for c in CONFIGS])
def test_drive_models_of_every_shipped_profile_are_unchanged(config: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The discrete model of every drive of every shipped profile, with ilcnc.vcnc.lti and with scipy.signal."""
    signal = pytest.importorskip("scipy.signal")
    from ilcnc.profile.load import load_profile

    prof = load_profile(config)
    period = prof.machine.servo_period_s

    def models() -> list[object]:
        out: list[object] = []
        for ax in prof.axes.values():
            try:
                m = discrete.discrete_model(ax.drive, period)
            except discrete.DriveModelError:
                out.append(None)
                continue
            out.append((m.b, m.a, m.dc_gain, m.delay_samples))
            if discrete.has_position_loop(ax.drive) or type(ax.drive).__name__ == "PFfFrictionDrive":
                p = discrete.loop_plant(ax.drive)
                out.append(discrete.discretise(p.a, p.bu, p.c, period, p.delay_s).tf())
        return out

    mine = models()

    def scipy_zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        ad, bd, _, _, _ = signal.cont2discrete((a, b, np.zeros((1, a.shape[0])), np.zeros((1, b.shape[1]))), dt,
                                               method="zoh")
        return ad, bd

    monkeypatch.setattr(discrete, "cont2discrete_zoh", scipy_zoh)
    monkeypatch.setattr(discrete, "ss2tf", signal.ss2tf)
    monkeypatch.setattr(discrete, "tf2ss", signal.tf2ss)
    theirs = models()
    assert len(mine) == len(theirs)
    for x, y in zip(mine, theirs, strict=True):
        if x is None or y is None:
            assert x is y
            continue
        assert all(_same(p, q) for p, q in zip(x, y, strict=True))


# ---------------------------------------------------------------------------------------------
# What a command imports
# ---------------------------------------------------------------------------------------------


def test_the_command_line_and_the_run_modules_import_neither_numba_nor_scipy_signal() -> None:
    res = _run_python("""
        import sys
        import ilcnc.cli, ilcnc.vcnc.run, ilcnc.vcnc.stream, ilcnc.vcnc.simulate, ilcnc.vcnc.drives
        import ilcnc.vcnc.plan, ilcnc.vcnc.plan_tp, ilcnc.vcnc.command_error, ilcnc.contour.search
        import ilcnc.program.scan, ilcnc.learning.learner, ilcnc.shop.workflow, ilcnc.shop.inspect
        from ilcnc.profile.load import default_profile
        from ilcnc.vcnc.discrete import discrete_model
        prof = default_profile()
        for ax in prof.axes.values():
            discrete_model(ax.drive, prof.machine.servo_period_s)
        heavy = [m for m in ("numba", "scipy.signal", "matplotlib", "dask", "distributed", "rich.table")
                 if m in sys.modules]
        print(heavy)
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


def test_scipy_linalg_leaves_numpys_extras_unloaded_until_used() -> None:
    # what ilcnc does before numba's first kernel and the drive models' expm: scipy.linalg then reads
    # numpy.f2py, numpy.testing, numpy.ma and numpy.polynomial without running them; they run (and work) when
    # first used
    res = _run_python("""
        import sys
        import numpy
        from ilcnc._lazy import defer_numpy_extras
        print(defer_numpy_extras())
        import scipy.linalg
        print("numpy.f2py.rules" in sys.modules, "unittest" in sys.modules)
        print("numpy.ma.core" in sys.modules, "numpy.polynomial.polynomial" in sys.modules)
        from numpy.testing import assert_array_equal
        assert_array_equal(scipy.linalg.expm(numpy.zeros((2, 2))), numpy.eye(2))
        assert numpy.ma.masked_array([1, 2], [0, 1]).sum() == 1 and numpy.polynomial.Polynomial([1, 2])(2.0) == 5.0
        print(numpy.f2py.__name__, "numpy.f2py.rules" in sys.modules or hasattr(numpy.f2py, "run_main"),
              "unittest" in sys.modules, defer_numpy_extras())
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == ["['numpy.f2py', 'numpy.testing', 'numpy.ma', 'numpy.polynomial']", "False False",
                                       "False False", "numpy.f2py True True []"]


def test_one_blas_thread_inside_the_block_and_the_previous_limit_after_it_from_two_threads() -> None:
    # the drive models' 4x4 expm runs in it (ilcnc.vcnc.lti): OpenBLAS's pool cost 300x the work there
    import threading
    import time

    import scipy.linalg
    from threadpoolctl import threadpool_info

    from ilcnc._threads import one_blas_thread

    def blas() -> list[int]:
        return sorted(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")

    before = blas()
    inside: list[list[int]] = []
    same: list[bool] = []

    def work() -> None:
        for _ in range(5):
            with one_blas_thread():
                inside.append(blas())
                m = np.array([[0.0, 1.0], [-4.0, -0.4]])
                same.append(np.array_equal(scipy.linalg.expm(m), scipy.linalg.expm(m)))
                time.sleep(0.001)

    threads = [threading.Thread(target=work) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert before and all(b == [1] * len(before) for b in inside) and len(inside) == 10 and all(same)
    assert blas() == before


def test_inspect_runs_without_numba() -> None:
    res = _run_python(f"""
        import sys
        from typer.testing import CliRunner
        from ilcnc.cli import app
        r = CliRunner().invoke(app, ["inspect", {str(ROOT / "samples" / "own" / "star.ngc")!r}, "--json"])
        assert r.exit_code == 0, r.output
        print("numba" in sys.modules, "scipy.signal" in sys.modules)
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["False", "False"]


# ---------------------------------------------------------------------------------------------
# A small job runs its kernels as Python (ilcnc._jit.kernels_for): no numba, the same numbers
# ---------------------------------------------------------------------------------------------

_STAR = str(ROOT / "samples" / "own" / "star.ngc")
_MILL = str(ROOT / "configs" / "example-mill.yaml")


@pytest.mark.parametrize("argv", [
    ["simulate", _STAR, "--profile", _MILL, "--json"],
    ["check", _STAR, "--profile", _MILL, "--max-error", "0.05"],
    # learn's corner report runs the output once more (a third run of 7,553 samples), which takes the process past
    # ilcnc._jit.SMALL_WORK: from there on it compiles, as designed; without the report learn stays in Python
    ["learn", _STAR, "--profile", _MILL, "--iterations", "1", "--corners", "0", "--force", "--out", "OUT"],
], ids=["simulate", "check", "learn"])
def test_a_small_program_command_does_not_import_numba(argv: list[str], tmp_path: Path) -> None:
    pytest.importorskip("numba")
    argv = [str(tmp_path / "star.ilc.ngc") if a == "OUT" else a for a in argv]
    res = _run_python(f"""
        import sys
        from typer.testing import CliRunner
        from ilcnc.cli import app
        r = CliRunner().invoke(app, {argv!r})
        assert r.exit_code == 0, r.output
        print("numba" in sys.modules)
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split()[-1] == "False"


def test_a_big_job_and_a_wide_search_import_numba() -> None:
    # spiral.ngc: 161k samples, over SMALL_WORK; seed000_corner.ngc: 8,001 samples, but 8,000 one-sample moves
    # make the contour search's windows ~740 segments wide: the numpy search would cost more than numba
    pytest.importorskip("numba")
    for prog, prof in (("samples/third_party/gcode/spiral.ngc", "configs/example-mill.yaml"),
                       ("samples/own/seed000_corner.ngc", "configs/seed000-paper-corner.yaml")):
        res = _run_python(f"""
            import sys
            from ilcnc.profile.load import load_profile
            from ilcnc.program import read_program
            from ilcnc.vcnc.run import run_virtual
            run_virtual(read_program({prog!r}), load_profile({prof!r}))
            print("numba" in sys.modules)
        """)
        assert res.returncode == 0, res.stderr
        assert res.stdout.split()[-1] == "True", prog


def test_the_exponential_cache_gives_scipys_numbers_bit_for_bit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    linalg = pytest.importorskip("scipy.linalg")
    from ilcnc.profile.load import load_profile
    from ilcnc.vcnc import discrete

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    folder = lti.expm_cache_dir()
    assert folder == tmp_path / "ilcnc-expm"
    # the block matrices of every shipped profile's drives, and random ones
    mats: list[np.ndarray] = []
    orig = lti.expm_cached
    monkeypatch.setattr(lti, "expm_cached", lambda m: (mats.append(np.array(m)), orig(m))[1])
    for config in CONFIGS:
        prof = load_profile(config)
        for ax in prof.axes.values():
            discrete.discrete_model(ax.drive, prof.machine.servo_period_s)
    rng = np.random.default_rng(24)
    mats += [rng.uniform(-50.0, 50.0, (n, n)) * 1e-3 for n in (2, 3, 5)]
    assert len(mats) > 10 and len(list(folder.iterdir())) >= 3
    for m in mats:
        first, again, want = orig(m), orig(m), linalg.expm(m)
        assert _same(first, want) and _same(again, want)
    # a damaged file is computed again (and written again)
    victim = sorted(folder.iterdir())[0]
    victim.write_bytes(victim.read_bytes()[:-1] + b"x")
    for m in mats:
        assert _same(orig(m), linalg.expm(m))
    # the folder holds at most EXPM_CACHE_MAX files: then nothing more is written, the answers stay right
    monkeypatch.setattr(lti, "EXPM_CACHE_MAX", len(list(folder.iterdir())))
    fresh = rng.uniform(-1.0, 1.0, (4, 4))
    n_files = len(list(folder.iterdir()))
    assert _same(orig(fresh), linalg.expm(fresh)) and len(list(folder.iterdir())) == n_files


def test_a_second_run_on_the_same_drives_imports_no_scipy(tmp_path: Path) -> None:
    code = f"""
        import sys
        from typer.testing import CliRunner
        from ilcnc.cli import app
        r = CliRunner().invoke(app, ["simulate", {_STAR!r}, "--profile", {_MILL!r}, "--json"])
        assert r.exit_code == 0, r.output
        print("scipy" in sys.modules, "numba" in sys.modules)
    """
    first = _run_python(code, NUMBA_CACHE_DIR=str(tmp_path))
    second = _run_python(code, NUMBA_CACHE_DIR=str(tmp_path))
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    assert first.stdout.split() == ["True", "False"]  # the first computes the exponentials
    assert second.stdout.split() == ["False", "False"]


#: (program, profile) run both ways: linear drives streamed, the friction loop, the cross-coupled controller,
#: a Klartext program on a second-order drive with dead time
_BOTH_WAYS = [("samples/own/star.ngc", "configs/example-mill.yaml"),
              ("samples/own/square.ngc", "configs/seed001-duong-p-ff-friction.yaml"),
              ("samples/own/square.ngc", "configs/seed003-li-cross-coupled.yaml"),
              ("samples/own/star.h", "configs/seed004-ward-sopdt.yaml")]


def test_python_kernels_agree_with_the_compiled_ones_within_ulps() -> None:
    """Each program run as Python (its kernels' py_func, the plan's, search's and E(k)'s numpy twins), then
    compiled, in one process: the samples, the contour error, the figures and E(k) agree to a few ulps.

    Tolerance, as tests/test_contour.py's ``_assert_same_error``: the numpy contour search computes the
    kernel's formulas, not its instructions (LLVM may contract ``a*b + c`` into one FMA, numpy's SIMD
    sin/cos/atan2 are not libm's); each distance or vector in mm is a chain of at most 16 operations on
    coordinates of magnitude at most R (the largest coordinate), so the two agree within 16 eps R, and so do
    the means, RMS and E(k) (weighted means of them). Measured (ulps of R): positions bit for bit; star.h's
    error vectors within 3.4, its distances within 0.8, its figures within 1e-4; the rest bit for bit.
    """
    pytest.importorskip("numba")
    res = _run_python(f"""
        import json, sys
        import numpy as np
        from ilcnc import _jit
        from ilcnc.profile.load import load_profile
        from ilcnc.program import read_program
        from ilcnc.vcnc.run import run_virtual

        def runs():
            out = []
            for prog, prof in {_BOTH_WAYS!r}:
                p, f = read_program(prog), load_profile(prof)
                s, w = run_virtual(p, f), run_virtual(p, f, keep_samples=True)
                out.append(dict(
                    figures=[s.stats[k] for k in ("max", "mean", "rms")] + [s.air_stats[k] for k in ("max", "mean", "rms")]
                    + [w.stats[k] for k in ("max", "mean", "rms")] + [s.cycle_time_s, w.cycle_time_s],
                    n=[s.n_samples, w.n_samples], actual=w.actual_mm, dist=w.error.dist_mm, vec=w.error.vector_mm,
                    # E(k) where the run went chunk by chunk (the friction and cross-coupled loops run whole)
                    e=s.signal.e_mm if hasattr(s, "signal") else np.zeros(1),
                    valid=s.signal.valid if hasattr(s, "signal") else np.zeros(1, bool)))
            return out

        python = runs()   # ILCNC_SMALL_WORK is huge: every kernel as Python
        assert "numba" not in sys.modules
        _jit.compiled_for(0)  # outside a Python block: imports numba
        assert _jit.numba_loaded()
        compiled = runs()

        def ulps(a, b, r):  # the largest difference in ulps of r (the run's largest coordinate, mm)
            a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
            assert a.shape == b.shape and np.array_equal(np.isnan(a), np.isnan(b))
            ok = np.isfinite(b)
            return float(np.max(np.abs(a[ok] - b[ok]), initial=0.0) / (r * np.finfo(float).eps))

        report = []
        for x, y in zip(python, compiled):
            assert x["n"] == y["n"] and np.array_equal(x["valid"], y["valid"])
            r = float(np.max(np.abs(y["actual"])))
            report.append({{"figures": ulps(x["figures"], y["figures"], r), "actual": ulps(x["actual"], y["actual"], r),
                           "dist": ulps(x["dist"], y["dist"], r), "vector": ulps(x["vec"], y["vec"], r),
                           "e": ulps(x["e"], y["e"], r)}})
        print(json.dumps(report))
    """, ILCNC_SMALL_WORK=str(10**12))
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout.splitlines()[-1])
    assert len(report) == len(_BOTH_WAYS)
    for (prog, prof), r in zip(_BOTH_WAYS, report, strict=True):
        assert max(r.values()) <= 16.0, (prog, prof, r)


def test_kernels_wait_for_their_first_call_then_are_numbas_everywhere() -> None:
    pytest.importorskip("numba")
    res = _run_python("""
        import sys
        from ilcnc import _jit
        from ilcnc.vcnc import plan_kernels
        from ilcnc.contour import search
        assert type(plan_kernels.group_kernel) is _jit.LazyKernel
        assert plan_kernels.group_kernel.py_func.__name__ == "group_kernel"
        assert "numba" not in sys.modules and not _jit.numba_loaded()
        assert _jit.set_component(1.0, 2.0, 3.0, 1, 9.0) == (1.0, 9.0, 3.0)   # the first call loads numba
        from numba.core.dispatcher import Dispatcher
        assert _jit.numba_loaded()
        for obj in (plan_kernels.group_kernel, search._k_chunk, search.set_component, _jit.set_component):
            assert isinstance(obj, Dispatcher), obj
        assert not isinstance(search._bits_of, _jit.LazyKernel)
        assert search.types is sys.modules["numba"].types
        # numba's BLAS check passed without importing scipy.linalg; importing it later works as ever
        from numba.np import arraymath
        assert arraymath._HAVE_BLAS and "scipy.linalg" not in sys.modules
        import numpy, scipy.linalg
        assert scipy.linalg.cython_blas.__name__ == "scipy.linalg.cython_blas"
        assert scipy.linalg.expm(numpy.zeros((2, 2)))[1, 1] == 1.0
        made_later = _jit.njit(cache=False)(lambda x: x + 1)
        assert isinstance(made_later, Dispatcher)
        print("ok")
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"


def test_a_kernel_that_has_to_compile_says_so_once_on_stderr() -> None:
    pytest.importorskip("numba")
    res = _run_python("""
        import json
        from ilcnc import _jit

        def f(n):
            s = 0.0
            for i in range(n):
                s += i * 0.5
            return s

        def g(n):
            return f(n) + 1.0

        f.__module__ = g.__module__ = "ilcnc.fake"
        kf = _jit.njit(cache=False)(f)
        kg = _jit.njit(cache=False)(g)
        g.__globals__["f"] = kf
        assert kg(4) == 4.0 and kf(3) == 1.5
        print(json.dumps(_jit.compile_stats()))
    """)
    assert res.returncode == 0, res.stderr
    assert res.stderr.splitlines() == [_jit_notice()]
    st = json.loads(res.stdout)
    assert [name for name, _ in st["compiled"]] == ["fake.f", "fake.g"]  # f compiled inside g's compile
    assert st["seconds"] > 0


def _jit_notice() -> str:
    from ilcnc._jit import COMPILE_NOTICE

    return COMPILE_NOTICE


# ---------------------------------------------------------------------------------------------
# ilcnc selftest (the command's wiring; the work is the usual commands', tested where they are)
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("ok", [True, False])
def test_selftest_command_reports_its_steps_and_fails_on_bad_figures(ok: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    from ilcnc.cli import app
    from ilcnc.shop import selftest as st

    def fake(progress=None):
        if progress is not None:
            progress("simulate (chunk by chunk)")
        return st.SelftestResult(steps=[("simulate (chunk by chunk)", 0.5, "max 12.94 µm")], compiled=3,
                                 compile_s=20.0, ok=ok)

    monkeypatch.setattr(st, "run_selftest", fake)
    r = CliRunner().invoke(app, ["selftest"])
    assert r.exit_code == (0 if ok else 1), r.output
    assert "simulate (chunk by chunk)" in r.output
    assert ("selftest ok" if ok else "selftest FAILED") in r.output
    assert "compiled 3 kernels in 20.0 s" in r.output
    r = CliRunner().invoke(app, ["selftest", "--json"])
    assert r.exit_code == (0 if ok else 1)
    got = json.loads(r.stdout)
    assert got["ok"] is ok and got["compiled"] == 3 and got["steps"][0]["figure"] == "max 12.94 µm"


# ---------------------------------------------------------------------------------------------
# The command line itself: what it imports, the one command it builds, option values without pydantic
# ---------------------------------------------------------------------------------------------

#: What the command line must not import before a command needs it: typer's pydantic coercion and rich's
#: Markdown (markdown_it) are for values ilcnc.cli_values does not answer and for help; the rest is work.
_NOT_AT_START = ("pydantic", "markdown_it", "rich.markdown", "scipy", "matplotlib", "numpy", "numba", "yaml")


def test_importing_the_command_line_imports_no_heavy_module() -> None:
    res = _run_python(f"""
        import sys
        import ilcnc.cli
        print([m for m in {_NOT_AT_START!r} if m in sys.modules])
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


@pytest.mark.parametrize("argv", [
    ["inspect", _STAR, "--json"],
    ["check", _STAR, "--profile", _MILL, "--max-error", "0.05"],
    ["simulate", _STAR, "--profile", _MILL, "--json", "--corners", "3"],
    ["check", _STAR, str(ROOT / "samples" / "own" / "square.ngc"), "--profile", _MILL, "--max-error", "0.05",
     "--json"],
], ids=["inspect", "check", "simulate", "check-many"])
def test_a_command_builds_only_itself_and_parses_its_options_without_pydantic(argv: list[str]) -> None:
    # as the shell runs it: ilcnc.cli.main with sys.argv
    res = _run_python(f"""
        import sys
        import typer.main
        built = []
        orig = typer.main.get_command_from_info
        def counted(*args, **kw):
            built.append((args[0] if args else kw["command_info"]).callback.__name__)
            return orig(*args, **kw)
        typer.main.get_command_from_info = counted
        sys.argv = ["ilcnc", *{argv!r}]
        from ilcnc.cli import main
        try:
            main()
        except SystemExit as exc:
            assert not exc.code, exc.code
        print(built, [m for m in ("pydantic", "markdown_it", "rich.markdown", "scipy.signal", "matplotlib")
                      if m in sys.modules])
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[-1] == f"{[argv[0]]} []"


def _commands() -> list[tuple[str, ...]]:
    import typer.main

    from ilcnc.cli import app

    out: list[tuple[str, ...]] = []

    def walk(cmd: object, path: tuple[str, ...]) -> None:
        subs = getattr(cmd, "commands", None)
        if subs is None:
            out.append(path)
        for name, sub in (subs or {}).items():
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return out


@pytest.mark.parametrize("args", [["--help"], ["--bogus"], ["--debug", "a", "b", "c", "d"]],
                         ids=["help", "bad-option", "too-many-arguments"])
def test_the_one_command_app_says_what_the_whole_app_says(args: list[str]) -> None:
    from ilcnc.cli import app

    commands = _commands()
    assert len(commands) >= 14 and ("linuxcnc", "run") in commands
    runner = CliRunner()
    for path in commands:
        argv = [*path, *args]
        trimmed = app.only(argv)
        assert trimmed is not app and [c.callback.__name__ for c in trimmed.registered_commands] in ([path[0]], [])
        whole, one = runner.invoke(app, argv, prog_name="ilcnc"), runner.invoke(trimmed, argv, prog_name="ilcnc")
        assert (one.exit_code, one.stdout, one.stderr) == (whole.exit_code, whole.stdout, whole.stderr), argv
    # no command, a root option first, an unknown name, shell completion: the whole app
    for argv in ([], ["--debug", "check"], ["chek"], ["--help"]):
        assert app.only(argv) is app


def test_shell_completion_sees_every_command(monkeypatch: pytest.MonkeyPatch) -> None:
    from ilcnc.cli import app

    monkeypatch.setenv("_ILCNC_COMPLETE", "bash_complete")
    assert app.only(["check"]) is app


#: Option texts: plain ones ilcnc.cli_values answers, and ones typer must (whitespace, underscores, inf, nan,
#: other digits, hex, empty, out of range), for every parameter of every command.
_TEXTS = ["0", "1", "-1", "+2", "0.05", ".5", "5.", "1e-3", "1E+3", "-0", "007", "8", "9", "100", "101", "256", "1000",
          "1001", "10000", "1e6", "1e7", "1e400", "0.000001", "1e-7", "123456789012345678", "1234567890123456789",
          " 1", "1 ", "1_000", "inf", "-inf", "nan", "Infinity", "0x10", "", "abc", "1e", "٣", "1.5.2", "--", "-",
          "samples/own/star.ngc", "samples", "missing.ngc", ".", "configs/example-mill.yaml", "x\ty"]


def test_plain_option_values_are_what_typers_coercion_gives(monkeypatch: pytest.MonkeyPatch) -> None:
    """ilcnc.cli_values against typer's own coercion (pydantic), value by value, on every parameter."""
    import typer.main
    from typer._click import Context
    from typer._coercion import build_runtime_param

    from ilcnc.cli import app
    from ilcnc.cli_values import PlainValue

    monkeypatch.chdir(ROOT)

    def outcome(coerce: object, value: object, param: object, ctx: object) -> tuple[str, str]:
        try:
            got = coerce(value, param=param, ctx=ctx)  # type: ignore[operator]
        except Exception as exc:  # the same error (type and message) is the point
            return type(exc).__name__, str(getattr(exc, "message", exc))
        return type(got).__name__, repr(got) + repr([type(v).__name__ for v in got] if isinstance(got, list) else "")

    root = typer.main.get_command(app)
    params = []
    stack = [root]
    while stack:
        cmd = stack.pop()
        stack += list(getattr(cmd, "commands", {}).values())
        ctx = Context(cmd)
        params += [(cmd, ctx, p) for p in [*cmd.params, cmd.get_help_option(ctx)] if hasattr(p, "type_descriptor")]
    kinds: dict[str, int] = {}
    plain = 0
    for _cmd, ctx, p in params:
        mine = PlainValue(p)
        theirs = build_runtime_param(p.type_descriptor)
        multi = p.multiple or p.nargs == -1
        values: list[object] = [None, p.default, True, False, 3, 2.5, *_TEXTS]
        if multi:
            values += [tuple(_TEXTS[i:i + 2]) for i in range(0, len(_TEXTS), 2)] + [(), ["1", "2"]]
        for v in values:
            want = outcome(theirs.coerce, v, p, ctx)
            mine._typer = None
            got = outcome(mine.coerce, v, p, ctx)
            assert got == want, (p.name, v)
            plain += mine._typer is None and v is not None
        kinds[p.type_descriptor.annotation.__name__ if hasattr(p.type_descriptor.annotation, "__name__")
              else str(p.type_descriptor.annotation)] = 1
    # every kind of parameter the commands have was seen, and most values were answered without typer
    assert {"Path", "str", "float", "int", "bool"} <= set(kinds) and any("list" in k for k in kinds)
    assert plain > len(params) * 15


@pytest.mark.parametrize(("argv", "value"), [
    (["check", _STAR, "--profile", _MILL, "--max-error", "0.05"], None),
    (["simulate", _STAR, "--profile", _MILL, "--corners", "7"], None),
])
def test_a_usual_command_line_never_builds_typers_coercion(argv: list[str], value: None,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    import typer._coercion

    from ilcnc.cli import app

    built: list[object] = []
    orig = typer._coercion.build_runtime_param
    monkeypatch.setattr(typer._coercion, "build_runtime_param", lambda d: (built.append(d), orig(d))[1])
    r = CliRunner().invoke(app, argv)
    assert r.exit_code in (0, 1), r.output
    assert built == []
