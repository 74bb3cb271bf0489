"""Shared test fixtures: paths of the third-party samples.

The samples are copied byte for byte into ``samples/third_party/`` (licence lines in
``samples/MANIFEST.tsv``), so the tests need nothing beside the repository. Only the
TEST-ONLY files (doubtful licence: never copied into the repository) are read from
``../shared/samples``; a test that needs one skips with the reason when ``../shared``
is not there.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "samples" / "third_party"
OWN = REPO / "samples" / "own"
SHARED = REPO.parent / "shared"
SHARED_SAMPLES = SHARED / "samples"

#: TEST-ONLY samples (notes in ../shared/samples/MANIFEST-heidenhain.tsv): read from ../shared, never copied
TEST_ONLY: dict[str, tuple[str, ...]] = {
    "heidenhain": ("lk_668.h", "lk_700.h", "lk_7025.h", "lk_BewegBlv.h", "lk_Krivka.h", "lk_SLII001.h",
                   "lk_zirkularnut-fraesen.h"),
}


def _is_program(p: Path) -> bool:
    return p.is_file() and p.suffix.lower() not in (".tsv", ".md")


def shared_present() -> bool:
    return SHARED_SAMPLES.is_dir()


def shared_sample_reason(folder: str, name: str | None = None) -> str:
    """Why a test that needs a TEST-ONLY sample (or all of ``folder``'s) skips without ../shared."""
    what = f"../shared/samples/{folder}/{name}" if name else f"the TEST-ONLY samples of ../shared/samples/{folder}"
    where = f"not in {SHARED_SAMPLES / folder}" if SHARED_SAMPLES.is_dir() else f"../shared not found at {SHARED}"
    return f"needs {what} (TEST-ONLY licence, never in the repository); {where}"


def shared_sample_path(folder: str, name: str) -> Path | None:
    """The TEST-ONLY sample in ../shared, or None when it is not there."""
    if name not in TEST_ONLY.get(folder, ()):
        raise ValueError(f"{folder}/{name} is not a TEST-ONLY sample")
    path = SHARED_SAMPLES / folder / name
    return path if path.is_file() else None


def shared_sample(folder: str, name: str) -> Path:
    """The path of a TEST-ONLY sample in ../shared; skips the calling test when it is not there."""
    path = shared_sample_path(folder, name)
    if path is None:
        pytest.skip(shared_sample_reason(folder, name))
    return path


def shared_marks(folder: str, name: str) -> list:
    """Marks for a parameter that needs the TEST-ONLY sample ``folder/name``: a skip, with the reason, when it is absent."""
    return [] if shared_sample_path(folder, name) is not None else [pytest.mark.skip(reason=shared_sample_reason(folder, name))]


def shared_param(folder: str, name: str, *more: object, id: str | None = None):
    """A ``pytest.param`` ``(path, *more)`` of the TEST-ONLY sample ``folder/name``, skipping (with the reason)
    when it is not there. Module-level parametrize lists use this, so collection never needs ../shared.
    """
    return pytest.param(SHARED_SAMPLES / folder / name, *more, id=id or name, marks=shared_marks(folder, name))


def skip_without_shared(folder: str) -> None:
    """Skips the calling test unless every TEST-ONLY sample of ``folder`` is in ../shared."""
    if missing_shared_samples(folder):
        pytest.skip(shared_sample_reason(folder))


def sample_files(*folders: str) -> list[Path]:
    """Every program file in the given sample folders (sorted by name in each folder).

    The files in ``samples/third_party/<folder>``, and the TEST-ONLY ones of ../shared when it is there
    (:func:`missing_shared_samples` lists those that are not).
    """
    out: list[Path] = []
    for folder in folders:
        files = [p for p in (SAMPLES / folder).iterdir() if _is_program(p)]
        files.extend(p for p in (shared_sample_path(folder, n) for n in TEST_ONLY.get(folder, ())) if p is not None)
        out.extend(sorted(files, key=lambda p: p.name))
    return out


def missing_shared_samples(*folders: str) -> list[tuple[str, str]]:
    """(folder, name) of the TEST-ONLY samples of ``folders`` that are not there (no ../shared)."""
    return [(f, n) for f in folders for n in TEST_ONLY.get(f, ()) if shared_sample_path(f, n) is None]


@pytest.fixture(scope="session")
def samples_dir() -> Path:
    if not SAMPLES.is_dir():
        pytest.fail(f"samples/third_party not found at {SAMPLES}")
    return SAMPLES


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist: ignored where it is not installed
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """Under ``pytest -n N --dist loadscope`` (.ci/run) every LinuxCNC integration test runs in one worker.

    One machine runs one LinuxCNC at a time: tests in two workers would find the run lock taken by the other
    worker and skip. Every other test is its own scope, so they spread over the workers one by one. (xdist's
    ``xdist_group`` mark does the same, but its ``loadgroup`` renames node ids through an attribute pytest 9 no
    longer reads, so the groups are silently lost.)
    """
    from xdist.scheduler import LoadScopeScheduling

    class _LinuxCNCInOneWorker(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return "linuxcnc" if nodeid.startswith("tests/integration/") else nodeid

    return _LinuxCNCInOneWorker(config, log)


def cli_output(res: Any) -> str:
    """What a CLI call printed (stdout and stderr) without the line ilcnc says when numba compiles on a cold cache
    (:data:`ilcnc._jit.COMPILE_NOTICE`, once per process): a test of an error message judges the message, whichever
    test of the process happened to compile first."""
    from ilcnc._jit import COMPILE_NOTICE

    return "".join(ln for ln in res.output.splitlines(keepends=True) if not ln.startswith(COMPILE_NOTICE))


def with_refine(profile: Any, **kw: Any) -> Any:
    """``profile`` with some ``learning.refine`` keys replaced (a copy)."""
    import dataclasses

    return dataclasses.replace(profile, learning=dataclasses.replace(
        profile.learning, refine=dataclasses.replace(profile.learning.refine, **kw)))
