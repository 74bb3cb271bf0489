"""Edit a machine profile in place, keeping its comments, key order and anchors.

``ilcnc identify --write`` and ``ilcnc tune --write`` store what they found in
the user's own profile YAML. The profile is a hand-written, commented file
(``configs/*.yaml``): rewriting it from data would lose every comment, the key
order, the number formats and the anchors that share one drive between axes.
:func:`update_profile` therefore edits the *text*: it locates each key with the
YAML parser's marks (PyYAML events: exact character spans of every scalar,
collection, anchor and alias) and replaces only the characters of the values
that change. Every other byte of the file stays as it was, so a diff shows the
edited values, the notes and, when sharing has to be broken, the copied
mapping.

Semantics of an update ``{"a.b.c": value}``
-------------------------------------------
* A scalar (number, string, bool) or a list replaces the value at the path;
  the comment after it on its line is kept. Numbers are written in their
  shortest exact form (``95.613``, ``0.0066``, ``1.0e-05``).
* A mapping replaces the mapping at the path: keys present in both are
  rewritten in place (their comments kept), new keys are appended at the end
  of the mapping with its indentation, keys the new mapping lacks are removed
  (with their line). A small flat mapping replacing a scalar is written in
  flow style, e.g. ``kp: {x: 0.5, y: 0.4}``.
* ``None`` removes the key (optional profile keys mean "absent" by ``None``).
* Missing parents are created (block style).
* A value equal to the current one (numerically: ``8`` equals ``8.0``) is not
  rewritten, so its text (``8.0``) stays.

Anchors and aliases
-------------------
Profiles share a drive between axes with an anchor, e.g. x's
``drive: &sopdt_seed004`` and y's ``drive: *sopdt_seed004``. Editing through
an alias would change every axis that shares the node, so an edit that
*changes* something inside a shared node first breaks the sharing for the
edited path only, and says so in a ``# ilcnc alias:`` comment:

* editing y (an alias): y's ``*sopdt_seed004`` becomes its own copy of the
  anchored mapping (values and their end-of-line comments; the full-line
  comments of the original are not duplicated); x and z keep the anchor;
* editing x (the anchor's owner): the anchor, with the values x had, moves to
  the first alias (y), the other aliases (z) now refer to it there, and x gets
  its own values.

Either way every other path keeps its value; this is checked before anything
is written (the updated profile, loaded, must equal the old one with only the
updated paths changed).

Notes
-----
With ``note=...`` a one-line comment ``# ilcnc: <note>`` is put on the line
above each edited key (e.g. how and when the values were identified and the
hash of the source file). A ``# ilcnc:`` note already directly above that key
is replaced, so repeated ``--write`` runs do not pile notes up.

Safety
------
The updated text is validated with :func:`ilcnc.profile.load.load_profile` before
anything is written: an invalid result raises :class:`ProfileError` naming
the key and the file is left untouched. The file is written atomically
(temporary file + rename), to ``out`` or in place; ``protect`` lists input
files (a program, a log) that must never be written over. A UTF-8 BOM and
CRLF line endings are kept.
"""

from __future__ import annotations

import json
import math
import numbers
import re
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from yaml.events import (
    AliasEvent,
    MappingEndEvent,
    MappingStartEvent,
    ScalarEvent,
    SequenceEndEvent,
    SequenceStartEvent,
)

from ilcnc.errors import ProfileError
from ilcnc.fileio import read_bytes, write_atomic
from ilcnc.profile.load import load_profile

__all__ = ["NOTE_PREFIX", "REMARK_PREFIX", "format_scalar", "update_profile", "update_text"]

#: Prefix of the note comments :func:`update_profile` writes (and replaces on the next write).
NOTE_PREFIX = "# ilcnc: "

#: Prefix of the comments that say where an alias was broken (never replaced by a note).
REMARK_PREFIX = "# ilcnc alias: "


class _Loader(yaml.SafeLoader):
    """Safe loader that reads ``1e-5`` (no dot) as a float, as the profile loader does."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)

_MISSING: Any = object()


# --------------------------------------------------------------------------
# Parsed text: nodes with exact character spans
# --------------------------------------------------------------------------


@dataclass(eq=False)
class _Node:
    """One YAML node with its character span in the text.

    ``start``: first character (anchor and tag included); ``body``: first
    character of the content; ``end``: one past the last character of the
    content (a block collection ends at its last value, before comments).
    """

    kind: str  # "scalar", "map", "seq" or "alias"
    start: int
    body: int
    end: int = 0
    path: tuple[str, ...] = ()
    anchor: str | None = None
    anchor_span: tuple[int, int] | None = None
    flow: bool = False
    style: str | None = None
    value: str | None = None
    items: list[tuple[_Node, _Node]] = field(default_factory=list)
    children: list[_Node] = field(default_factory=list)
    target: _Node | None = None
    aliases: list[_Node] = field(default_factory=list)
    key: _Node | None = None  # the key node when this node is a mapping value

    def find(self, key: str) -> tuple[_Node, _Node] | None:
        for k, v in self.items:
            if k.kind == "scalar" and k.value == key:
                return k, v
        return None

    def walk(self):  # type: ignore[no-untyped-def]
        yield self
        for k, v in self.items:
            yield from k.walk()
            yield from v.walk()
        for c in self.children:
            yield from c.walk()


def _skip_props(text: str, start: int, end: int) -> int:
    """Index of the content after the anchor (``&a``) and tag (``!!float``) tokens at ``start``."""
    i = start
    while i < end and text[i] in "&!":
        while i < end and not text[i].isspace():
            i += 1
        while i < end and text[i] in " \t\n":
            i += 1
    return i


def _parse(text: str) -> _Node:
    """Parse the first document of ``text`` into :class:`_Node` s (aliases bound to their anchors)."""
    events = iter(yaml.parse(text, Loader=_Loader))
    anchors: dict[str, _Node] = {}

    def props(n: _Node, anchor: str | None) -> None:
        if anchor:
            token = "&" + anchor
            i = text.find(token, n.start, max(n.body, n.start + len(token)))
            n.anchor = anchor
            n.anchor_span = (i, i + len(token)) if i >= 0 else None
            anchors[anchor] = n

    def build(ev: Any, path: tuple[str, ...]) -> _Node:
        s, e = ev.start_mark.index, ev.end_mark.index
        if isinstance(ev, AliasEvent):
            tgt = anchors[ev.anchor]
            n = _Node("alias", s, s, e, path=path, anchor=ev.anchor, target=tgt)
            tgt.aliases.append(n)
            return n
        if isinstance(ev, ScalarEvent):
            n = _Node("scalar", s, _skip_props(text, s, e), e, path=path, style=ev.style or "", value=ev.value)
            props(n, ev.anchor)
            return n
        if isinstance(ev, (MappingStartEvent, SequenceStartEvent)):
            is_map = isinstance(ev, MappingStartEvent)
            flow = bool(ev.flow_style)
            n = _Node("map" if is_map else "seq", s, _skip_props(text, s, e) if flow else s, path=path, flow=flow)
            if flow:
                n.body = text.find("{" if is_map else "[", s)
            props(n, ev.anchor)
            closing = MappingEndEvent if is_map else SequenceEndEvent
            while True:
                sub = next(events)
                if isinstance(sub, closing):
                    end_ev = sub
                    break
                if is_map:
                    k = build(sub, path)
                    v = build(next(events), (*path, str(k.value)))
                    v.key = k
                    n.items.append((k, v))
                else:
                    n.children.append(build(sub, (*path, str(len(n.children)))))
            if flow:
                n.end = end_ev.end_mark.index
            else:
                last = n.items[-1][1] if n.items else (n.children[-1] if n.children else None)
                n.body = (n.items[0][0].start if n.items else n.children[0].start) if last is not None else s
                n.end = last.end if last is not None else s
            return n
        raise ValueError(f"unexpected YAML event {type(ev).__name__}")  # pragma: no cover

    for ev in events:
        if isinstance(ev, (ScalarEvent, MappingStartEvent, SequenceStartEvent, AliasEvent)):
            return build(ev, ())
    return _Node("scalar", 0, 0, 0, value="")


# --------------------------------------------------------------------------
# Formatting of new values
# --------------------------------------------------------------------------


def format_scalar(value: Any) -> str:
    """Return YAML text for a scalar that the profile loader reads back as ``value``.

    Parameters
    ----------
    value : bool, int, float, str or None
        The value.

    Returns
    -------
    str
        ``true``/``false``, an integer, the shortest exact float text (with a
        dot, so YAML 1.1 readers see a float: ``1.0e-05``, ``2.0``), a plain
        string when it reads back unchanged, else a double-quoted one.

    Raises
    ------
    ValueError
        For NaN or infinite floats and unsupported types.
    """
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"cannot write a non-finite number ({v}) into a profile")
        s = repr(v)
        if "e" in s or "E" in s:
            mant, exp = s.split("e")
            if "." not in mant:
                mant += ".0"
            s = f"{mant}e{exp}"
        elif "." not in s:
            s += ".0"
        return s
    if isinstance(value, str):
        if value and "\n" not in value:
            try:
                if yaml.load(f"k: {value}", Loader=_Loader) == {"k": value} and not value.startswith(("&", "*", "!", "#")):
                    return value
            except yaml.YAMLError:
                pass
        return json.dumps(value, ensure_ascii=False)
    raise ValueError(f"cannot write a {type(value).__name__} into a profile")


def _flow(value: Any) -> str:
    """Flow-style text of a scalar, list or mapping."""
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{format_scalar(str(k))}: {_flow(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_flow(v) for v in value) + "]"
    return format_scalar(value)


def _is_flat(value: Any) -> bool:
    """A mapping of scalars (or short lists): written in flow style in place of a scalar."""
    return isinstance(value, Mapping) and all(not isinstance(v, Mapping) for v in value.values()) and len(value) <= 6


def _block(value: Mapping[str, Any], col: int, step: int) -> list[str]:
    """Block-style lines of a mapping at indentation ``col``."""
    out: list[str] = []
    for k, v in value.items():
        if isinstance(v, Mapping) and v:
            out.append(f"{' ' * col}{format_scalar(str(k))}:")
            out.extend(_block(v, col + step, step))
        else:
            out.append(f"{' ' * col}{format_scalar(str(k))}: {_flow(v)}")
    return out


def _plain(value: Any) -> Any:
    """Plain Python data (numpy scalars to int/float, tuples to lists) for comparison and writing."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    return value


def _same(a: Any, b: Any) -> bool:
    """Equal as profile values (``8 == 8.0``; mappings regardless of key order)."""
    if a is _MISSING or b is _MISSING:
        return a is b
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if isinstance(a, numbers.Real) and isinstance(b, numbers.Real):
        return float(a) == float(b)
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return set(map(str, a)) == set(map(str, b)) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


def _get(data: Any, keys: Sequence[str]) -> Any:
    for k in keys:
        if not isinstance(data, Mapping) or k not in data:
            return _MISSING
        data = data[k]
    return data


def _put(data: dict[str, Any], keys: Sequence[str], value: Any) -> None:
    """Apply one update to plain data (the expected result of the text edit)."""
    d = data
    for k in keys[:-1]:
        if not isinstance(d.get(k), dict):
            d[k] = {}
        d = d[k]
    if value is None:
        d.pop(keys[-1], None)
    else:
        d[keys[-1]] = _plain(value)


def _deep_copy(data: Any) -> Any:
    if isinstance(data, Mapping):
        return {k: _deep_copy(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_deep_copy(v) for v in data]
    return data


# --------------------------------------------------------------------------
# The text editor
# --------------------------------------------------------------------------


class _Editor:
    """Edits on YAML text; every operation re-parses (profiles are small)."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.step = self._indent_step()

    # ---- text helpers -----------------------------------------------------

    def line_start(self, i: int) -> int:
        return self.text.rfind("\n", 0, i) + 1

    def line_end(self, i: int) -> int:
        j = self.text.find("\n", i)
        return len(self.text) if j < 0 else j

    def col(self, i: int) -> int:
        return i - self.line_start(i)

    def data(self) -> Any:
        return yaml.load(self.text, Loader=_Loader)

    def _indent_step(self) -> int:
        steps: dict[int, int] = {}
        try:
            root = _parse(self.text)
        except yaml.YAMLError:
            return 2
        for n in root.walk():
            if n.kind == "map" and not n.flow and n.items and n.key is not None:
                d = self.col(n.body) - self.col(n.key.start)
                if d > 0:
                    steps[d] = steps.get(d, 0) + 1
        return max(steps, key=lambda d: steps[d]) if steps else 2

    def _comment_tail(self, a: int, b: int) -> str:
        """The comment (with the blanks before it) in ``text[a:b]``, or ``""``."""
        seg = self.text[a:b]
        m = re.search(r"(\s+#.*)$", seg)
        return m.group(1) if m else ""

    def _colon_after(self, key: _Node) -> int:
        i = key.end
        while i < len(self.text) and self.text[i] in " \t":
            i += 1
        if i >= len(self.text) or self.text[i] != ":":
            raise ValueError(f"cannot find the ':' after key {key.value!r}")
        return i

    def _splice(self, a: int, b: int, new: str) -> None:
        """Replace ``text[a:b]`` (within one line) by ``new``, keeping a following comment in its column."""
        le = self.line_end(b)
        rest = self.text[b:le]
        m = re.match(r"^([ \t]+)#", rest)
        if m and "\n" not in new:
            comment_col = self.col(b) + len(m.group(1))
            end_col = self.col(a) + len(new)
            if len(m.group(1)) == 2:  # pushed out by a longer value before? line up with the neighbours again
                near = self._neighbour_comment_col(a)
                if near is not None and near >= end_col + 2:
                    comment_col = near
            blanks = max(comment_col - end_col, 2 if len(m.group(1)) >= 2 else 1)
            self.text = self.text[:a] + new + " " * blanks + rest[len(m.group(1)):] + self.text[le:]
        else:
            self.text = self.text[:a] + new + self.text[b:]

    def _neighbour_comment_col(self, i: int) -> int | None:
        """Column of the end-of-line comment on the line above or below the line of ``i``, if any."""
        ls = self.line_start(i)
        le = self.line_end(i)
        around = []
        if ls > 0:
            around.append(self.text[self.line_start(ls - 1): ls - 1])
        if le < len(self.text):
            around.append(self.text[le + 1: self.line_end(le + 1)])
        for line in around:
            m = re.search(r"\S(\s+)#", line)
            if m and not line.lstrip().startswith("#"):
                return m.end() - 1
        return None

    # ---- operations -------------------------------------------------------

    def set(self, keys: tuple[str, ...], value: Any) -> None:
        """Set ``keys`` to ``value`` (``None``: remove the key)."""
        if value is None:
            self.delete(keys)
            return
        if _same(_get(self.data(), keys), value):
            return
        while True:
            root = _parse(self.text)
            node = root
            for i, key in enumerate(keys):
                if node.kind != "map":
                    where = ".".join(keys[:i]) or "the document"
                    raise ValueError(f"{where} is not a mapping: cannot set {'.'.join(keys)}")
                item = node.find(key)
                if item is None:
                    nested: Any = value
                    for k in reversed(keys[i + 1:]):
                        nested = {k: nested}
                    self._insert(node, key, nested)
                    return
                knode, vnode = item
                if vnode.kind == "alias" or vnode.aliases:
                    self._unshare(vnode)
                    break  # re-parse and walk again
                if i < len(keys) - 1 and vnode.kind == "scalar" and vnode.style == "" and vnode.value in ("", "~", "null"):
                    nested = value  # "key:" with no value (null): it becomes the mapping the path needs
                    for k in reversed(keys[i + 1:]):
                        nested = {k: nested}
                    self._replace(knode, vnode, nested)
                    return
                if i == len(keys) - 1:
                    if isinstance(value, Mapping) and vnode.kind == "map" and not vnode.flow and vnode.items:
                        for k, v in value.items():
                            self.set((*keys, str(k)), v)
                        data = _get(self.data(), keys)
                        for k in [k for k in data if k not in value]:
                            self.delete((*keys, k))
                    else:
                        self._replace(knode, vnode, value)
                    return
                node = vnode

    def delete(self, keys: tuple[str, ...]) -> None:
        """Remove the key at ``keys`` (nothing when it is absent)."""
        if _get(self.data(), keys) is _MISSING:
            return
        while True:
            root = _parse(self.text)
            node = root
            restart = False
            for i, key in enumerate(keys[:-1]):
                item = node.find(key)
                if item is None or item[1].kind not in ("map", "alias"):
                    raise ValueError(f"cannot remove {'.'.join(keys)}: {'.'.join(keys[: i + 1])} is inherited or not a mapping")
                vnode = item[1]
                if vnode.kind == "alias" or vnode.aliases:
                    self._unshare(vnode)
                    restart = True
                    break
                node = vnode
            if restart:
                continue
            if node.kind != "map":
                raise ValueError(f"cannot remove {'.'.join(keys)}: its parent is not a mapping")
            item = node.find(keys[-1])
            if item is None:
                raise ValueError(f"cannot remove {'.'.join(keys)}: it is inherited through a merge key (<<)")
            knode, vnode = item
            if node.flow:
                data = _get(self.data(), keys[:-1])
                new = {k: v for k, v in data.items() if k != keys[-1]}
                self.text = self.text[: node.body] + _flow(new) + self.text[node.end:]
                return
            a = self.line_start(knode.start)
            if self.text[a: knode.start].strip():
                raise ValueError(f"cannot remove {'.'.join(keys)}: the key does not start its line")
            b = self.line_end(max(vnode.end, knode.end))
            self.text = self.text[:a] + self.text[min(b + 1, len(self.text)):]
            return

    def _insert(self, parent: _Node, key: str, value: Any) -> None:
        """Add ``key: value`` at the end of the mapping ``parent``."""
        if parent.flow or not parent.items:
            if parent.flow:
                data = _get(self.data(), parent.path) if parent.path else self.data()
                new = dict(data or {})
                new[key] = _plain(value)
                self.text = self.text[: parent.body] + _flow(new) + self.text[parent.end:]
                return
            raise ValueError(f"cannot add {key} to the empty mapping at {'.'.join(parent.path)}")  # pragma: no cover
        col = self.col(parent.items[0][0].start)
        lines = _block({key: _plain(value)}, col, self.step)
        at = self.line_end(parent.end)
        self.text = self.text[:at] + "\n" + "\n".join(lines) + self.text[at:]

    def _replace(self, knode: _Node, vnode: _Node, value: Any) -> None:
        """Replace the value ``vnode`` of key ``knode`` with ``value``."""
        value = _plain(value)
        nested = isinstance(value, Mapping) and not _is_flat(value)
        block_val = (vnode.kind in ("map", "seq") and not vnode.flow) or (vnode.kind == "scalar" and vnode.style in ("|", ">"))
        empty_val = vnode.kind == "scalar" and vnode.body == vnode.end and vnode.style == ""
        if not block_val and not nested:
            text = _flow(value)
            if empty_val:
                text = " " + text
            self._splice(vnode.body, vnode.end, text)
            return
        # the key line keeps its comment; the old value's lines go; the new value follows
        colon = self._colon_after(knode)
        key_line_end = self.line_end(colon)
        last_line_end = self.line_end(max(vnode.end, colon))
        tail = self._comment_tail(colon + 1, key_line_end)
        head = self.text[self.line_start(knode.start): colon + 1]
        if nested:
            col = self.col(knode.start) + self.step
            new = head + tail + "\n" + "\n".join(_block(value, col, self.step))
        else:
            new = head + " " + _flow(value) + tail
        self.text = self.text[: self.line_start(knode.start)] + new + self.text[last_line_end:]

    # ---- sharing ----------------------------------------------------------

    def _copy_lines(self, tgt: _Node, new_col: int) -> list[str]:
        """The lines of the block node ``tgt`` re-indented to ``new_col``, full-line comments dropped."""
        a = self.line_start(tgt.body)
        b = self.line_end(tgt.end)
        old_col = self.col(tgt.body)
        block_scalars = [(n.start, n.end) for n in tgt.walk() if n.kind == "scalar" and n.style in ("|", ">")]
        out: list[str] = []
        pos = a
        for line in self.text[a:b].split("\n"):
            inside = any(s <= pos < e for s, e in block_scalars)
            pos += len(line) + 1
            if not inside and line.lstrip().startswith("#"):
                continue
            if not line.strip():
                out.append("")
                continue
            lead = len(line) - len(line.lstrip(" "))
            out.append(" " * max(0, lead - old_col + new_col) + line.lstrip(" "))
        return out

    def _site_replacement(self, site: _Node, tgt: _Node, *, keep_anchor: bool, remark: str) -> tuple[int, int, str]:
        """Text edit that replaces the alias ``site`` by a copy of ``tgt`` (optionally with its anchor)."""
        if site.key is None:
            raise ValueError(f"cannot break the alias *{site.anchor} at {'.'.join(site.path)} (not a mapping value)")
        ls = self.line_start(site.start)
        le = self.line_end(site.end)
        after = self.text[site.end: le]
        block_site = not after.strip() or after.strip().startswith("#")
        anchor = f"&{tgt.anchor} " if keep_anchor else ""
        ind = " " * self.col(site.key.start)
        remark_line = f"{ind}{REMARK_PREFIX}{remark}\n" if self.text[ls: site.key.start].strip() == "" else ""
        if tgt.kind in ("map", "seq") and not tgt.flow:
            if not block_site:
                data = _get(self.data(), tgt.path) if tgt.path else self.data()
                return site.start, site.end, anchor + _flow(data)
            key_col = self.col(site.key.start)
            step = self.col(tgt.body) - self.col(tgt.key.start) if tgt.key is not None else self.step
            lines = self._copy_lines(tgt, key_col + max(step, 1))
            head = self.text[ls: site.start].rstrip()
            anchor_txt = f" &{tgt.anchor}" if keep_anchor else ""
            return ls, le, remark_line + head + anchor_txt + after + "\n" + "\n".join(lines)
        # a scalar or a flow collection: copy its text in place
        body = self.text[tgt.body: tgt.end]
        if remark_line:
            return ls, le, remark_line + self.text[ls: site.start] + anchor + body + after
        return site.start, site.end, anchor + body

    def _unshare(self, node: _Node) -> None:
        """Break the sharing of ``node`` (an alias, or an anchored node with aliases) for its own path only."""
        path = ".".join(node.path)
        edits: list[tuple[int, int, str]] = []
        if node.kind == "alias":
            tgt = node.target
            assert tgt is not None
            others = [".".join(tgt.path)] + [".".join(a.path) for a in tgt.aliases if a is not node]
            remark = (
                f"was *{node.anchor} (shared with {', '.join(others)}); own copy so that editing {path}"
                " leaves the others unchanged"
            )
            edits.append(self._site_replacement(node, tgt, keep_anchor=False, remark=remark))
        else:
            first = min(node.aliases, key=lambda a: a.start)
            remark_site = f"anchor &{node.anchor} moved here from {path} (with its values before {path} was edited)"
            edits.append(self._site_replacement(first, node, keep_anchor=True, remark=remark_site))
            if node.anchor_span is None:  # pragma: no cover - the parser always finds the token
                raise ValueError(f"cannot find the anchor &{node.anchor} of {path}")
            s, e = node.anchor_span
            while s > 0 and self.text[s - 1] in " \t":
                s -= 1
            edits.append((s, e, ""))  # "key: &a value" -> "key: value" (the blank after the token stays)
            if node.key is not None and not self.text[self.line_start(node.key.start): node.key.start].strip():
                ls = self.line_start(node.key.start)
                ind = " " * self.col(node.key.start)
                edits.append((ls, ls, f"{ind}{REMARK_PREFIX}was &{node.anchor}, now moved to {'.'.join(first.path)}:"
                                      f" {path} has its own values\n"))
        for s, e, new in sorted(edits, key=lambda x: (x[0], x[1]), reverse=True):
            self.text = self.text[:s] + new + self.text[e:]

    # ---- notes ------------------------------------------------------------

    def note(self, keys: tuple[str, ...], note: str) -> None:
        """Put ``# ilcnc: note`` on the line above the key at ``keys`` (replacing an earlier note there)."""
        node = _parse(self.text)
        knode = None
        for key in keys:
            if node.kind != "map":
                return
            item = node.find(key)
            if item is None:
                return
            knode, node = item
        if knode is None:
            return
        ls = self.line_start(knode.start)
        line = self.text[ls: self.line_end(ls)]
        ind = line[: len(line) - len(line.lstrip(" "))]
        new = f"{ind}{NOTE_PREFIX}{' '.join(note.split())}"
        # the comment block directly above the key
        j = ls
        while j > 0:
            ps = self.line_start(j - 1)
            prev = self.text[ps: j - 1]
            if not prev.lstrip().startswith("#"):
                break
            if prev.lstrip().startswith(NOTE_PREFIX):
                self.text = self.text[:ps] + new + self.text[j - 1:]
                return
            j = ps
        self.text = self.text[:ls] + new + "\n" + self.text[ls:]


# --------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------


def _split_path(path: str) -> tuple[str, ...]:
    keys = tuple(path.split("."))
    if not path or any(not k for k in keys):
        raise ValueError(f"bad profile key path {path!r} (expected dotted keys, e.g. axes.x.drive.zeta)")
    return keys


def update_text(text: str, updates: Mapping[str, object], *, note: str | None = None) -> str:
    """Apply ``updates`` to YAML ``text`` and return the new text (no validation, no I/O).

    Parameters
    ----------
    text : str
        YAML text (``\\n`` line ends).
    updates : mapping of str to object
        Dotted key path to new value; see the module docstring.
    note : str, optional
        One-line note written as ``# ilcnc: note`` above each edited key.

    Returns
    -------
    str
        The edited text. Parts of the text not edited are byte-identical.

    Raises
    ------
    ValueError
        A path through a non-mapping, a value that cannot be written, or a
        result that would change something besides the updated paths.
    yaml.YAMLError
        ``text`` is not valid YAML.
    """
    ed = _Editor(text)
    before = ed.data()
    expected = _deep_copy(before) if isinstance(before, Mapping) else {}
    for path, value in updates.items():
        keys = _split_path(path)
        ed.set(keys, value)
        _put(expected, keys, value)
    after = ed.data()
    if not _same(after, expected):
        raise ValueError("internal error: the edit would change more than the updated keys; nothing written")
    if note:
        for path, value in updates.items():
            keys = _split_path(path)
            ed.note(keys if value is not None else keys[:-1], note)
    return ed.text


def update_profile(
    path: str | Path,
    updates: Mapping[str, object],
    *,
    out: str | Path | None = None,
    note: str | None = None,
    protect: Sequence[str | Path] = (),
) -> Path:
    """Set values at dotted YAML paths of a machine profile, keeping its comments, order and anchors.

    Parameters
    ----------
    path : str or Path
        The profile YAML (must load without errors).
    updates : mapping of str to object
        Dotted key path to new value, applied in order, e.g.
        ``{"axes.x.drive": {"model": "sopdt", "gain": 1.0, "omega0_rad_s": 95.6,
        "zeta": 1.0, "delay_s": 0.0066}}``, ``{"axes.x.drive.zeta": 0.9}`` or
        ``{"learning.gains.kp": {"x": 0.5, "y": 0.4}}``. A mapping replaces the
        mapping at its path (keys it lacks are removed); ``None`` removes a key.
        Numpy scalars are accepted.
    out : str or Path, optional
        Write here instead of in place (the default: the profile is the
        user's own configuration and ``--write`` updates it).
    note : str, optional
        One-line note, written as ``# ilcnc: <note>`` on the line above each
        edited key (replacing an earlier ``# ilcnc:`` note there), e.g.
        ``"identified 2026-05-01 from step.csv (sha256 1a2b3c4d): sopdt, R² 0.998"``.
    protect : sequence of paths
        Input files (program, log) that must never be written over.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ProfileError
        The profile does not load, an update path is not a mapping, or the
        updated profile would be invalid (the message names the key, e.g.
        ``axes.x.drive.zeta: must be > 0 and <= 10, got -1``); nothing is
        written then.
    InputError
        ``out`` (or the profile) is one of ``protect``, or cannot be written.
    """
    p = Path(path)
    load_profile(p)  # the original must be a valid profile
    raw = read_bytes(p)
    bom = raw.startswith(b"\xef\xbb\xbf")
    text = raw.decode("utf-8-sig")
    crlf = "\r\n" in text
    if crlf:
        text = text.replace("\r\n", "\n")
    try:
        new = update_text(text, updates, note=note)
    except ValueError as exc:
        raise ProfileError(p, None, f"update refused, profile not changed: {exc}") from None
    dest = Path(out) if out is not None else p
    final = new.replace("\n", "\r\n") if crlf else new
    data = (b"\xef\xbb\xbf" if bom else b"") + final.encode("utf-8")
    with tempfile.TemporaryDirectory(prefix="ilcnc-profile-") as tmp:
        check = Path(tmp) / p.name
        check.write_bytes(data)
        try:
            load_profile(check)
        except ProfileError as exc:
            raise ProfileError(p, None, f"update refused, profile not changed: {exc.problem}") from None
    return write_atomic(dest, data, protect=tuple(protect))
