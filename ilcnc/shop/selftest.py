"""``ilcnc selftest``: run the usual commands' work once on a small program, so the compiled kernels are cached.

The first run after an install compiles ilcnc's numba kernels (20-40 s; numba keeps them in its cache,
``__pycache__`` beside the sources or ``NUMBA_CACHE_DIR``, and later runs load them in milliseconds).
``ilcnc selftest`` pays that once, as an install step (a Dockerfile's ``RUN``, a CI job's set-up), instead
of the first real command: it reads a small built-in program (a five-pointed star, the same as
``samples/own/star.ngc``) and a generated long one (the reader's compiled scanner), runs it on the built-in
machine (the example mill of ``configs/example-mill.yaml``) chunk by chunk as ``ilcnc simulate`` and
``ilcnc check`` do, with every sample kept as ``simulate --log-out`` does, and learns one iteration as
``ilcnc learn`` does, and checks that the figures are finite. A profile with other drive models
(friction, a cross-coupled controller) compiles its own kernels on its first run.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ilcnc.wording import plural

__all__ = ["SelftestResult", "run_selftest"]

#: ``samples/own/star.ngc``: 12 G01 commands around a star, 9,779 samples at 1 ms on the example mill.
STAR = """(ilcnc selftest: five-pointed star, 40 mm outer radius)
G21 G90 G17 G64 P0.02 Q0
G0 X0 Y40 Z5
G1 Z-1 F600
G1 X-9.405 Y12.944 F2500
G1 X-38.042 Y12.361 F2500
G1 X-15.217 Y-4.944 F2500
G1 X-23.511 Y-32.361 F2500
G1 X-0.000 Y-16.000 F2500
G1 X23.511 Y-32.361 F2500
G1 X15.217 Y-4.944 F2500
G1 X38.042 Y12.361 F2500
G1 X9.405 Y12.944 F2500
G1 X0.000 Y40.000 F2500
G0 Z5
M2
"""


@dataclass(slots=True)
class SelftestResult:
    """What the self-test ran (``steps``: name, seconds, a figure) and what it compiled."""

    steps: list[tuple[str, float, str]] = field(default_factory=list)
    compiled: int = 0
    compile_s: float = 0.0
    ok: bool = True


def run_selftest(progress: Callable[[str], None] | None = None) -> SelftestResult:
    """Run the self-test (see the module docstring); ``progress`` is told each step's name as it starts."""
    from ilcnc._jit import compile_stats
    from ilcnc.learning.learner import learn_virtual
    from ilcnc.profile.load import default_profile
    from ilcnc.program import read_program
    from ilcnc.program.gcode_plain import SCANNER_MIN_LINES
    from ilcnc.vcnc.run import simulate_figures
    from ilcnc.vcnc.simulate import simulate_program

    res = SelftestResult()
    before = compile_stats()
    profile = default_profile()

    def step(name: str, fn: Callable[[], str]) -> None:
        if progress is not None:
            progress(name)
        t = time.perf_counter()
        figure = fn()
        res.steps.append((name, time.perf_counter() - t, figure))

    def um(x: float) -> str:
        res.ok &= math.isfinite(x)
        return f"{x * 1e3:.2f} µm"

    with tempfile.TemporaryDirectory(prefix="ilcnc-selftest-") as tmp:
        star_path = Path(tmp) / "star.ngc"
        star_path.write_text(STAR, encoding="ascii")
        long_path = Path(tmp) / "long.ngc"
        lines = ["G21 G90 G17", "G0 X0 Y0 Z1", "G1 Z-1 F1000"]
        lines += [f"G1 X{(i % 50) * 0.2:.3f} Y{(i // 50) * 0.2:.3f}" for i in range(SCANNER_MIN_LINES)]
        long_path.write_text("\n".join([*lines, "M2", ""]), encoding="ascii")
        star = read_program(star_path, default_units=profile.machine.units)
        step("read a long program", lambda: plural(len(read_program(long_path).moves), "move"))

        def rewrite() -> str:  # a rewrite of a long program reads and spells its numbers in compiled loops
            import numpy as np

            from ilcnc.program.rewrite import apply_corrections

            long = read_program(long_path)
            corr = np.zeros((long.n_commands, 3))
            corr[:, 0] = 0.001
            return plural(len(apply_corrections(long, corr, min_decimals=3)[1]), "number") + " rewritten"

        step("rewrite a long program", rewrite)
        step("simulate (chunk by chunk)", lambda: "max " + um(simulate_figures(star, profile).stats.max_mm))
        step("simulate (every sample)", lambda: "max " + um(simulate_program(star, profile).stats.max_mm))
        def learn() -> str:
            r = learn_virtual(star, profile, iterations=1)
            return f"max {um(r.iterations[0].stats['max'])} (iteration 0), {um(r.iterations[-1].stats['max'])} (1)"

        step("learn (1 iteration)", learn)
    after = compile_stats()
    res.compiled = len(after["compiled"]) - len(before["compiled"])
    res.compile_s = after["seconds"] - before["seconds"]
    return res
