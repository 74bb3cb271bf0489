"""The per-part learning state: a directory that keeps every iteration of a learning run.

A shop learns a part over several runs on the machine, days apart, so the
state lives on disk, one directory per part::

    DIR/state.json              the index (written last: the commit point)
    DIR/original.<suffix>       the part program as given (the drawing)
    DIR/iter-NNN.<suffix>       the program of iteration NNN (000 = original)
    DIR/iter-NNN.corrections.csv   U of that program (k,dx,dy,dz)
    DIR/iter-NNN.errors.csv        E(k) measured on it (k,ex,ey,ez,t_s,valid)

Every file is written atomically before ``state.json`` names it, and
``state.json`` records the SHA-256 of each, so a run killed mid-write leaves
the previous state loadable, and a file changed behind ilcnc's back is
refused. Nothing here is ever overwritten except ``state.json`` itself.

One ``ilcnc learn`` at a time works on a state: :func:`state_lock` takes an
exclusive ``fcntl`` lock on ``.DIR.lock`` beside it for the whole call and
removes the file when done; the kernel frees the lock when the process ends,
however it ends, so no lock is ever stale.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import StateError
from ilcnc.fileio import output_mode, read_bytes, write_atomic
from ilcnc.outcomes import LearnStatus

__all__ = ["STATE_FILE", "IterationEntry", "LearnState", "sha256_bytes", "sha256_file", "state_lock"]

STATE_FILE = "state.json"
FORMAT = "ilcnc-learning-state"
VERSION = 1


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of bytes."""
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of a file."""
    return sha256_bytes(read_bytes(path))


@dataclass
class IterationEntry:
    """One iteration of a learning run, as the state records it.

    Attributes
    ----------
    iteration : int
        0 for the original program.
    program : str
        File name (in the state directory) of the program of this iteration.
    program_sha256 : str
        Its hash.
    corrections : str
        File name of its corrections ``U``.
    errors : str or None
        File name of ``E(k)`` measured on it (None until measured).
    stats : dict or None
        ``max``, ``mean``, ``rms`` error measured on it, mm (None until measured).
    measured_from : dict or None
        ``{"kind": "virtual"|"log"|"points", "path": ..., "sha256": ...}``.
    kept : bool or None
        The guard kept it (None until measured).
    gain_scale : float
        Factor on the law's gains used to compute its corrections.
    clipped : int
        Corrections clipped when computing it.
    output : str or None
        Where it was written for the machine (``--out``), for the record.
    profile_sha256 : str or None
        Hash of the profile this iteration was made and measured with (None: the one that started the run,
        :attr:`LearnState.profile_sha256`; a run continued with ``--new-profile`` records the new one).
    """

    iteration: int
    program: str
    program_sha256: str
    corrections: str
    errors: str | None = None
    stats: dict[str, float] | None = None
    measured_from: dict[str, Any] | None = None
    kept: bool | None = None
    gain_scale: float = 1.0
    clipped: int = 0
    output: str | None = None
    profile_sha256: str | None = None


@dataclass
class LearnState:
    """A learning run on disk (see the module docstring).

    Attributes
    ----------
    directory : Path
    part : dict
        ``name``, ``sha256``, ``file`` (copy in the directory), ``dialect``, ``units``, ``commands``.
    law : str
        The profile's law name.
    error : str
        The error estimate used.
    profile_sha256 : str
        Hash of the profile file used to start the run.
    iterations : list of IterationEntry
    gain_scale : float
        Current factor on the gains (the guard halves it once).
    status : str
        ``learning``, ``diverged``, ``converged``.
    file_sha256 : dict
        SHA-256 of each corrections and errors CSV, by file name: a CSV changed behind ilcnc's back is refused
        like a changed program (states written before these were recorded have none to check).
    """

    directory: Path
    part: dict[str, Any]
    law: str
    error: str
    profile_sha256: str
    iterations: list[IterationEntry] = field(default_factory=list)
    gain_scale: float = 1.0
    status: LearnStatus = LearnStatus.LEARNING
    file_sha256: dict[str, str] = field(default_factory=dict)

    # -- queries -----------------------------------------------------------------------------

    @property
    def path(self) -> Path:
        return self.directory / STATE_FILE

    def pending(self) -> IterationEntry | None:
        """The last iteration, if its program has not been measured yet."""
        if self.iterations and self.iterations[-1].stats is None:
            return self.iterations[-1]
        return None

    def kept(self, *, profile_sha256: str | None = None) -> list[IterationEntry]:
        """Measured iterations the guard kept, in order (only those made with this profile, if given)."""
        return [e for e in self.iterations if e.stats is not None and e.kept
                and (profile_sha256 is None or self.profile_of(e) == profile_sha256)]

    def best(self) -> IterationEntry | None:
        """The kept iteration with the lowest RMS error (the later one of equals), as the learner chooses its output.

        A kept iteration may be a hair worse than the best before it (the guard's allowance): the last kept is
        not always the best, and a continued run starts from the best.
        """
        k = self.kept()
        return min(reversed(k), key=lambda e: e.stats["rms"]) if k else None  # type: ignore[index]

    def profile_of(self, entry: IterationEntry) -> str:
        """Hash of the profile an iteration was made with."""
        return entry.profile_sha256 or self.profile_sha256

    def profile_record(self, profile_sha256: str) -> str | None:
        """What an iteration made with this profile records as :attr:`IterationEntry.profile_sha256`: None for the
        profile that started the run, else its hash (the reverse of :meth:`profile_of`)."""
        return None if profile_sha256 == self.profile_sha256 else profile_sha256

    @property
    def current_profile_sha256(self) -> str:
        """Hash of the profile the run goes on with: its last iteration's."""
        return self.profile_of(self.iterations[-1]) if self.iterations else self.profile_sha256

    def find_program(self, sha: str) -> IterationEntry | None:
        """The iteration whose program has this hash."""
        for e in self.iterations:
            if e.program_sha256 == sha:
                return e
        return None

    def used_measurement(self, sha: str, *, samples_sha: str | None = None) -> IterationEntry | None:
        """The iteration measured from a file with this hash, or from a log with these samples, if any."""
        for e in self.iterations:
            m = e.measured_from
            if m and (m.get("sha256") == sha or (samples_sha is not None and m.get("samples_sha256") == samples_sha)):
                return e
        return None

    # -- files -------------------------------------------------------------------------------

    def file(self, name: str) -> Path:
        return self.directory / name

    def write_file(self, name: str, data: bytes | str) -> str:
        """Write a new file of the state atomically; return its SHA-256."""
        raw = data.encode("utf-8") if isinstance(data, str) else data
        write_atomic(self.file(name), raw)
        return sha256_bytes(raw)

    def read_program_bytes(self, entry: IterationEntry) -> bytes:
        data = read_bytes(self.file(entry.program))
        if sha256_bytes(data) != entry.program_sha256:
            raise StateError(self.file(entry.program), None,
                             "changed since ilcnc wrote it (hash mismatch): the learning state is damaged")
        return data

    def read_original_bytes(self) -> bytes:
        data = read_bytes(self.file(self.part["file"]))
        if sha256_bytes(data) != self.part["sha256"]:
            raise StateError(self.file(self.part["file"]), None,
                             "changed since ilcnc wrote it (hash mismatch): the learning state is damaged")
        return data

    def write_array(self, name: str, header: str, rows: NDArray[np.float64], fmt: str) -> str:
        """Write a CSV of ``rows`` with a header; return its SHA-256."""
        lines = [header]
        lines.extend(fmt % tuple(r) for r in rows.tolist())
        sha = self.write_file(name, "\n".join(lines) + "\n")
        self.file_sha256[name] = sha
        return sha

    def _read_checked(self, name: str) -> bytes:
        """A CSV of the state, refused when its recorded hash (``file_sha256``) no longer matches."""
        p = self.file(name)
        raw = read_bytes(p)
        want = self.file_sha256.get(name)
        if want is not None and sha256_bytes(raw) != want:
            raise StateError(p, None, "changed since ilcnc wrote it (hash mismatch): the learning state is damaged")
        return raw

    def read_array(self, name: str, ncols: int) -> NDArray[np.float64]:
        p = self.file(name)
        text = self._read_checked(name).decode("utf-8", errors="replace")
        try:
            arr = np.loadtxt(text.splitlines()[1:], delimiter=",", ndmin=2)
        except ValueError as exc:
            raise StateError(p, None, f"damaged state file: {exc}") from None
        if arr.size == 0:
            arr = np.zeros((0, ncols))
        if arr.shape[1] != ncols:
            raise StateError(p, None, f"damaged state file: {arr.shape[1]} columns, expected {ncols}")
        return arr

    def write_corrections(self, entry_iteration: int, u_mm: NDArray[np.float64]) -> str:
        name = f"iter-{entry_iteration:03d}.corrections.csv"
        k = np.arange(u_mm.shape[0], dtype=np.float64)[:, None]
        self.write_array(name, "k,dx,dy,dz", np.hstack([k, u_mm]), "%d,%.9f,%.9f,%.9f")
        return name

    def read_corrections(self, entry: IterationEntry) -> NDArray[np.float64]:
        arr = self.read_array(entry.corrections, 4)
        refined = self.part.get("refined") or {}
        n = int(refined["commands"]) if refined.get("file") else int(self.part["commands"])  # the learning index
        if arr.shape[0] != n:
            raise StateError(self.file(entry.corrections), None, f"damaged state file: {arr.shape[0]} commands, part has {n}")
        return arr[:, 1:4]

    def write_errors(self, entry_iteration: int, e_mm: NDArray[np.float64], t_s: NDArray[np.float64],
                     valid: NDArray[np.bool_]) -> str:
        name = f"iter-{entry_iteration:03d}.errors.csv"
        k = np.arange(e_mm.shape[0], dtype=np.float64)[:, None]
        rows = np.hstack([k, e_mm, t_s[:, None], valid.astype(np.float64)[:, None]])
        self.write_array(name, "k,ex,ey,ez,t_s,valid", rows, "%d,%.9f,%.9f,%.9f,%.9f,%d")
        return name

    def read_errors(self, entry: IterationEntry) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        if entry.errors is None:
            raise StateError(self.path, None, f"iteration {entry.iteration} has no measured errors")
        arr = self.read_array(entry.errors, 6)
        return arr[:, 1:4], arr[:, 4], arr[:, 5] > 0.5

    # -- load / save -------------------------------------------------------------------------

    def save(self) -> None:
        """Write ``state.json`` atomically (after every file it names)."""
        data = {
            "format": FORMAT,
            "version": VERSION,
            "part": self.part,
            "law": self.law,
            "error": self.error,
            "profile_sha256": self.profile_sha256,
            "gain_scale": self.gain_scale,
            "status": self.status,
            "iterations": [asdict(e) for e in self.iterations],
            "file_sha256": self.file_sha256,
        }
        write_atomic(self.path, json.dumps(data, indent=1, sort_keys=False) + "\n")

    @classmethod
    def load(cls, directory: str | Path) -> LearnState:
        """Read and check a state directory.

        Raises
        ------
        StateError
            Not a learning state, an unknown version, a damaged index, or a
            file it names missing or changed.
        """
        d = Path(directory)
        p = d / STATE_FILE
        raw = read_bytes(p)
        try:
            data = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            line = getattr(exc, "lineno", None)
            raise StateError(p, line, f"damaged learning state ({exc.__class__.__name__})") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise StateError(p, None, "not an ilcnc learning state")
        if data.get("version") != VERSION:
            raise StateError(p, None, f"learning state version {data.get('version')} is not supported (expected {VERSION})")
        try:
            st = cls(
                directory=d,
                part=dict(data["part"]),
                law=str(data["law"]),
                error=str(data["error"]),
                profile_sha256=str(data["profile_sha256"]),
                iterations=[IterationEntry(**e) for e in data["iterations"]],
                gain_scale=float(data["gain_scale"]),
                status=LearnStatus(str(data["status"])),
                file_sha256={str(k): str(v) for k, v in dict(data.get("file_sha256", {})).items()},
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise StateError(p, None, f"damaged learning state: {exc}") from None
        st.check_files()
        return st

    def check_files(self) -> None:
        """Every file the index names exists with the recorded hash."""
        self.read_original_bytes()
        for e in self.iterations:
            self.read_program_bytes(e)
            for name in (e.corrections, e.errors):
                if name is None:
                    continue
                if not self.file(name).is_file():
                    raise StateError(self.file(name), None, "missing: the learning state is damaged")
                if name in self.file_sha256:
                    self._read_checked(name)

    @classmethod
    def exists(cls, directory: str | Path) -> bool:
        return (Path(directory) / STATE_FILE).is_file()


@contextmanager
def state_lock(directory: str | Path) -> Iterator[None]:
    """Hold the learning state ``directory`` for one ``ilcnc learn``; refuse when another holds it.

    The lock is ``fcntl.flock`` on ``.DIR.lock`` beside the state, removed again when the call ends (a lock
    taken on a file another process removed meanwhile is retaken on the new one, so two callers never hold
    it at once). A process killed while it holds the lock leaves the empty file and no lock: the next call
    takes it.

    Raises
    ------
    StateError
        Another process holds the state (its pid and since when, from the lock file).
    """
    d = Path(directory)
    if not d.parent.is_dir():  # nothing to lock yet; creating the state refuses a missing folder with its own message
        yield
        return
    lock = d.parent / f".{d.name}.lock"
    fd = -1
    for _attempt in range(20):
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, output_mode(lock))
        except OSError as exc:
            raise StateError(d, None, f"cannot lock the learning state ({lock.name}: {exc.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            who = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "another process"
            os.close(fd)
            raise StateError(d, None, f"is in use by another ilcnc learn ({who}): wait for it to end, or learn into"
                             " another --state") from None
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder before us removed the file: lock the one at the path now
        fd = -1
    if fd < 0:  # pragma: no cover - twenty removals in a row
        raise StateError(d, None, "cannot lock the learning state: its lock file keeps changing")
    try:
        os.pwrite(fd, f"pid {os.getpid()}, since {time.strftime('%Y-%m-%d %H:%M:%S')}".encode(), 0)
        yield
    finally:
        try:
            os.unlink(lock)  # while still held: a caller that opened it meanwhile retakes the next one
        except OSError:
            pass
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
