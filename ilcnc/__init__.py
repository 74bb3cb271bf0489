"""ilcnc: iterative learning control for CNC part programs.

Reads a part program (G-code or Heidenhain Klartext), predicts or measures how
the machine really moves, and rewrites the G01 end points with learned
corrections.

The packages, from the bottom layer up (``docs/architecture.md``; imports point
down only, ``tests/test_architecture.py`` checks it):

- :mod:`ilcnc.errors`, :mod:`ilcnc.units`, :mod:`ilcnc.fileio`: the error root, units, atomic files;
- :mod:`ilcnc.program`, :mod:`ilcnc.profile`, :mod:`ilcnc.axislog`: part programs, machine profiles, axis logs;
- :mod:`ilcnc.contour`: the path, the exact contour error, cutting and air moves;
- :mod:`ilcnc.vcnc`: the virtual CNC (planners, drives, error sources, a run and its ``E(k)``);
- :mod:`ilcnc.learning`: learning laws, the learning loop, refinement, tuning, identification;
- :mod:`ilcnc.shop`: the shop workflow (measurements, state, batch, LinuxCNC, reports, export);
- :mod:`ilcnc.cli`: the command line.
"""

from ilcnc._moved import install as _install_moved

__version__ = "0.1.0"

__all__ = ["__version__"]

_install_moved()
