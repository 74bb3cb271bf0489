"""Shared test fixtures: paths of the third-party samples in ../shared."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
SAMPLES = SHARED / "samples"
OWN = REPO / "samples" / "own"


def sample_files(*folders: str) -> list[Path]:
    """Every program file in the given ../shared/samples folders (sorted)."""
    out: list[Path] = []
    for folder in folders:
        d = SAMPLES / folder
        out.extend(sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() not in (".tsv", ".md")))
    return out


@pytest.fixture(scope="session")
def samples_dir() -> Path:
    if not SAMPLES.is_dir():
        pytest.fail(f"../shared/samples not found at {SAMPLES}")
    return SAMPLES
