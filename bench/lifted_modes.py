"""Where the growing modes of tune's lifted check sit (issue 18: the Q filter against the measurements).

Usage::

    python bench/lifted_modes.py                                  # jsdc.gcode, configs/linuxcnc-sim.yaml
    python bench/lifted_modes.py PROG --profile P.yaml --q 20 60 --gamma 0.5 --shift 52

``ilcnc tune PROG --method lifted`` builds the lifted map G of a window of commands (the 200 whose
error is largest) and judges each (Γ, Q filter) by the spectral radius ρ of the iteration matrix
``I − Γ G Q S`` on the errors normal to the path. For each candidate this prints ρ, the n-step
prediction ‖Eₙ‖/‖E₀‖ (n = the profile's iterations) that the measured runs can be held against, and
where the modes with |λ| > 1 sit: how many there are, and the share of each one's energy within the
first and last ``--edge`` commands of the window (mean and least over those modes). With ``--shift N``
it does the same on the window moved by N commands: a mode of the program stays on its commands, a
mode of the window's cut edge moves with the edge.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcnc.learning import lifted_check as lc  # noqa: E402
from ilcnc.learning.laws import cut_runs  # noqa: E402
from ilcnc.learning.learner import correctable_commands  # noqa: E402
from ilcnc.profile import load_profile  # noqa: E402
from ilcnc.program import read_program  # noqa: E402


def report(prog, prof, window: tuple[int, int] | None, qs: list[float], gammas: list[float],
           edge: int) -> tuple[int, int]:
    mdl = lc.lifted_model(prog, prof, commands=window)
    runs, corr = cut_runs(prog), correctable_commands(prog)
    k0, k1 = mdl.window
    cut_edges = [k0 > 0 and runs[k0 - 1] == runs[k0], k1 < len(runs) and runs[k1] == runs[k1 - 1]]
    print(f"window commands {k0}..{k1 - 1} (lines {int(prog.moves.line[prog.command_moves[k0]])}.."
          f"{int(prog.moves.line[prog.command_moves[k1 - 1]])}); start cuts a run: {cut_edges[0]}, "
          f"end cuts a run: {cut_edges[1]}; {mdl.n} coordinates")
    b = mdl.normal_basis
    near = (mdl.command < k0 + edge) | (mdl.command >= k1 - edge)
    n_it = int(prof.learning.iterations)
    e0 = mdl.e0_mm
    for q in qs:
        qm = lc._q_matrix(mdl, runs, corr, None if q <= 0 else q, int(prof.learning.lead_commands),
                          prof.machine.servo_period_s)
        for gam in gammas:
            m = np.eye(mdl.n) - gam * mdl.g @ qm
            lam, vec = np.linalg.eig(b.T @ m @ b)
            energy = np.abs(b @ vec) ** 2
            energy /= energy.sum(axis=0)
            share = energy[near].sum(axis=0)
            grow = np.abs(lam) > 1.0 + lc.RHO_TOL
            e = e0.copy()
            for _ in range(n_it):
                e = m @ e
            ratio = float(np.linalg.norm(e) / np.linalg.norm(e0))
            where = (f"{int(grow.sum())} growing, energy in the {edge} edge commands: mean {share[grow].mean():.0%}, "
                     f"least {share[grow].min():.0%}") if grow.any() else "none growing"
            print(f"  Q {q:5g} Hz, Γ {gam:g}: ρ {np.abs(lam).max():.6f} (×{np.abs(lam).max() ** n_it:.3f} in {n_it}"
                  f" iterations), ‖E{n_it}‖/‖E0‖ {ratio:.3f}; {where}")
    return k0, k1


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("program", nargs="?", type=Path, default=ROOT / "samples" / "jsdc.gcode")
    ap.add_argument("--profile", type=Path, default=ROOT / "configs" / "linuxcnc-sim.yaml")
    ap.add_argument("--q", type=float, nargs="+", default=[0, 5, 20, 60], help="Q filter cut-offs, Hz (0: none)")
    ap.add_argument("--gamma", type=float, nargs="+", default=[0.5, 1.0])
    ap.add_argument("--edge", type=int, default=10)
    ap.add_argument("--shift", type=int, default=52)
    a = ap.parse_args(argv)
    prof = load_profile(a.profile)
    prog = read_program(a.program)
    first = report(prog, prof, None, a.q, a.gamma, a.edge)
    if a.shift:
        k0 = max(0, first[0] + a.shift)
        report(prog, prof, (k0, k0 + first[1] - first[0]), a.q, a.gamma, a.edge)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
