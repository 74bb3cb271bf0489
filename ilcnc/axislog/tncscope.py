"""Heidenhain TNCscope CSV exports.

TNCscope writes what the user chose to record, with German or English signal
names, units in the header, decimal commas and a sampling line; the columns
are found by their names (nominal / actual position per axis, block number,
time), their units converted to s and mm (:func:`read_tncscope`).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.log import AxisLog, check_sample_times, decode_text, norm_unit
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes

__all__ = ["LENGTH_UNITS_MM", "TNCSCOPE_COLUMNS", "read_tncscope", "split_unit"]


# ---------------------------------------------------------------------------
# Heidenhain TNCscope CSV exports
# ---------------------------------------------------------------------------


#: Signals :func:`read_tncscope` looks for (the keys its ``columns`` argument accepts):
#: time, NC block number, nominal X Y Z, actual X Y Z.
TNCSCOPE_COLUMNS: tuple[str, ...] = ("t_s", "line", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act")

_TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "msec": 1e-3, "µs": 1e-6, "us": 1e-6}
LENGTH_UNITS_MM = {"mm": 1.0, "µm": 1e-3, "um": 1e-3, "nm": 1e-6, "m": 1e3, "inch": 25.4, "in": 25.4, '"': 25.4}
_RATE_UNITS = {"hz": 1.0, "khz": 1e3}
_REQUIRED = ("x_ref", "y_ref", "x_act", "y_act")
_HEADER_SCAN_LINES = 500  # the header must be within the first lines of the file
_NOM_WORDS = ("nominal", "nom", "soll", "cmd", "command", "ref", "setpoint", "target", "demand")
_ACT_WORDS = ("actual", "act", "ist", "pos", "feedback", "fb", "meas", "real")
_NOT_POSITION = frozenset(
    "v a i j f vel velocity speed feed acc accel acceleration jerk ruck current strom error fehler diff differenz "
    "abweichung following lag torque moment dev deviation temp temperature temperatur power leistung load".split()
)
_NOT_POSITION_PREFIX = ("schlepp", "geschw", "beschl", "vorschub", "veloc", "accel")
_TOKEN_RE = re.compile(r"[a-z0-9äöüßµ]+")
_KIND_WORDS = "nominal|nom|soll|ist|actual|act|ref|cmd|pos"
_AXIS_WORD_RE = re.compile(rf"([xyz])({_KIND_WORDS})|({_KIND_WORDS})([xyz])")
_BRACKET_UNIT_RE = re.compile(r"^(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]\s*$")
_SUFFIX_UNIT_RE = re.compile(r"^(?P<name>.*?)(?:_|/|\s+in\s+)(?P<unit>[a-zµμ\"]+)$", re.IGNORECASE)
_SAMPLING_RE = re.compile(
    r"(?:sampling|sample|abtast)[\s_-]*(?P<kind>time|period|interval|intervall|zeit|periode|rate|frequency|frequenz)?",
    re.IGNORECASE,
)
_NUMBER_RE = re.compile(r"[-+]?(?:\d+(?:[.,]\d+)?|[.,]\d+)(?:[eE][-+]?\d+)?")
_BLOCK_RE = re.compile(r"^[Nn]?\s*([-+]?\d+)(?:\.0*)?$")
_END_MARKERS = frozenset({"eof", "end", "ende", "end of data"})


def split_unit(cell: str) -> tuple[str, str | None]:
    """``"Time [ms]"`` -> ``("Time", "ms")``; also ``(ms)``, ``_ms``, ``/ms`` and `` in ms``."""
    cell = cell.strip().strip('"').strip()
    m = _BRACKET_UNIT_RE.match(cell)
    if m:
        unit = norm_unit(m["unit"])
        known = unit in _TIME_UNITS or unit in LENGTH_UNITS_MM or unit in _RATE_UNITS
        if cell.endswith("]") or known or "/" in unit or len(unit) <= 3:  # "(interpolator)" is no unit
            return m["name"].strip(), unit
    m = _SUFFIX_UNIT_RE.match(cell)
    if m and norm_unit(m["unit"]) in (_TIME_UNITS.keys() | LENGTH_UNITS_MM.keys()):
        return m["name"].strip(), norm_unit(m["unit"])
    return cell, None


def _norm_text(text: str) -> str:
    return " ".join(text.strip().strip('"').split()).casefold()


def _classify_cell(cell: str) -> tuple[str, int] | None:
    """The signal a header cell names, as (role, rank): rank orders block-number candidates (lower first)."""
    name, unit = split_unit(cell)
    raw_tokens = _TOKEN_RE.findall(name.lower())
    if not raw_tokens:
        return None
    tokens: list[str] = []
    for tok in raw_tokens:  # split compounds such as "xsoll" / "istx"
        m = _AXIS_WORD_RE.fullmatch(tok)
        tokens.extend([g for g in m.groups() if g] if m else [tok])
    axes = {t for t in tokens if t in ("x", "y", "z")}
    words = [t for t in tokens if t not in ("x", "y", "z")]
    is_length = unit is None or unit in LENGTH_UNITS_MM
    joined = " ".join(tokens)
    if not axes and (unit is None or unit in ("", "-")):
        if re.search(r"\b(block|satz|zeile|line|lines)|programline|programmzeile", joined) or joined in ("n", "nr"):
            numbered = re.search(r"\b(number|nummer|nr|no)\b|satznummer|satznr|zeilennummer|blocknumber|^n$", joined)
            return "line", 0 if numbered else 1
    if not axes and any(t in ("t", "time", "zeit", "timestamp", "zeitstempel", "zeitachse") for t in tokens):
        return "t_s", 0  # an unknown unit is refused later, rather than the column ignored
    if len(axes) != 1 or not is_length:
        return None
    if any(t in _NOT_POSITION or t.startswith(_NOT_POSITION_PREFIX) for t in words):
        return None
    axis = next(iter(axes))
    if any(t.startswith(_NOM_WORDS) or "soll" in t for t in words):
        return f"{axis}_ref", 0
    if any(t.startswith(_ACT_WORDS) or "istwert" in t or "istpos" in t or t.startswith("lageist") for t in words):
        return f"{axis}_act", 0
    return None


def _is_number(cell: str) -> bool:
    try:
        float(cell.strip().replace(",", "."))
    except ValueError:
        return False
    return True


def _sampling_period(line: str) -> float | None:
    """Sampling period in s from a metadata line such as ``Sampling time: 0.6 ms`` / ``Abtastzeit;0,6;ms``."""
    m = _SAMPLING_RE.search(line)
    if not m:
        return None
    rest = line[m.end():]
    num = _NUMBER_RE.search(rest)
    if not num:
        return None
    value = float(num.group().replace(",", "."))
    before = re.search(r"[\[(]([^\])]*)[\])]", rest[: num.start()])
    after = re.match(r"\s*[;,:\t=]?\s*[\[(]?\s*([a-zA-Zµμ]+)", rest[num.end():])
    unit = norm_unit(after.group(1)) if after else (norm_unit(before.group(1)) if before else None)
    kind = (m["kind"] or "").lower()
    if unit in _RATE_UNITS or (unit is None and kind in ("rate", "frequency", "frequenz")):
        f = value * _RATE_UNITS.get(unit or "hz", 1.0)
        return 1.0 / f if f > 0 else None
    period = value * _TIME_UNITS.get(unit, 1e-3) if unit in _TIME_UNITS or unit is None else None
    return period if period is not None and period > 0 and math.isfinite(period) else None


def _tncscope_overrides(columns: object) -> dict[str, str | int | None]:
    """Validate the ``columns`` argument of :func:`read_tncscope`."""
    if columns is None:
        return {}
    if not isinstance(columns, Mapping):
        raise InputError(None, None, f"TNCscope columns must map names to header texts or 0-based indices, got {columns!r}")
    out: dict[str, str | int | None] = {}
    for key, value in columns.items():
        name = str(key).strip().lower()
        if name not in TNCSCOPE_COLUMNS:
            raise InputError(None, None, f"unknown TNCscope column name {key!r} (known: {', '.join(TNCSCOPE_COLUMNS)})")
        if value is None or isinstance(value, str):
            out[name] = value
        elif isinstance(value, int) and not isinstance(value, bool) and value >= 0:
            out[name] = int(value)
        else:
            raise InputError(None, None, f"TNCscope column {name}: expected a header text or a 0-based index, got {value!r}")
    if (out.get("z_ref") is None) != (out.get("z_act") is None):
        raise InputError(None, None, "TNCscope columns must give both z_ref and z_act, or neither")
    return out


def _header_columns(cells: list[str], overrides: dict[str, str | int | None]) -> tuple[dict[str, int], list[int], list[str]]:
    """Roles found in a header row: (role -> column, block-number candidates in order, override texts not found)."""
    cols: dict[str, int] = {}
    line_cands: list[tuple[int, int]] = []
    for i, cell in enumerate(cells):
        found = _classify_cell(cell)
        if found is None:
            continue
        role, rank = found
        if role == "line":
            line_cands.append((rank, i))
        elif role not in cols:
            cols[role] = i
    lines = [i for _, i in sorted(line_cands)]
    not_found: list[str] = []
    normed = [_norm_text(c) for c in cells]
    bare = [_norm_text(split_unit(c)[0]) for c in cells]
    for role, value in overrides.items():
        if role == "line":
            lines = []
        if value is None:
            cols.pop(role, None)
            continue
        if isinstance(value, int):
            idx: int | None = value
        else:
            want = _norm_text(value)
            idx = normed.index(want) if want in normed else (bare.index(want) if want in bare else None)
        if idx is None:
            not_found.append(str(value))
            cols.pop(role, None)
        else:
            cols[role] = idx
    if ("z_ref" in cols) != ("z_act" in cols):
        cols.pop("z_ref", None)
        cols.pop("z_act", None)
    return cols, lines, not_found


def _describe(cells: list[str], cols: dict[str, int]) -> str:
    return ", ".join(f"{r}={cells[i].strip()!r}" if i < len(cells) else f"{r}=column {i}" for r, i in cols.items()) or "nothing"


def _tncscope_slow(
    p: Path,
    lines: list[str],
    rows: list[list[str]],
    rowline: list[int],
    sep: str,
    cols: dict[str, int],
    num_roles: list[str],
    header_name: dict[str, str],
    width: int | None,
) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.int64]]:
    """Numbers and block numbers of the data rows, cell by cell, naming the line and column of the first bad one."""

    def as_written(j: int, c: int) -> str:
        """Cell c of data row j as written in the file."""
        return next(csv.reader([lines[rowline[j] - 1]], delimiter=sep, skipinitialspace=True))[c].strip()

    ncols = max(cols.values()) + 1
    for cells_, ln in zip(rows, rowline, strict=True):
        if len(cells_) < ncols:
            raise InputError(p, ln, f"expected at least {ncols} columns, got {len(cells_)} (truncated line?)")
        if width is not None and len(cells_) > width and any(c.strip() for c in cells_[width:]):
            raise InputError(p, ln, f"{len(cells_)} columns but the header has {width} (a stray separator?)")
    data: dict[str, NDArray[np.float64]] = {}
    for r in num_roles:
        c = cols[r]
        raw = [row[c] for row in rows]
        try:
            data[r] = np.array(raw, dtype=np.float64)
        except ValueError:
            for j, v in enumerate(raw):
                try:
                    float(v)
                except ValueError:
                    what = "is empty" if not v.strip() else f"value {as_written(j, c)!r} is not a number"
                    raise InputError(p, rowline[j], f"{header_name[r]} {what}") from None
            raise  # pragma: no cover
    bad_rows = [(int(np.flatnonzero(~np.isfinite(a))[0]), r) for r, a in data.items() if not np.isfinite(a).all()]
    if bad_rows:
        j, r = min(bad_rows, key=lambda x: (x[0], cols[x[1]]))
        raise InputError(p, rowline[j], f"{header_name[r]} is not a finite number ({as_written(j, cols[r])!r})")
    block = np.zeros(len(rows), dtype=np.int64)
    if "line" in cols:
        c = cols["line"]
        for j, row in enumerate(rows):
            v = row[c].strip()
            if not v:
                continue  # no block: 0
            m = _BLOCK_RE.match(v)
            if not m:
                raise InputError(p, rowline[j], f"{header_name['line']}: block number {as_written(j, c)!r} is not an integer")
            block[j] = int(m.group(1))
    return data, block


def read_tncscope(
    path: str | Path,
    *,
    columns: Mapping[str, str | int | None] | None = None,
    max_gap_periods: float = 1.5,
    length_unit: str | None = None,
) -> AxisLog:
    """Read a Heidenhain TNCscope CSV export (or a similar scope export) as an axis log.

    Parameters
    ----------
    path : str or Path
        The export: any metadata lines (e.g. ``Sampling time: 0.6 ms`` /
        ``Abtastzeit;0,6;ms``), a header row naming the signals, optionally a
        row of units, then one row per sample. Separator ``;``, tab or ``,``
        (the one with which a header row is found); with ``;`` or tab a
        decimal comma is accepted. UTF-8, UTF-16 and Windows-1252 text.
    columns : mapping, optional
        Overrides the detection: keys from :data:`TNCSCOPE_COLUMNS` (``t_s``,
        ``line``, ``x_ref`` ... ``z_act``), values a header text (compared
        case-insensitively, with or without its unit) or a 0-based column
        index, or ``None`` for "not in the file". With indices for all
        needed columns the file may have no header row at all.
    max_gap_periods : float
        Largest allowed time step, in median sample periods.
    length_unit : {None, "mm", "inch", "µm", ...}, optional
        Unit of position columns whose header names none (default mm). A
        header that names a different unit is an error.

    Returns
    -------
    AxisLog
        ``t_s`` in s (as recorded: not shifted to start at 0; built from the
        sampling time when there is no time column); ``ref_mm`` / ``act_mm``
        in mm (Z NaN without both Z signals); ``line`` the NC block number
        (0 without such a column or where a cell is empty); ``k`` is -1
        everywhere (map lines to commands with :func:`commands_from_lines`).

    Notes
    -----
    Header detection (case-insensitive, English and German): time
    ``Time``/``t``/``Zeit``; nominal position: an axis letter X/Y/Z and one of
    nominal, nom, soll, cmd, ref, setpoint; actual position: an axis letter
    and one of actual, act, ist, pos, feedback. Velocity, acceleration,
    current and following-error signals (``v act X``, ``X following error``,
    ``Schleppfehler X``, a unit such as ``mm/min``) are not positions. Units
    come from brackets (``Time [ms]``, ``Pos.Soll X [µm]``) or a unit row:
    time s, ms, µs/us (none: ms, or whichever matches the sampling time);
    length mm, µm/um, nm, m, inch/in.

    Raises
    ------
    InputError
        No header row with the needed signals (the message lists what the
        best candidate row has), no time column and no sampling-time line, an
        unknown unit, a short row, a bad or non-finite number (naming the line
        and the column), time not increasing, or a gap longer than
        ``max_gap_periods`` sample periods. Line numbers are 1-based file lines.
    """
    p = Path(path)
    overrides = _tncscope_overrides(columns)
    if length_unit is not None and norm_unit(length_unit) not in LENGTH_UNITS_MM:
        raise InputError(None, None, f"unknown length unit {length_unit!r} (known: {', '.join(LENGTH_UNITS_MM)})")
    default_len = norm_unit(length_unit) if length_unit is not None else None
    text = decode_text(read_bytes(p))
    lines = text.splitlines()
    if not any(ln.strip() for ln in lines):
        raise InputError(p, None, "empty TNCscope export")
    head = lines[:_HEADER_SCAN_LINES]
    index_only = all(isinstance(overrides.get(r), int) for r in _REQUIRED) and (
        isinstance(overrides.get("t_s"), int) or ("t_s" in overrides and overrides["t_s"] is None)
    )
    best: tuple[int, int, list[str], dict[str, int], list[str]] | None = None  # score, line index, cells, roles, lacking
    found: tuple[str, int, list[str], dict[str, int], list[int], float | None, bool] | None = None
    for sep in (";", "\t", ","):
        period: float | None = None
        scan = csv.reader(head, delimiter=sep, skipinitialspace=True)
        for cells in scan:
            idx = scan.line_num - 1
            if not any(c.strip() for c in cells):
                continue
            cols, line_cands, not_found = _header_columns(cells, overrides)
            used = list(cols.values())
            numeric_row = bool(used) and all(i < len(cells) and _is_number(cells[i]) for i in used)
            if numeric_row and not index_only:
                continue  # a data row before any header (wrong separator, or no header)
            missing = [r for r in _REQUIRED if r not in cols] + [f"column {t!r}" for t in not_found]
            if any(i >= len(cells) for i in used):
                missing.append(f"column {max(used) + 1} (the line has {len(cells)})")
            if not missing and ("t_s" in cols or period is not None):
                found = (sep, idx, cells, cols, line_cands, period, numeric_row)
                break
            if not missing:
                missing = ["time (no time column and no sampling-time line before the header)"]
            if best is None or len(cols) > best[0]:
                best = (len(cols), idx, cells, cols, missing)
            if period is None:
                period = _sampling_period(head[idx])
        if found is not None:
            break
    if found is None:
        need = "time (or a sampling-time line), X/Y nominal and X/Y actual position columns"
        if best is None or best[0] == 0:
            raise InputError(p, None, f"no TNCscope header row found: need {need}; no line names any of them")
        _, idx, cells, cols, missing = best
        has = _describe(cells, cols)
        raise InputError(p, idx + 1, f"no TNCscope header row with {need}: this line has {has}; lacks {', '.join(missing)}")
    sep, h, cells, cols, line_cands, period, headerless = found
    units: dict[str, str | None] = {r: None if headerless else split_unit(cells[i])[1] for r, i in cols.items()}
    first_line = h + 1 if headerless else h + 2
    body = lines[first_line - 1:]
    if sep != ",":  # decimal comma (the original text is quoted in error messages)
        body = [ln.replace(",", ".") for ln in body]
    quoted = any('"' in ln for ln in body)
    texts: list[str] = []  # the non-blank data lines (unquoted files only)
    rows: list[list[str]] = []
    rowline: list[int] = []
    if quoted:
        reader = csv.reader(body, delimiter=sep, skipinitialspace=True)
        for cells_ in reader:
            if any(c.strip() for c in cells_):
                rows.append(cells_)
                rowline.append(first_line + reader.line_num - 1)
    else:
        blank = sep + " \t'"
        for j, ln in enumerate(body):
            if ln.strip(blank):
                texts.append(ln)
                rowline.append(first_line + j)

    def row(j: int) -> list[str]:
        return rows[j] if quoted else texts[j].split(sep)

    def drop(j: int) -> None:
        (rows if quoted else texts).pop(j)
        rowline.pop(j)

    while rowline and len([c for c in row(-1) if c.strip()]) == 1 and _norm_text(row(-1)[0]) in _END_MARKERS:
        drop(-1)
    # an optional row of units right under the header
    if rowline and not headerless and not any(i < len(row(0)) and _is_number(row(0)[i]) for i in cols.values()):
        top = row(0)
        unit_cells = {r: norm_unit(top[i].strip().strip("[]()")) if i < len(top) else "" for r, i in cols.items()}
        if all(u == "" or u in _TIME_UNITS or u in LENGTH_UNITS_MM or u == "-" for u in unit_cells.values()):
            for r, u in unit_cells.items():
                if units.get(r) is None and u not in ("", "-"):
                    units[r] = u
            drop(0)
    if not rowline:
        raise InputError(p, None, "TNCscope export has a header but no samples")
    # the block-number column: the first candidate that holds numbers
    if "line" not in cols and line_cands:
        top = row(0)
        for i in line_cands:
            first = top[i].strip() if i < len(top) else ""
            if not first or _BLOCK_RE.match(first):
                cols["line"] = i
                break
    header_name = {r: f"column {i + 1}" if headerless else f"column {i + 1} ({cells[i].strip()!r})" for r, i in cols.items()}
    num_roles = [r for r in ("t_s", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act") if r in cols]
    n = len(rowline)
    width = len(cells)  # cells beyond the header's width shift the columns (a stray separator): refuse them
    data: dict[str, NDArray[np.float64]] = {}
    block = np.zeros(n, dtype=np.int64)
    fast = None
    if not quoted and (headerless or max(t.count(sep) for t in texts) < width):
        roles = [*num_roles, "line"] if "line" in cols else num_roles
        try:
            fast = np.loadtxt(io.StringIO("\n".join(texts)), delimiter=sep, usecols=[cols[r] for r in roles], ndmin=2)
        except (ValueError, IndexError):
            fast = None
        if fast is not None and (fast.shape[0] != n or not np.isfinite(fast).all()):
            fast = None
        if fast is not None and "line" in cols and not np.all(fast[:, -1] == np.round(fast[:, -1])):
            fast = None
    if fast is not None:
        data = {r: fast[:, j] for j, r in enumerate(num_roles)}
        if "line" in cols:
            block = fast[:, -1].astype(np.int64)
    else:
        data, block = _tncscope_slow(p, lines, [row(j) for j in range(n)], rowline, sep, cols, num_roles, header_name,
                                     width=None if headerless else width)
    # time in s
    if "t_s" in data:
        u = units.get("t_s")
        if u is None:
            scale = 1e-3
            if period is not None and n > 1:
                step = float(np.median(np.diff(data["t_s"])))
                if step > 0:
                    scale = min((1.0, 1e-3, 1e-6), key=lambda s: abs(math.log(step * s / period)))
        elif u in _TIME_UNITS:
            scale = _TIME_UNITS[u]
        else:
            raise InputError(p, h + 1, f"{header_name['t_s']}: unknown time unit {u!r} (known: {', '.join(_TIME_UNITS)})")
        t = data["t_s"] * scale
    else:
        assert period is not None
        t = np.arange(n, dtype=np.float64) * period
    check_sample_times(p, t, np.asarray(rowline, dtype=np.int64), max_gap_periods)
    pos: dict[str, NDArray[np.float64]] = {}
    for r in ("x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act"):
        if r not in data:
            continue
        u = units.get(r)
        if u is not None and u not in LENGTH_UNITS_MM:
            raise InputError(p, h + 1, f"{header_name[r]}: unknown length unit {u!r} (known: {', '.join(LENGTH_UNITS_MM)})")
        if u is not None and default_len is not None and LENGTH_UNITS_MM[u] != LENGTH_UNITS_MM[default_len]:
            raise InputError(p, h + 1, f"{header_name[r]} is in {u}, but the positions were said to be in {default_len}")
        pos[r] = data[r] * LENGTH_UNITS_MM[u or default_len or "mm"]
    nan = np.full(n, math.nan)
    ref = np.column_stack([pos["x_ref"], pos["y_ref"], pos.get("z_ref", nan)])
    act = np.column_stack([pos["x_act"], pos["y_act"], pos.get("z_act", nan)])
    return AxisLog(t, np.full(n, -1, dtype=np.int64), block, ref, act, line_is_block_number=True)


