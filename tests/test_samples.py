"""The third-party samples in the repository: samples/MANIFEST.tsv against the files.

Every row names a file under ``samples/`` (its ``file`` column is the path relative
to ``samples/``) with its source, licence, SHA-256, number of lines (a last line
without a newline counts) and whether it has CRLF line ends. The copies in
``samples/third_party/`` are byte-for-byte copies of ``../shared/samples``; when
``../shared`` is beside the repository they are compared with it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from .conftest import REPO, SAMPLES, SHARED, SHARED_SAMPLES, TEST_ONLY, sample_files, shared_present

MANIFEST = REPO / "samples" / "MANIFEST.tsv"
COLUMNS = ["file", "repo", "path_in_repo", "commit", "license", "sha256", "lines", "crlf", "notes"]
FOLDERS = ("gcode", "contour", "interp", "heidenhain", "large")
SHARED_MANIFESTS = ("MANIFEST-gcode.tsv", "MANIFEST-heidenhain.tsv")


def _rows(path: Path) -> list[dict[str, str]]:
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0].split("\t") == COLUMNS, path
    rows = [dict(zip(COLUMNS, line.split("\t"), strict=True)) for line in lines[1:]]
    return rows


def _n_lines(data: bytes) -> int:
    return data.count(b"\n") + (1 if data and not data.endswith(b"\n") else 0)


ROWS = _rows(MANIFEST)
VENDORED = [r for r in ROWS if r["file"].startswith("third_party/")]


def _needs_shared() -> None:
    if not shared_present():
        pytest.skip(f"compares with ../shared/samples; ../shared not found at {SHARED}")


def test_manifest_lists_every_sample_once():
    files = [r["file"] for r in ROWS]
    assert len(files) == len(set(files))
    on_disk = sorted(str(p.relative_to(REPO / "samples")) for p in SAMPLES.rglob("*") if p.is_file())
    assert sorted(r["file"] for r in VENDORED) == on_disk
    assert {Path(f).parts[1] for f in on_disk} == set(FOLDERS)
    assert len(VENDORED) == 50
    # the four copies at the top of samples/ (README examples) are still there
    assert sorted(f for f in files if "/" not in f) == ["circle-inch.gcode", "compass.ngc", "jsdc.gcode", "scorpion.nc"]


def test_no_test_only_sample_is_in_the_repository():
    for r in ROWS:
        assert "TEST-ONLY" not in r["notes"], r["file"]
    for folder, names in TEST_ONLY.items():
        for name in names:
            assert not (SAMPLES / folder / name).exists()
            assert not any(p.name == name for p in (REPO / "samples").rglob("*"))


@pytest.mark.parametrize("row", ROWS, ids=lambda r: r["file"])
def test_row_matches_the_file(row):
    data = (REPO / "samples" / row["file"]).read_bytes()
    assert hashlib.sha256(data).hexdigest() == row["sha256"]
    assert _n_lines(data) == int(row["lines"])
    assert row["crlf"] == ("yes" if b"\r\n" in data else "no")
    assert len(row["commit"]) == 40 and int(row["commit"], 16) >= 0
    assert row["repo"].count("/") == 1 and row["path_in_repo"] and row["license"]


def test_gitattributes_keeps_the_bytes():
    rules = (REPO / ".gitattributes").read_text().split("\n")
    assert "samples/** -text" in rules
    crlf = [r["file"] for r in ROWS if r["crlf"] == "yes"]
    assert len(crlf) >= 4
    for f in crlf:
        assert b"\r\n" in (REPO / "samples" / f).read_bytes()


def test_sample_files_are_the_vendored_copies():
    vendored = {str(p.relative_to(SAMPLES)) for p in sample_files(*FOLDERS) if p.is_relative_to(SAMPLES)}
    assert vendored == {r["file"].removeprefix("third_party/") for r in VENDORED}
    others = [p for p in sample_files(*FOLDERS) if not p.is_relative_to(SAMPLES)]
    assert sorted(p.name for p in others) == (sorted(TEST_ONLY["heidenhain"]) if shared_present() else [])


# --------------------------------------------------------------------------- against ../shared


def test_vendored_copies_equal_the_shared_ones():
    _needs_shared()
    for r in VENDORED:
        rel = r["file"].removeprefix("third_party/")
        assert (SAMPLES / rel).read_bytes() == (SHARED_SAMPLES / rel).read_bytes(), rel


def test_every_shared_sample_is_vendored_or_test_only():
    _needs_shared()
    shared = sorted(str(p.relative_to(SHARED_SAMPLES)) for folder in FOLDERS
                    for p in (SHARED_SAMPLES / folder).iterdir() if p.is_file())
    test_only = sorted(f"{f}/{n}" for f, names in TEST_ONLY.items() for n in names)
    vendored = sorted(r["file"].removeprefix("third_party/") for r in VENDORED)
    assert sorted(vendored + test_only) == shared


def test_rows_are_the_shared_manifest_rows():
    """Same source, licence, hash and notes as ../shared's manifests; TEST-ONLY there is exactly conftest's list.

    ``lines`` may differ: MANIFEST-gcode.tsv counts newlines (``wc -l``), so a file without a final newline
    has one line less there; samples/MANIFEST.tsv counts that last line like MANIFEST-heidenhain.tsv.
    """
    _needs_shared()
    shared = {r["file"]: r for m in SHARED_MANIFESTS for r in _rows(SHARED_SAMPLES / m)}
    test_only = sorted(f for f, r in shared.items() if "TEST-ONLY" in r["notes"])
    assert test_only == sorted(f"{f}/{n}" for f, names in TEST_ONLY.items() for n in names)
    assert sorted(r["file"].removeprefix("third_party/") for r in VENDORED) == sorted(set(shared) - set(test_only))
    for r in VENDORED:
        s = shared[r["file"].removeprefix("third_party/")]
        for col in COLUMNS[1:]:
            if col == "lines":
                data = (SHARED_SAMPLES / s["file"]).read_bytes()
                assert int(s[col]) in (int(r[col]), data.count(b"\n")), (r["file"], col)
            else:
                assert r[col] == s[col], (r["file"], col)
