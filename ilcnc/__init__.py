"""ilcnc: iterative learning control for CNC part programs.

Reads a part program (G-code or Heidenhain Klartext), predicts or measures how
the machine really moves, and rewrites the G01 end points with learned
corrections.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
