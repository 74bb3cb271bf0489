"""Conversion under fuzzing (issue 20 acceptance): mutated lines of real programs, converted to the other dialect.

The cases are those of :mod:`tests.test_fuzz` (a sample or a window of a big one, one to three mutated lines).
A case whose program the reader runs in full is exported to the other dialect; the only allowed outcomes are

* a refusal: one of ilcnc's own errors, naming the program and a line, and no output file; or
* an output that the reader runs in full, with the same motion as the source (every move's kind, machine flag and
  end point within the written decimals) and the same machining words in the same order.

2,000 examples per dialect, derandomized (the same cases on every run).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, note, settings

from ilcnc.errors import IlcncError
from ilcnc.program import read_program
from ilcnc.shop.export import export_program

from .test_convert_safety import _machining, _same_motion
from .test_fuzz import (
    DEADLINE_MS,
    GCODE_SAMPLES,
    GCODE_TOKENS,
    HARD_LIMIT_S,
    HEIDENHAIN_SAMPLES,
    HEIDENHAIN_TOKENS,
    Case,
    cases,
    hard_time_limit,
)

EXAMPLES = 2_000
SETTINGS = settings(max_examples=EXAMPLES, derandomize=True, database=None, deadline=DEADLINE_MS, print_blob=True)


def check_conversion(case: Case, tmp: Path) -> None:
    path = case.sample.path
    with hard_time_limit(HARD_LIMIT_S):
        try:
            src = read_program(path, data=case.data)
        except IlcncError:
            return  # the reader's own refusals are test_fuzz's business
        if src.unsupported is not None or src.unmodelled is not None:
            return
        name = f"case-{abs(hash(case.data)) % 10**9}"
        src_file = tmp / (name + path.suffix)
        src_file.write_bytes(case.data)
        out = tmp / (name + (".ngc" if src.dialect == "heidenhain" else ".h"))
        try:
            export_program(src_file, out)
        except IlcncError as exc:
            assert getattr(exc, "line", None) is not None or "arc" in str(exc), str(exc)
            assert not out.exists()
            return
        back = read_program(out)
        note(out.read_text(encoding="latin-1")[:2000])
        assert back.unsupported is None, back.unsupported
        tol = 6e-4 * (25.4 if src.units == "inch" else 1.0)
        _same_motion(src, back, tol)
        assert _machining(back) == _machining(src)


@pytest.mark.slow
@SETTINGS
@given(case=cases(GCODE_SAMPLES, GCODE_TOKENS))
def test_gcode_to_klartext_under_fuzzing(case: Case, tmp_path_factory: pytest.TempPathFactory) -> None:
    check_conversion(case, tmp_path_factory.mktemp("conv"))


@pytest.mark.slow
@SETTINGS
@given(case=cases(HEIDENHAIN_SAMPLES, HEIDENHAIN_TOKENS))
def test_klartext_to_gcode_under_fuzzing(case: Case, tmp_path_factory: pytest.TempPathFactory) -> None:
    check_conversion(case, tmp_path_factory.mktemp("conv"))
