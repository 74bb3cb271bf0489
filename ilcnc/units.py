"""Units and axis names, declared once.

Unit-suffix convention (as Klipper's): a name ends in its unit -- ``_mm``, ``_s``, ``_mm_s``
(mm/s), ``_mm_min`` (mm/min), ``_m_s2`` (m/s²), ``_m_s3`` (m/s³), ``_hz``, ``_rad_s``, ``_um``
(µm, in reports only), ``_pct``. Lengths inside ilcnc are millimetres and times seconds unless
the name says otherwise; a profile key in other units is converted once, when it is loaded.

Axis names: ``AXIS_NAMES`` in profiles, logs and JSON (lower case), ``AXIS_LETTERS`` in part
programs (upper case, the words of G-code and Klartext), ``CENTER_LETTERS`` for arc centres.
"""

from __future__ import annotations

__all__ = ["AXIS_LETTERS", "AXIS_NAMES", "CENTER_LETTERS", "LENGTH_UNITS", "MM_PER_INCH", "length_word"]

#: Millimetres per inch (exact, by definition).
MM_PER_INCH = 25.4
#: The length units a program, a profile or a log may be in.
LENGTH_UNITS: tuple[str, ...] = ("mm", "inch")
#: The linear axes, lower case, in this order (profiles, logs, JSON).
AXIS_NAMES: tuple[str, ...] = ("x", "y", "z")
#: The linear axes' words in a part program, upper case, in this order.
AXIS_LETTERS = "XYZ"
#: The arc-centre words belonging to X, Y and Z.
CENTER_LETTERS = "IJK"


def length_word(v_mm: float, units: str) -> str:
    """A length for a program word (``G64 P``, cycle 32 ``T``) in the program's ``units``: 4 decimals of mm, 5 of
    inch, trailing zeros dropped (0.0125 mm is ``0.0125``; in inch ``0.00049``)."""
    if units == "inch":
        return f"{v_mm / MM_PER_INCH:.5f}".rstrip("0").rstrip(".")
    return f"{v_mm:.4f}".rstrip("0").rstrip(".")
