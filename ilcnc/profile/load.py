"""Reading a profile: YAML with line numbers, every value checked against the schema, the dataclasses built.

Every value is checked when the profile is loaded (types, ranges, choices, unknown and missing keys,
cross-key rules). A bad profile raises :class:`ilcnc.errors.ProfileError` whose message is one line naming
the file, the line and the YAML path of the bad key with the allowed range, e.g.::

    mill.yaml:12: axes.x.max_jerk_m_s3: must be > 0 and <= 100000, got -5

:func:`load_profile` reads a file, :func:`profile_from_dict` a mapping, and :func:`default_profile` is the
3-axis mill used when no profile is given.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import yaml

from ilcnc.errors import InputError, ProfileError
from ilcnc.fileio import read_bytes
from ilcnc.profile.schema import (
    DEFAULT_ERROR,
    DRIVE_KEY,
    HISTORY_LAWS,
    MAX_COEFFS,
    MAX_DK_CANDIDATES,
    PREDICTED_ERRORS,
    SELECTORS,
    SPECS,
    TOP_SECTIONS,
    Spec,
    format_number,
    spec_of,
)
from ilcnc.profile.sections import (
    DRIVE_MODELS,
    MODE_KEYS,
    AxisProfile,
    ControllerSection,
    CuttingSection,
    GeometrySection,
    LearningSection,
    MachineProfile,
    MachineSection,
    OutputSection,
    PlannerSection,
    RefineSection,
    ScheduleTuning,
    ToolMode,
    ToolSection,
    TuningSection,
    has_position_loop,
)
from ilcnc.units import AXIS_NAMES

__all__ = ["default_profile", "load_profile", "profile_from_dict"]


# --------------------------------------------------------------------------
# YAML reading with line numbers
# --------------------------------------------------------------------------


class _Loader(yaml.SafeLoader):
    """Safe loader that also reads ``1e-5`` (no dot) as a float, as YAML 1.2 does."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _compose_and_load(text: str, fail: _Fail) -> tuple[Any, Any]:
    """The node tree of ``text`` and the data built from it, in one parse; the lines of its keys into ``fail``.

    The keys' lines are read before the data is built (building merges ``<<`` keys into the tree); a duplicate
    key is reported after the data is built, as when the text was parsed twice (first the data, then the lines).
    """
    ld = _Loader(text)  # a SafeLoader
    try:
        node = ld.get_single_node()
        if node is None:
            return None, None
        late: Exception | None = None
        try:
            _key_lines(node, (), fail.lines, fail)
        except (ProfileError, RecursionError) as exc:
            late = exc
        data = ld.construct_document(node)
        if late is not None:
            raise late
        return node, data
    finally:
        ld.dispose()


def _key_lines(
    node: yaml.Node,
    prefix: tuple[str, ...],
    out: dict[tuple[str, ...], int],
    fail: _Fail,
    visited: set[int] | None = None,
) -> None:
    """Record the 1-based line of every mapping key under ``node`` by its path.

    A node reached again through an alias is not walked again (its keys keep
    the lines of the anchored definition through the fallback of
    :meth:`_Fail.line`), which also stops recursive aliases.
    """
    if visited is None:
        visited = set()
    if id(node) in visited:
        return
    visited.add(id(node))
    if isinstance(node, yaml.MappingNode):
        seen: dict[str, int] = {}
        for knode, vnode in node.value:
            if not isinstance(knode, yaml.ScalarNode) or knode.tag == "tag:yaml.org,2002:merge":
                continue
            key = str(knode.value)
            line = knode.start_mark.line + 1
            if key in seen:
                fail.at_line(line, f"{'.'.join((*prefix, key))}: duplicate key (first given on line {seen[key]})")
            seen[key] = line
            path = (*prefix, key)
            out[path] = line
            _key_lines(vnode, path, out, fail, visited)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            out.setdefault((*prefix, str(i)), item.start_mark.line + 1)
            _key_lines(item, (*prefix, str(i)), out, fail, visited)


def _parse_yaml(text: str, fail: _Fail) -> tuple[Any, int | None]:
    """Parse ``text``; return the data and the line of the top-level node.

    The text is parsed once (:func:`_compose_and_load`; composing and loading it apart parsed it twice:
    configs/example-mill.yaml 15 ms, now 8 ms, of a 0.4 s ``ilcnc check``, issue 24). libyaml's parser
    (``yaml.CSafeLoader``, 0.6 ms) is not used: it takes text PyYAML refuses (tabs, a BOM inside the text,
    ``[x ?]``, hundreds of levels deep), so a broken profile would load.
    """
    try:
        node, data = _compose_and_load(text, fail)
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, exc.position) + 1
        ch = exc.character if isinstance(exc.character, int) else ord(str(exc.character)[:1] or "\0")
        fail.at_line(line, f"invalid YAML: control character U+{ch:04X} is not allowed")
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or "syntax error"
        if exc.context and exc.problem:
            problem = f"{problem} ({exc.context})"
        fail.at_line(mark.line + 1 if mark is not None else None, f"invalid YAML: {problem}")
    except yaml.YAMLError as exc:
        fail.at_line(None, f"invalid YAML: {exc}")
    except RecursionError:
        fail.at_line(None, "invalid YAML: nested too deeply")
    if node is None:
        return None, None
    return data, node.start_mark.line + 1







# --------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------


class _Fail:
    """Raises :class:`ProfileError` with the file and the line of a key path."""

    def __init__(self, file: Path | None) -> None:
        self.file = file
        self.lines: dict[tuple[str, ...], int] = {}
        self.root_line: int | None = None

    def line(self, path: tuple[str, ...]) -> int | None:
        for n in range(len(path), 0, -1):
            if path[:n] in self.lines:
                return self.lines[path[:n]]
        return self.root_line

    def at_line(self, line: int | None, problem: str) -> NoReturn:
        raise ProfileError(self.file, line, problem)

    def __call__(self, path: tuple[str, ...], problem: str, *, line_path: tuple[str, ...] | None = None) -> NoReturn:
        where = ".".join(path)
        raise ProfileError(self.file, self.line(path if line_path is None else line_path), f"{where}: {problem}")





def _got(v: Any) -> str:
    if v is None:
        return "nothing (empty value)"
    if isinstance(v, bool):
        return f"{str(v).lower()} (a boolean)"
    if isinstance(v, str):
        return repr(v)
    if isinstance(v, (int, float)):
        return format_number(v) if not isinstance(v, float) else repr(v)
    if isinstance(v, Mapping):
        return "a mapping"
    if isinstance(v, (list, tuple)):
        return "a list"
    return type(v).__name__


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _children(pattern: str) -> list[Spec]:
    return [s for s in SPECS if s.parent == pattern]


def _resolve(selector: str, concrete: tuple[str, ...]) -> tuple[str, ...]:
    """Concrete path of a selector pattern, taking ``<axis>`` from ``concrete``."""
    parts = selector.split(".")
    return tuple(concrete[i] if p == "<axis>" and i < len(concrete) else p for i, p in enumerate(parts))


class _Validator:
    """Walks the data against :data:`SPECS`; remembers validated values by concrete path (for ``when``)."""

    def __init__(self, fail: _Fail) -> None:
        self.fail = fail
        self.values: dict[tuple[str, ...], Any] = {}

    def active(self, spec: Spec, concrete: tuple[str, ...]) -> bool:
        if spec.when is None:
            return True
        return self.values.get(_resolve(spec.when[0], concrete)) == spec.when[1]

    def section(self, spec_path: str, path: tuple[str, ...], value: Any) -> dict[str, Any]:
        """Validate a mapping of fixed keys; return it with defaults filled."""
        if value is None:
            value = {}
        if not isinstance(value, Mapping):
            allowed = ", ".join(s.key for s in _children(spec_path) if s.when is None)
            self.fail(path, f"must be a mapping with keys {allowed}, got {_got(value)}")
        children = _children(spec_path)
        out: dict[str, Any] = {}
        # Selectors first: the keys allowed here may depend on them.
        for s in children:
            if s.path in SELECTORS:
                out[s.key] = self.entry(s, path, value)
        active = [s for s in children if self.active(s, path)]
        names = [s.key for s in active]
        for key in value:
            if not isinstance(key, str) or key not in names:
                extra = ""
                sel = next((s.when for s in children if s.when and s.key == key), None)
                if sel is not None:
                    cur = self.values.get(_resolve(sel[0], path))
                    extra = f" for {sel[0].rsplit('.', 1)[-1]} {cur}"
                elif path == () and isinstance(key, str) and key in AXIS_NAMES:
                    extra = " (axes go under 'axes:')"
                self.fail((*path, str(key)), f"unknown key{extra}; allowed: {', '.join(names)}")
        for s in active:
            if s.key not in out:
                out[s.key] = self.entry(s, path, value)
        return out

    def entry(self, spec: Spec, parent: tuple[str, ...], mapping: Mapping[str, Any]) -> Any:
        path = (*parent, spec.key)
        if spec.key not in mapping or (mapping[spec.key] is None and spec.default is None):
            if spec.required:
                what = "section" if spec.kind in ("section", "axis_map") else "key"
                rng = spec.range_text()
                extra = f" ({spec.unit + ', ' if spec.unit else ''}{rng})" if rng else ""
                self.fail(path, f"missing required {what}{extra}", line_path=parent)
            if spec.kind == "section":
                return self.section(spec.path, path, {})
            if spec.kind == "axis_map":
                return {}
            self.values[path] = spec.default
            return spec.default
        v = self.value(spec, path, mapping[spec.key])
        self.values[path] = v
        return v

    def value(self, spec: Spec, path: tuple[str, ...], v: Any) -> Any:
        kind = spec.kind
        if kind == "section":
            return self.section(spec.path, path, v)
        if kind == "axis_map":
            return self.axis_map(spec, path, v)
        if kind == "str":
            if not isinstance(v, str) or not v.strip():
                self.fail(path, f"must be a non-empty text (quote it if needed), got {_got(v)}")
            return v
        if kind == "choice":
            if not isinstance(v, str) or v not in spec.choices:
                self.fail(path, f"must be {spec.range_text()}, got {_got(v)}")
            return v
        if kind in ("float", "int"):
            return self.number(spec, path, v)
        if kind == "axis_float":
            if isinstance(v, Mapping):
                out: dict[str, float] = {}
                for ax, g in v.items():
                    if ax not in AXIS_NAMES:
                        self.fail(
                            (*path, str(ax)), f"unknown axis; a per-axis gain is keyed by {', '.join(AXIS_NAMES)}"
                        )
                    out[ax] = self.number(spec, (*path, ax), g)
                if not out:
                    self.fail(path, "empty per-axis mapping; give a number or one per axis")
                return {ax: out[ax] for ax in AXIS_NAMES if ax in out}
            return self.number(spec, path, v, per_axis=True)
        if kind == "range_pair":
            ok = isinstance(v, (list, tuple)) and len(v) == 2 and all(_is_number(e) for e in v)
            want = f"must be a list [min, max] of two numbers {spec.range_text()} with min < max"
            if not ok:
                self.fail(path, f"{want}, got {_got(v)}")
            lo, hi = float(v[0]), float(v[1])
            if not (math.isfinite(lo) and math.isfinite(hi)) or not (
                self.in_range(spec, lo) and self.in_range(spec, hi)
            ):
                self.fail(path, f"{want}, got [{format_number(v[0])}, {format_number(v[1])}]")
            if not lo < hi:
                self.fail(path, f"{want}, got min {format_number(v[0])} >= max {format_number(v[1])}")
            return (lo, hi)
        if kind == "axis_pair":
            want = f"must be a list of two different axis names from {', '.join(AXIS_NAMES)}"
            ok = (
                isinstance(v, (list, tuple))
                and len(v) == 2
                and all(isinstance(e, str) and e in AXIS_NAMES for e in v)
                and v[0] != v[1]
            )
            if not ok:
                shown = f"[{', '.join(str(e) for e in v)}]" if isinstance(v, (list, tuple)) else _got(v)
                self.fail(path, f"{want}, got {shown}")
            return (v[0], v[1])
        if kind == "coeffs":
            return self.coeffs(spec, path, v)
        if kind == "numbers":
            return self.numbers(spec, path, v)
        if kind == "modes":
            return self.modes(path, v)
        raise AssertionError(kind)  # pragma: no cover

    def coeffs(self, spec: Spec, path: tuple[str, ...], v: Any) -> tuple[float, ...]:
        """Validate a list of polynomial coefficients (descending powers of s)."""
        want = (
            f"must be a list of 1 to {MAX_COEFFS} finite numbers (coefficients in descending powers of s,"
            " the first non-zero)"
        )
        if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= MAX_COEFFS:
            self.fail(path, f"{want}, got {_got(v) if not isinstance(v, (list, tuple)) else f'{len(v)} items'}")
        for i, e in enumerate(v):
            if not _is_number(e) or not math.isfinite(e) or not self.in_range(spec, e):
                self.fail((*path, str(i)), f"{want}, got {_got(e)}", line_path=path)
        if v[0] == 0:
            self.fail(path, f"{want}, got a leading 0")
        return tuple(float(e) for e in v)

    def numbers(self, spec: Spec, path: tuple[str, ...], v: Any) -> tuple[float, ...]:
        """Validate a list of finite numbers within the spec's range."""
        want = f"must be a list of 1 to {MAX_DK_CANDIDATES} finite numbers {spec.range_text()}"
        if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= MAX_DK_CANDIDATES:
            self.fail(path, f"{want}, got {_got(v) if not isinstance(v, (list, tuple)) else f'{len(v)} items'}")
        for i, e in enumerate(v):
            if not _is_number(e) or not math.isfinite(e) or not self.in_range(spec, e):
                self.fail(path, f"{want}, got {_got(e)} (item {i})")
        return tuple(float(e) for e in v)

    def modes(self, path: tuple[str, ...], v: Any) -> tuple[ToolMode, ...]:
        """Validate a list of tool modes (``tool.modes``)."""
        want = "must be a list of 1 to 10 modes {direction, natural_frequency_hz, damping_ratio, stiffness_n_um}"
        if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= 10:
            self.fail(path, f"{want}, got {_got(v) if not isinstance(v, (list, tuple)) else f'{len(v)} items'}")
        out = []
        for i, m in enumerate(v):
            p = (*path, str(i))
            if not isinstance(m, Mapping):
                self.fail(p, f"{want}; item {i} is {_got(m)}", line_path=path)
            extra = sorted(set(map(str, m)) - set(MODE_KEYS))
            if extra:
                self.fail((*p, extra[0]), f"unknown key; allowed: {', '.join(MODE_KEYS)}", line_path=p)
            for key in MODE_KEYS:
                if key not in m:
                    self.fail(p, f"mode {i} misses {key}", line_path=path)
            if m["direction"] not in ("feed", "normal"):
                self.fail((*p, "direction"), f"must be feed or normal, got {_got(m['direction'])}", line_path=p)
            vals = {}
            for key, lo, hi, unit in (("natural_frequency_hz", 0.0, 1e5, "Hz"), ("damping_ratio", 0.0, 1.0, ""),
                                      ("stiffness_n_um", 0.0, 1e6, "N/µm")):
                x = m[key]
                if not _is_number(x) or not math.isfinite(x) or not lo < x < hi:
                    self.fail((*p, key), f"must be a number > {format_number(lo)} and < {format_number(hi)}"
                                         f"{' ' + unit if unit else ''}, got {_got(x)}", line_path=p)
                vals[key] = float(x)
            out.append(ToolMode(direction=m["direction"], **vals))
        return tuple(out)

    @staticmethod
    def in_range(spec: Spec, x: float) -> bool:
        if spec.lo is not None and (x <= spec.lo if spec.lo_open else x < spec.lo):
            return False
        return not (spec.hi is not None and (x >= spec.hi if spec.hi_open else x > spec.hi))

    def number(self, spec: Spec, path: tuple[str, ...], v: Any, *, per_axis: bool = False) -> Any:
        rng = spec.range_text()
        if spec.kind == "int":
            if not isinstance(v, int) or isinstance(v, bool):
                if isinstance(v, float) and v.is_integer():
                    v = int(v)
                else:
                    self.fail(path, f"must be an integer {rng}, got {_got(v)}")
            if not self.in_range(spec, v):
                self.fail(path, f"must be {rng}, got {_got(v)}")
            return v
        if not _is_number(v):
            what = "a number or a per-axis mapping of numbers" if per_axis else "a number"
            self.fail(path, f"must be {what} {rng}, got {_got(v)}")
        if not math.isfinite(v):
            self.fail(path, f"must be a finite number {rng}, got {v!r}")
        if not self.in_range(spec, v):
            self.fail(path, f"must be {rng}, got {_got(v)}")
        return float(v)

    def axis_map(self, spec: Spec, path: tuple[str, ...], v: Any) -> dict[str, Any]:
        child = next(s for s in SPECS if s.parent == spec.path)
        if v is None:
            v = {}
        if not isinstance(v, Mapping):
            self.fail(path, f"must be a mapping keyed by axis name ({', '.join(AXIS_NAMES)}), got {_got(v)}")
        out: dict[str, Any] = {}
        for key in v:
            if key not in AXIS_NAMES:
                hint = " (axis names are lowercase)" if isinstance(key, str) and key.lower() in AXIS_NAMES else ""
                self.fail((*path, str(key)), f"unknown axis{hint}; allowed: {', '.join(AXIS_NAMES)}")
        for key in AXIS_NAMES:  # canonical order
            if key in v:
                out[key] = self.value(child, (*path, key), v[key])
                self.values[(*path, key)] = out[key]
        if spec.required and not out:
            self.fail(path, f"at least one axis is required; allowed: {', '.join(AXIS_NAMES)}")
        return out


def _cross_checks(d: dict[str, Any], fail: _Fail) -> None:
    """Rules that involve more than one key."""
    cut, tool = d["cutting"], d["tool"]
    if cut["model"] != "none":
        if cut["stock"] is None and cut["radial_depth_mm"] is None:
            fail(("cutting", "model"), f"cutting.model {cut['model']} needs cutting.stock (an OMI file) or"
                                       " cutting.radial_depth_mm")
        if not tool["modes"] and tool["frf_csv"] is None:
            fail(("cutting", "model"), f"cutting.model {cut['model']} needs the tool's frequency response:"
                                       " tool.modes or tool.frf_csv")
        if cut["radial_depth_mm"] is not None and cut["radial_depth_mm"] > tool["diameter_mm"]:
            fail(("cutting", "radial_depth_mm"), f"must be <= tool.diameter_mm ({format_number(tool['diameter_mm'])} mm),"
                                                 f" got {format_number(cut['radial_depth_mm'])}")
    lr = d["learning"]
    if lr["error"] == "surface" and cut["model"] == "none":
        fail(("learning", "error"), "surface is the wall the cutting error model leaves: it needs cutting.model"
                                    " mechanistic")
    if lr["model_steps"]:
        law = lr["law"]
        kind = lr["error"] if lr["error"] != "auto" else DEFAULT_ERROR[law]
        if law in HISTORY_LAWS:
            fail(("learning", "model_steps"), f"must be 0 with learning.law {law}: the law keeps a history of runs and"
                                             " takes no model-assisted step")
        elif kind not in PREDICTED_ERRORS:
            why = f"learning.error {kind}" if lr["error"] != "auto" else f"learning.error auto ({kind} for law {law})"
            fail(("learning", "model_steps"), f"must be 0 with {why}: the virtual CNC predicts only the"
                                             f" {', '.join(PREDICTED_ERRORS)} estimates; set learning.error to one")
    axes = d["axes"]
    names = ", ".join(axes)
    for ax in d["machine"]["travel_mm"]:
        if ax not in axes:
            fail(("machine", "travel_mm", ax), f"axis {ax} is not defined under axes (defined: {names})")
    ctl = d["controller"]
    if ctl["type"] == "cross_coupled":
        gain_spec = spec_of("controller.cross_coupling_gain")
        if ctl["cross_coupling_gain"] <= 0:
            fail(
                ("controller", "cross_coupling_gain"),
                f"must be > 0 and {gain_spec.range_text().split(' and ')[-1]} when controller.type is"
                f" cross_coupled, got {format_number(ctl['cross_coupling_gain'])}",
                line_path=("controller", "type") if ("controller", "cross_coupling_gain") not in fail.lines else None,
            )
        for ax in ctl["coupled_axes"]:
            if ax not in axes:
                fail(
                    ("controller", "coupled_axes"),
                    f"axis {ax} is not defined under axes (defined: {names}); cross-coupling needs two defined axes",
                )
        for ax in ctl["coupled_axes"]:
            drv = dict(axes[ax]["drive"])
            if not has_position_loop(DRIVE_MODELS[drv.pop("model")](**drv)):
                fail(
                    ("controller", "coupled_axes"),
                    f"axis {ax} has no position loop for the cross-coupled controller to act on (axes.{ax}.drive"
                    " must be mass_damper_pid, p_ff_friction, sopdt with position_gain_1_s or transfer_function"
                    " with feedback unity)",
                )
    for name, g in d["learning"]["gains"].items():
        if isinstance(g, dict):
            for ax in g:
                if ax not in axes:
                    fail(("learning", "gains", name, ax), f"axis {ax} is not defined under axes (defined: {names})")
            for ax in axes:
                if ax not in g:
                    fail(
                        ("learning", "gains", name, ax),
                        f"missing; a per-axis gain must give every axis ({names}) or be one number",
                        line_path=("learning", "gains", name),
                    )
    _schedule_checks(d["tuning"]["schedule"], names, axes, fail)
    for ax, a in axes.items():
        drv = a["drive"]
        p = ("axes", ax, "drive")
        if drv["model"] == "transfer_function":
            _transfer_function_checks(drv, p, fail)
        if drv["model"] != "p_ff_friction":
            continue
        friction = drv["coulomb_n"] > 0 or drv["viscous_n_s_mm"] > 0 or drv["static_n"] > 0
        if friction and drv["inertia_kg"] is None:
            rng = spec_of(f"{DRIVE_KEY}.inertia_kg").range_text()
            fail((*p, "inertia_kg"), f"missing; required ({rng}, kg) when a friction term is non-zero", line_path=p)
        if drv["static_n"] > 0 and drv["static_n"] < drv["coulomb_n"]:
            fail(
                (*p, "static_n"),
                f"must be 0 or >= coulomb_n ({format_number(drv['coulomb_n'])}), got {format_number(drv['static_n'])}",
            )
        if drv["static_n"] > drv["coulomb_n"] and drv["stribeck_velocity_mm_s"] <= 0:
            rng = spec_of(f"{DRIVE_KEY}.stribeck_velocity_mm_s").range_text()
            fail(
                (*p, "stribeck_velocity_mm_s"),
                f"must be > 0 ({rng}) when static_n > coulomb_n, got {format_number(drv['stribeck_velocity_mm_s'])}",
                line_path=p if (*p, "stribeck_velocity_mm_s") not in fail.lines else None,
            )


def _schedule_checks(sch: dict[str, Any], names: str, axes: dict[str, Any], fail: _Fail) -> None:
    """``tuning.schedule``: a defined axis, kp_min < kp_max, distinct ΔK candidates that include 0."""
    p = ("tuning", "schedule")
    if sch["axis"] is not None and sch["axis"] not in axes:
        fail((*p, "axis"), f"axis {sch['axis']} is not defined under axes (defined: {names})")
    if not sch["kp_min_m_min_mm"] < sch["kp_max_m_min_mm"]:
        fail(
            (*p, "kp_min_m_min_mm"),
            f"must be < kp_max_m_min_mm ({format_number(sch['kp_max_m_min_mm'])}), got {format_number(sch['kp_min_m_min_mm'])}",
            line_path=(*p, "kp_min_m_min_mm") if (*p, "kp_min_m_min_mm") in fail.lines else (*p, "kp_max_m_min_mm"),
        )
    dk = sch["dk_candidates"]
    shown = "[" + ", ".join(format_number(x) for x in dk) + "]"
    if 0.0 not in dk:
        fail((*p, "dk_candidates"), f"must include 0 (holding the gain is always a candidate), got {shown}")
    if len(set(dk)) != len(dk):
        dup = next(x for i, x in enumerate(dk) if x in dk[:i])
        fail((*p, "dk_candidates"), f"must be distinct, got {format_number(dup)} twice in {shown}")


def _transfer_function_checks(drv: dict[str, Any], p: tuple[str, ...], fail: _Fail) -> None:
    """A transfer_function drive must be strictly proper and its closed loop stable."""
    num, den = drv["numerator"], drv["denominator"]
    if len(num) >= len(den):
        fail(
            (*p, "numerator"),
            f"must have fewer coefficients than denominator ({len(den)}): the axis transfer function must be"
            f" strictly proper, got {len(num)}",
        )
    char = list(den)
    if drv["feedback"] == "unity":
        char = [c + n for c, n in zip(char, [0.0] * (len(den) - len(num)) + list(num), strict=True)]
    if char[0] == 0:
        fail((*p, "denominator"), "the closed-loop characteristic polynomial (denominator + numerator) has a leading 0")
    poles = np.roots(char)
    bad = [z for z in poles if z.real >= 0]
    if bad:
        what = "1 + L(s)" if drv["feedback"] == "unity" else "the closed loop"
        shown = ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" if abs(z.imag) > 0 else f"{z.real:.4g}" for z in bad)
        fail((*p, "denominator"), f"{what} is unstable: pole(s) with real part >= 0: {shown}")


def _build(d: dict[str, Any], path: Path | None, text: str) -> MachineProfile:
    m = d["machine"]
    axes: dict[str, AxisProfile] = {}
    for name, a in d["axes"].items():
        drv = dict(a["drive"])
        cls = DRIVE_MODELS[drv.pop("model")]
        axes[name] = AxisProfile(
            name=name,
            max_velocity_mm_min=a["max_velocity_mm_min"],
            max_acceleration_m_s2=a["max_acceleration_m_s2"],
            max_jerk_m_s3=a["max_jerk_m_s3"],
            rapid_mm_min=a["rapid_mm_min"] if a["rapid_mm_min"] is not None else a["max_velocity_mm_min"],
            drive=cls(**drv),
        )
    return MachineProfile(
        machine=MachineSection(**m),
        axes=axes,
        controller=ControllerSection(**d["controller"]),
        planner=PlannerSection(**d["planner"]),
        learning=LearningSection(**{**d["learning"], "refine": RefineSection(**d["learning"]["refine"])}),
        output=OutputSection(**d["output"]),
        geometry=GeometrySection(**d["geometry"]),
        tool=ToolSection(**d["tool"]),
        cutting=CuttingSection(**d["cutting"]),
        tuning=TuningSection(schedule=ScheduleTuning(**{("lam" if k == "lambda" else k): v
                                                          for k, v in d["tuning"]["schedule"].items()})),
        path=path,
        source_text=text,
    )


def _validate(data: Any, fail: _Fail, path: Path | None, text: str) -> MachineProfile:
    sections = ", ".join(TOP_SECTIONS)
    if data is None:
        fail.at_line(1, f"empty profile; expected a mapping with the sections {sections}")
    if not isinstance(data, Mapping):
        fail.at_line(fail.root_line, f"the profile must be a mapping with the sections {sections}, got {_got(data)}")
    v = _Validator(fail)
    d = v.section("", (), data)
    _cross_checks(d, fail)
    return _build(d, path, text)


# --------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------


def load_profile(path: str | Path) -> MachineProfile:
    """Read, check and return the machine profile in a YAML file.

    Parameters
    ----------
    path : str or Path
        The YAML file.

    Returns
    -------
    MachineProfile
        The profile with every default filled.

    Raises
    ------
    ProfileError
        When the file cannot be read, is not valid YAML, or a key is unknown,
        missing, of the wrong type or out of range. The message is one line:
        ``file:line: yaml.path: problem``.
    """
    p = Path(path)
    try:
        raw = read_bytes(p)
    except InputError as exc:
        raise ProfileError(exc.file, exc.line, exc.problem) from None
    fail = _Fail(p)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        fail.at_line(raw.count(b"\n", 0, exc.start) + 1, "not UTF-8 text; save the profile as UTF-8")
    data, root_line = _parse_yaml(text, fail)
    fail.root_line = root_line
    return _validate(data, fail, p, text)


def profile_from_dict(data: Mapping[str, Any], *, path: str | Path | None = None) -> MachineProfile:
    """Check and return a machine profile given as plain data.

    Parameters
    ----------
    data : mapping
        The profile as :func:`yaml.safe_load` or :meth:`MachineProfile.to_dict`
        gives it.
    path : str or Path, optional
        File name used in error messages.

    Returns
    -------
    MachineProfile

    Raises
    ------
    ProfileError
        As :func:`load_profile` (without line numbers).
    """
    p = Path(path) if path is not None else None
    return _validate(data, _Fail(p), p, "")


_DEFAULT_DRIVE: dict[str, Any] = {"model": "sopdt", "gain": 1.0, "omega0_rad_s": 95.6, "zeta": 1.0, "delay_s": 0.0066}

_DEFAULT_PROFILE: dict[str, Any] = {
    "machine": {"name": "generic 3-axis VMC", "units": "mm", "servo_period_s": 0.001, "resolution_mm": 0.001},
    "axes": {
        "x": {
            "max_velocity_mm_min": 30000.0,
            "max_acceleration_m_s2": 3.0,
            "max_jerk_m_s3": 50.0,
            "rapid_mm_min": 36000.0,
            "drive": _DEFAULT_DRIVE,
        },
        "y": {
            "max_velocity_mm_min": 30000.0,
            "max_acceleration_m_s2": 3.0,
            "max_jerk_m_s3": 50.0,
            "rapid_mm_min": 36000.0,
            "drive": _DEFAULT_DRIVE,
        },
        "z": {
            "max_velocity_mm_min": 24000.0,
            "max_acceleration_m_s2": 2.5,
            "max_jerk_m_s3": 40.0,
            "rapid_mm_min": 30000.0,
            "drive": _DEFAULT_DRIVE,
        },
    },
}


def default_profile() -> MachineProfile:
    """Return the profile used when none is given: a generic 3-axis mill.

    It is the same machine as ``configs/example-mill.yaml``: 30 m/min,
    3 m/s², 50 m/s³ on X/Y (24 m/min, 2.5 m/s², 40 m/s³ on Z), SOPDT velocity
    drives with the seed-004 fit (ω0 = 95.6 rad/s, ζ = 1, Td = 6.6 ms, unity
    gain), independent axes, a 7-phase planner and a P-type law with Γ = 0.5.
    """
    return profile_from_dict(_DEFAULT_PROFILE)


