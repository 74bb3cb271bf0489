"""The HAL files a LinuxCNC INI loads, read for what ilcnc needs: parameters set, signals and their pins.

``[HAL] HALFILE`` names each file (several lines; ``POSTGUI_HALFILE`` once more after the GUI). As the
``linuxcnc`` launcher does, a name is looked up in the INI's folder and then in LinuxCNC's ``hallib``
(``LIB:name`` only there); halcmd replaces ``[SECTION]KEY`` by the INI's value before it runs a line. Only
``setp`` (and ``NAME = value``), ``net``, ``linksp``/``linkps``, ``loadrt`` and ``source`` are read; every
other command is passed over. ``.tcl`` HAL files cannot be read without Tcl and are named in
:attr:`HalConfig.notes`.
"""

from __future__ import annotations

import os
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes
from ilcnc.shop.linuxcnc_config import IniFile, IniValue

__all__ = ["DEFAULT_HALLIB", "HalConfig", "HalSetting", "hallib_dir", "read_hal", "resolve_hal_file"]

_SUBST = re.compile(r"\[([A-Za-z0-9_]+)\]([A-Za-z0-9_]+)")
_ARROWS = frozenset(("=>", "<=", "<=>"))
#: Where LinuxCNC's packages install the shared HAL files (``core_sim.hal``, ...); ``HALLIB_DIR`` overrides.
DEFAULT_HALLIB = Path("/usr/share/linuxcnc/hallib")


def hallib_dir() -> Path:
    """LinuxCNC's shared HAL folder: ``$HALLIB_DIR`` when set (run-in-place builds), else the Debian path."""
    env = os.environ.get("HALLIB_DIR")
    return Path(env) if env else DEFAULT_HALLIB


@dataclass(frozen=True, slots=True)
class HalSetting:
    """A value a HAL line gives a pin or parameter: the text after substitution, the text as written, where."""

    name: str
    value: str
    written: str
    file: Path
    line: int

    @property
    def source(self) -> str:
        """``file:line setp NAME WRITTEN`` for a comment that names where a value came from."""
        sub = f" = {self.value}" if self.written != self.value else ""
        return f"{self.file.name}:{self.line} setp {self.name} {self.written}{sub}"

    def number(self) -> float:
        """The value as a number; :class:`InputError` at the HAL line when it is none."""
        try:
            v = float(self.value)
        except ValueError:
            raise InputError(self.file, self.line, f"setp {self.name} {self.written!r}: not a number") from None
        if v != v or abs(v) == float("inf"):
            raise InputError(self.file, self.line, f"setp {self.name} {self.written!r}: not a finite number")
        return v


@dataclass(slots=True)
class HalConfig:
    """What the HAL files set and connect (see the module docstring)."""

    files: list[Path] = field(default_factory=list)
    settings: dict[str, HalSetting] = field(default_factory=dict)  # last setp of each pin / parameter
    nets: dict[str, list[str]] = field(default_factory=dict)       # signal -> pins
    signal_of: dict[str, str] = field(default_factory=dict)        # pin -> signal
    components: list[str] = field(default_factory=list)            # loadrt component names, in order
    notes: list[str] = field(default_factory=list)

    def linked(self, pin: str) -> list[str]:
        """The other pins on ``pin``'s signal (empty when it is on none)."""
        sig = self.signal_of.get(pin)
        return [] if sig is None else [p for p in self.nets.get(sig, []) if p != pin]


def resolve_hal_file(name: str, ini: IniFile, where: IniValue) -> Path:
    """The HAL file ``name`` of ``[HAL] HALFILE`` as the launcher finds it; :class:`InputError` at the INI line if none."""
    if name.startswith("LIB:"):
        cands = [hallib_dir() / name[4:]]
    elif os.path.isabs(os.path.expanduser(name)):
        cands = [Path(os.path.expanduser(name))]
    else:
        cands = [ini.folder / name, hallib_dir() / name]
    for c in cands:
        if c.is_file():
            return c
    raise InputError(where.file, where.line, f"{where.where} {name}: not found in {' or '.join(str(c.parent) for c in cands)}")


def read_hal(ini: IniFile) -> HalConfig:
    """Read every HAL file the INI loads (``[HAL] HALFILE`` in order, then ``POSTGUI_HALFILE``)."""
    hal = HalConfig()
    entries = [(iv, False) for iv in ini.get_all("HAL", "HALFILE")]
    entries += [(iv, True) for iv in ini.get_all("HAL", "POSTGUI_HALFILE")]
    for iv, postgui in entries:
        parts = iv.value.split()
        if not parts:
            if postgui:
                continue
            # the launcher reads HALFILE values until the first empty one
            hal.notes.append(f"{iv.file}:{iv.line}: {iv.where} is empty: LinuxCNC loads no HAL file after it")
            break
        try:
            path = resolve_hal_file(parts[0], ini, iv)
        except InputError as exc:
            if not postgui:
                raise
            # the GUI loads POSTGUI_HALFILE after start-up; a missing one does not stop LinuxCNC
            hal.notes.append(f"{exc.format()}: not read")
            continue
        if path.suffix.lower() == ".tcl":
            hal.notes.append(f"{iv.file}:{iv.line}: {path.name} is a Tcl HAL file: not read (gains set there are"
                             " not in the profile)")
            continue
        _read_file(hal, ini, path, [path.resolve()])
    return hal


def _logical_lines(text: str) -> list[tuple[int, str]]:
    """The HAL text as (first line number, line) with backslash continuations joined."""
    out: list[tuple[int, str]] = []
    pending = ""
    start = 0
    for no, raw in enumerate(text.splitlines(), 1):
        if not pending:
            start = no
        if raw.rstrip().endswith("\\"):
            pending += raw.rstrip()[:-1] + " "
            continue
        out.append((start, pending + raw))
        pending = ""
    if pending:
        out.append((start, pending))
    return out


def _read_file(hal: HalConfig, ini: IniFile, path: Path, chain: list[Path]) -> None:
    hal.files.append(path)
    text = read_bytes(path).decode("utf-8", errors="replace")
    for no, line in _logical_lines(text):
        written = line
        line = _SUBST.sub(lambda m: _ini_value(ini, m), line)
        try:
            tokens = shlex.split(line, comments=True)
            raw_tokens = shlex.split(written, comments=True)
        except ValueError as exc:
            raise InputError(path, no, f"HAL line not readable: {exc}") from None
        if not tokens:
            continue
        cmd = tokens[0]
        if cmd == "setp" and len(tokens) >= 3:
            _set(hal, tokens[1], tokens[2], raw_tokens[2] if len(raw_tokens) >= 3 else tokens[2], path, no)
        elif len(tokens) >= 3 and tokens[1] == "=":
            _set(hal, tokens[0], tokens[2], raw_tokens[2] if len(raw_tokens) >= 3 else tokens[2], path, no)
        elif cmd == "net" and len(tokens) >= 2:
            for pin in tokens[2:]:
                if pin not in _ARROWS:
                    _link(hal, tokens[1], pin)
        elif cmd == "linksp" and len(tokens) >= 3:
            _link(hal, tokens[1], tokens[2])
        elif cmd == "linkps" and len(tokens) >= 3:
            _link(hal, tokens[2], tokens[1])
        elif cmd == "loadrt" and len(tokens) >= 2:
            hal.components.append(tokens[1])
        elif cmd == "source" and len(tokens) >= 2:
            src = Path(os.path.expanduser(tokens[1]))
            src = src if src.is_absolute() else ini.folder / src
            if not src.is_file():
                raise InputError(path, no, f"source {tokens[1]}: file not found")
            if src.resolve() in chain:
                raise InputError(path, no, f"source {tokens[1]} sources itself")
            _read_file(hal, ini, src, [*chain, src.resolve()])


def _ini_value(ini: IniFile, m: re.Match[str]) -> str:
    v = ini.get(m.group(1), m.group(2))
    return m.group(0) if v is None else v.value


def _set(hal: HalConfig, name: str, value: str, written: str, path: Path, no: int) -> None:
    hal.settings[name] = HalSetting(name, value, written, path, no)


def _link(hal: HalConfig, signal: str, pin: str) -> None:
    hal.nets.setdefault(signal, [])
    if pin not in hal.nets[signal]:
        hal.nets[signal].append(pin)
    hal.signal_of[pin] = signal
