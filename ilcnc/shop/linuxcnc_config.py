"""A LinuxCNC configuration for one run: its INI read and rewritten, and the program's time scaled.

LinuxCNC INIs repeat keys and keep comments, so they are handled line by line (:func:`read_ini`,
:func:`scaled_ini_text`). A run slowed by ``--time-scale k`` (a slow machine keeps up with the servo thread)
has every time and rate of the INI and every feed, dwell and time word of the program scaled by ``k``
(:func:`scale_program_time`), so the motion is the same path at 1/k of the speed.
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes

__all__ = ["IniFile", "IniValue", "ini_in", "read_ini", "read_ini_file", "read_ini_text", "scale_program_time",
           "scaled_ini_text"]


# ---------------------------------------------------------------------------
# INI handling (line based: LinuxCNC INIs repeat keys and keep comments)
# ---------------------------------------------------------------------------

_SECTION = re.compile(r"^\s*\[([^\]]+)\]\s*$")
_KEYVAL = re.compile(r"^(\s*)([A-Za-z0-9_]+)(\s*=\s*)(.*?)(\s*)$")


def read_ini(path: str | Path) -> dict[str, dict[str, str]]:
    """The INI file as ``{SECTION: {KEY: value}}`` (first value of a repeated key; ``#``/``;`` comments skipped)."""
    p = Path(path)
    if p.is_dir():
        p = ini_in(p)
    return read_ini_text(read_bytes(p).decode("utf-8", errors="replace"))


def _fmt(v: float) -> str:
    """A number for an INI or G-code word: integers without a dot, others with up to 12 significant digits."""
    if v == int(v) and abs(v) < 1e15:
        return str(int(v))
    s = f"{v:.12g}"
    if "e" in s or "E" in s:
        s = f"{v:.9f}".rstrip("0").rstrip(".")
    return s


#: Time-based INI values LinuxCNC 2.9 assumes when the INI leaves them out, by section: a time-scaled run must
#: write them scaled. [TRAJ] ARC_BLEND_RAMP_FREQ (Hz): the planner runs a segment shorter than v / f at a ramped
#: velocity; left at 100 Hz while v grows k-fold, far longer segments counted as short at k = 8 and a program of
#: 0.3 mm blocks planned a different velocity profile from its 10th block on (bench/linuxcnc_dwell.py
#: --block-mm 0.3; compass ran 1.1 % longer at k = 8 than at k = 1).
TIME_DEFAULTS: dict[str, dict[str, str]] = {"TRAJ": {"ARC_BLEND_RAMP_FREQ": "100"}}


def _scale_factor(section: str, key: str, k: int) -> float | None:
    """How an INI value scales with time scale k (None: unchanged). SERVO_PERIOD is handled apart."""
    key_u = key.upper()
    if section.upper() == "ILCNC" and key_u == "KV":
        return float(k)
    if key_u.endswith("FREQ"):
        return float(k)  # a rate, 1/s (ARC_BLEND_RAMP_FREQ)
    if "JERK" in key_u:
        return float(k) ** 3
    if "ACCEL" in key_u:
        return float(k) ** 2
    if "VEL" in key_u:
        return float(k)
    return None


def scaled_ini_text(
    text: str,
    time_scale: int = 1,
    overrides: Mapping[str, Mapping[str, object]] | None = None,
    *,
    ini_path: str | Path | None = None,
) -> str:
    """The INI text with ``overrides`` applied, then scaled for ``time_scale`` (see module docstring).

    Overrides are real-time values (``{"JOINT_0": {"FERROR": 1}}``); a key that
    is not in its section is appended to it, a missing section at the end.
    """
    k = int(time_scale)
    pending = {sec.upper(): {str(key).upper(): str(v) for key, v in vals.items()} for sec, vals in (overrides or {}).items()}
    if k > 1:  # LinuxCNC's defaults of time-based values the INI leaves out, written out so that they scale
        have = {sec.upper(): {key.upper() for key in vals} for sec, vals in read_ini_text(text).items()}
        for sec, vals in TIME_DEFAULTS.items():
            for key, v in vals.items():
                if key not in have.get(sec, set()) and key not in pending.get(sec, {}):
                    pending.setdefault(sec, {})[key] = v
    seen: dict[str, set[str]] = {}
    out: list[str] = []
    section = ""

    def flush(sec: str) -> None:
        for key, v in pending.get(sec.upper(), {}).items():
            if key not in seen.get(sec.upper(), set()):
                out.append(f"{key} = {_scaled_value(sec, key, v, k, ini_path)}")
                seen.setdefault(sec.upper(), set()).add(key)

    for raw in text.splitlines():
        m = _SECTION.match(raw)
        if m:
            flush(section)
            section = m.group(1).strip()
            out.append(raw)
            continue
        s = raw.strip()
        m = _KEYVAL.match(raw)
        if not s or s[0] in "#;" or m is None:
            out.append(raw)
            continue
        key = m.group(2)
        value = m.group(4)
        ov = pending.get(section.upper(), {})
        if key.upper() in ov:
            value = ov[key.upper()]
            seen.setdefault(section.upper(), set()).add(key.upper())
        out.append(f"{m.group(1)}{key}{m.group(3)}{_scaled_value(section, key, value, k, ini_path)}")
    flush(section)
    for sec, vals in pending.items():
        if sec not in seen and not any(_SECTION.match(r) and _SECTION.match(r).group(1).strip().upper() == sec for r in out):  # type: ignore[union-attr]
            out.append(f"[{sec}]")
            for key, v in vals.items():
                out.append(f"{key} = {_scaled_value(sec, key, v, k, ini_path)}")
    return "\n".join(out) + "\n"


def _scaled_value(section: str, key: str, value: str, k: int, ini_path: str | Path | None) -> str:
    if k == 1:
        return value
    if section.upper() == "EMCMOT" and key.upper() == "SERVO_PERIOD":
        try:
            ns = int(float(value))
        except ValueError:
            raise InputError(ini_path, None, f"[EMCMOT] SERVO_PERIOD {value!r} is not a number of nanoseconds") from None
        if ns % k:
            raise InputError(ini_path, None, f"[EMCMOT] SERVO_PERIOD {ns} ns is not divisible by the time scale {k}")
        return str(ns // k)
    f = _scale_factor(section, key, k)
    if f is None:
        return value
    try:
        v = float(value)
    except ValueError:
        return value  # not a number (e.g. a comment-like value): leave it
    return _fmt(v * f)


# ---------------------------------------------------------------------------
# Time scaling of the program text
# ---------------------------------------------------------------------------

_NUMBER = re.compile(r"[+-]?[ \t]*(?:\d[\d \t]*(?:\.[\d \t]*)?|\.[ \t]*\d[\d \t]*)")
_FUNC = re.compile(r"(?i)(atan|abs|acos|asin|cos|exp|fix|fup|round|ln|sin|sqrt|tan|exists)[ \t]*(?=\[)")
_DWELL_G = (4.0, 82.0, 86.0, 88.0, 89.0)


class _Unscannable(Exception):
    pass


def _skip_bracket(s: str, i: int) -> int:
    """Index after the ``[...]`` expression starting at ``s[i] == '['`` (nested)."""
    depth = 0
    while i < len(s):
        c = s[i]
        if c == "[":
            depth += 1
        elif c == "]":
            depth -= 1
            if depth == 0:
                return i + 1
        elif c == "(":
            j = s.find(")", i)
            if j < 0:
                raise _Unscannable
            i = j
        i += 1
    raise _Unscannable


def _scan_value(s: str, i: int) -> int:
    """Index after the real value starting at ``i`` (number, #parameter, [expression], function)."""
    while i < len(s) and s[i] in " \t":
        i += 1
    if i >= len(s):
        raise _Unscannable
    c = s[i]
    if c == "[":
        return _skip_bracket(s, i)
    if c == "#":
        i += 1
        while i < len(s) and s[i] in " \t":
            i += 1
        if i < len(s) and s[i] == "<":
            j = s.find(">", i)
            if j < 0:
                raise _Unscannable
            return j + 1
        return _scan_value(s, i)
    m = _FUNC.match(s, i)
    if m:
        j = _skip_bracket(s, m.end())
        if m.group(1).lower() == "atan":  # ATAN[a]/[b]
            k = j
            while k < len(s) and s[k] in " \t":
                k += 1
            if k < len(s) and s[k] == "/":
                k += 1
                while k < len(s) and s[k] in " \t":
                    k += 1
                if k < len(s) and s[k] == "[":
                    return _skip_bracket(s, k)
        return j
    m = _NUMBER.match(s, i)
    if m:
        return m.end()
    raise _Unscannable


def _scale_line(line: str, k: int) -> str:
    """One block with its F words x k and its dwell P words / k (comments and O-word lines untouched)."""
    body = line
    lead = re.match(r"[ \t]*(?:/[ \t]*)?(?:[Nn][ \t]*\d+(?:\.\d*)?[ \t]*)?", body)
    i = lead.end() if lead else 0
    if i < len(body) and body[i] in "Oo%":
        return line
    words: list[tuple[str, int, int]] = []  # (letter, value start, value end)
    try:
        while i < len(body):
            c = body[i]
            if c in " \t\r":
                i += 1
            elif c == "(":
                j = body.find(")", i)
                if j < 0:
                    return line
                i = j + 1
            elif c == ";":
                break
            elif c == "#":  # parameter setting #n = value
                j = _scan_value(body, i)
                while j < len(body) and body[j] in " \t":
                    j += 1
                if j >= len(body) or body[j] != "=":
                    raise _Unscannable
                i = _scan_value(body, j + 1)
            elif c.isalpha():
                j = _scan_value(body, i + 1)
                words.append((c.upper(), i + 1, j))
                i = j
            else:
                raise _Unscannable
    except _Unscannable:
        pass  # leave the rest as it is: LinuxCNC will say what is wrong with it
    dwell = False
    for letter, a, b in words:
        if letter == "G":
            with contextlib.suppress(ValueError):
                dwell = dwell or float(body[a:b].replace(" ", "").replace("\t", "")) in _DWELL_G
    edits: list[tuple[int, int, str]] = []
    for letter, a, b in words:
        if letter == "F" or (letter == "P" and dwell):
            raw = body[a:b]
            trail = len(raw) - len(raw.rstrip(" \t"))
            b -= trail  # keep the spacing after the number
            raw = body[a:b]
            op = "*" if letter == "F" else "/"
            try:
                v = float(raw.replace(" ", "").replace("\t", ""))
            except ValueError:
                edits.append((a, b, f"[{raw.strip()}{op}{k}]"))
                continue
            edits.append((a, b, _fmt(v * k if letter == "F" else v / k)))
    for a, b, new in reversed(edits):
        body = body[:a] + new + body[b:]
    return body


def scale_program_time(text: str, time_scale: int) -> str:
    """The program with every F word multiplied by ``time_scale`` and dwell P words divided by it.

    Line structure (and so every source line number) is kept; comments, ``%``
    and O-word lines are untouched. F words given as parameters or
    expressions become ``[... * k]``. Feed-per-revolution (G95) and
    spindle-synchronised moves are not time-scaled (the simulation has no
    spindle); F words in external subroutine files are not scaled either.
    """
    k = int(time_scale)
    if k == 1:
        return text
    parts = text.split("\n")
    return "\n".join(_scale_line(p, k) for p in parts)


def ini_in(config: Path) -> Path:
    """The INI of a configuration: the file itself, the folder's ``sim.ini``, or its only ``.ini``."""
    if config.is_file():
        return config
    if not config.is_dir():
        raise InputError(config, None, "LinuxCNC configuration directory not found")
    inis = sorted(config.glob("*.ini"))
    if (config / "sim.ini").is_file():
        return config / "sim.ini"
    if len(inis) != 1:
        raise InputError(config, None, f"expected one .ini file in the configuration directory, found {len(inis)}")
    return inis[0]


def read_ini_text(text: str) -> dict[str, dict[str, str]]:
    """:func:`read_ini` on a string."""
    out: dict[str, dict[str, str]] = {}
    section = ""
    for raw in text.splitlines():
        s = raw.strip()
        if not s or s[0] in "#;":
            continue
        m = _SECTION.match(raw)
        if m:
            section = m.group(1).strip()
            out.setdefault(section, {})
            continue
        m = _KEYVAL.match(raw)
        if m:
            out.setdefault(section, {}).setdefault(m.group(2), m.group(4))
    return out


# ---------------------------------------------------------------------------
# The INI with the file and line of every value (for messages that name them)
# ---------------------------------------------------------------------------

_INCLUDE = re.compile(r"^#INCLUDE(?:\s+(.*?))?\s*$")


@dataclass(frozen=True, slots=True)
class IniValue:
    """One ``KEY = value`` of an INI: the value as written and where it is (``#INCLUDE`` files name their own)."""

    section: str
    key: str
    value: str
    file: Path
    line: int

    @property
    def where(self) -> str:
        """``[SECTION] KEY`` as a message names it."""
        return f"[{self.section}] {self.key}"

    def number(self) -> float:
        """The value as a number; :class:`InputError` naming the file, line and key when it is none."""
        try:
            v = float(self.value)
        except ValueError:
            raise InputError(self.file, self.line, f"{self.where} {self.value!r} is not a number") from None
        if v != v or v in (float("inf"), float("-inf")):
            raise InputError(self.file, self.line, f"{self.where} {self.value!r} is not a finite number")
        return v


@dataclass(slots=True)
class IniFile:
    """A LinuxCNC INI as LinuxCNC reads it: sections, ``#``/``;`` comment lines, repeated keys, ``#INCLUDE``.

    LinuxCNC takes the first value of a repeated key (``HALFILE`` is read as a list); names are matched
    exactly (upper case by convention). ``#INCLUDE FILE`` is expanded in place, relative to the INI's folder,
    as the ``linuxcnc`` launcher does; an include it cannot read is skipped with a note in :attr:`notes`
    (the launcher prints a warning and runs on).
    """

    path: Path
    values: dict[str, dict[str, list[IniValue]]] = field(default_factory=dict)
    section_lines: dict[str, tuple[Path, int]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def folder(self) -> Path:
        return self.path.parent

    def get(self, section: str, key: str) -> IniValue | None:
        """The first value of ``[section] key``, or None."""
        vals = self.values.get(section, {}).get(key)
        return vals[0] if vals else None

    def get_all(self, section: str, key: str) -> list[IniValue]:
        """Every value of ``[section] key`` in file order (``[HAL] HALFILE``)."""
        return list(self.values.get(section, {}).get(key, []))

    def has_section(self, section: str) -> bool:
        return section in self.section_lines

    def number(self, section: str, key: str) -> float | None:
        """``[section] key`` as a number (None when absent; :class:`InputError` at its line when not numeric)."""
        v = self.get(section, key)
        return None if v is None else v.number()

    def missing(self, section: str, key: str, why: str = "") -> InputError:
        """The error for a required key that is absent, at its section's line when the section exists."""
        file, line = self.section_lines.get(section, (self.path, None))
        tail = f": {why}" if why else ""
        return InputError(file, line, f"[{section}] {key} is missing{tail}")


def read_ini_file(path: str | Path) -> IniFile:
    """Read a LinuxCNC INI with the file and line of every value (see :class:`IniFile`)."""
    p = Path(path)
    if p.is_dir():
        p = ini_in(p)
    ini = IniFile(path=p)
    _read_into(ini, p, [p.resolve()], "")
    return ini


def _read_into(ini: IniFile, p: Path, chain: list[Path], section: str) -> str:
    text = read_bytes(p).decode("utf-8", errors="replace")
    for no, raw in enumerate(text.splitlines(), 1):
        s = raw.strip()
        m = _INCLUDE.match(s)
        if m:
            name = (m.group(1) or "").strip()
            inc = Path(os.path.expanduser(name)) if name else None
            if inc is not None and not inc.is_absolute():
                inc = ini.folder / inc
            if inc is None or not inc.is_file():
                ini.notes.append(f"{p}:{no}: #INCLUDE {name or '(no file name)'} cannot be read: skipped, as the"
                                 " linuxcnc launcher does")
                continue
            if inc.resolve() in chain:
                raise InputError(p, no, f"#INCLUDE {name} includes itself")
            section = _read_into(ini, inc, [*chain, inc.resolve()], section)
            continue
        if not s or s[0] in "#;":
            continue
        m = _SECTION.match(raw)
        if m:
            section = m.group(1).strip()
            ini.values.setdefault(section, {})
            ini.section_lines.setdefault(section, (p, no))
            continue
        m = _KEYVAL.match(raw)
        if m and section:
            key = m.group(2)
            ini.values[section].setdefault(key, []).append(IniValue(section, key, m.group(4), p, no))
    return section
