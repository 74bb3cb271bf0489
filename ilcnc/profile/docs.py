"""The profile reference (``docs/profile.md``'s generated block), written from the schema table.

``python -m ilcnc.profile`` prints :func:`schema_markdown`; a test checks ``docs/profile.md`` holds it.
"""

from __future__ import annotations

from collections.abc import Iterator

from ilcnc.profile.schema import MAX_COEFFS, MAX_DK_CANDIDATES, SPECS, TOP_SECTIONS, Spec, format_number
from ilcnc.units import AXIS_NAMES

__all__ = ["schema_markdown"]


# --------------------------------------------------------------------------
# Documentation from the schema
# --------------------------------------------------------------------------


def _iter_doc_rows(section: str) -> Iterator[Spec]:
    for s in SPECS:
        if s.path == section or s.path.startswith(section + "."):
            yield s


def _doc_default(s: Spec) -> str:
    if s.default_doc:
        return s.default_doc
    if s.required:
        return "**required**"
    if s.kind in ("section", "axis_map"):
        return "all defaults" if s.kind == "section" else "none"
    if s.default is None:
        return "none"
    if isinstance(s.default, tuple):
        return "[" + ", ".join(str(x) for x in s.default) + "]"
    if isinstance(s.default, str):
        return f"`{s.default}`"
    return format_number(s.default)


def _doc_type(s: Spec) -> str:
    return {
        "section": "mapping",
        "axis_map": "mapping by axis",
        "float": "number",
        "int": "integer",
        "str": "text",
        "choice": "choice",
        "axis_float": "number or per-axis",
        "range_pair": "[min, max]",
        "axis_pair": "[axis, axis]",
        "coeffs": "[number, ...]",
        "numbers": "[number, ...]",
        "modes": "list of modes",
    }[s.kind]


def schema_markdown() -> str:
    """Return the reference tables of ``docs/profile.md``, generated from :data:`SPECS`.

    Returns
    -------
    str
        Markdown: one table per section, conditional keys (drive models,
        learning laws) in tables of their own.
    """
    lines: list[str] = []
    header = ["| key | type | unit | allowed | default | description |", "|---|---|---|---|---|---|"]
    for top in TOP_SECTIONS:
        groups: dict[tuple[str, str] | None, list[Spec]] = {}
        for s in _iter_doc_rows(top):
            groups.setdefault(s.when, []).append(s)
        for when, specs in groups.items():
            title = f"`{top}`" if when is None else f"`{top}` — `{when[0]}: {when[1]}`"
            lines += [f"### {title}", "", *header]
            for s in specs:
                desc = s.doc.replace("|", "\\|")
                rng = s.range_text() if s.kind not in ("section", "axis_map", "str", "axis_pair", "coeffs", "modes") else ""
                if s.kind == "coeffs":
                    rng = f"1 to {MAX_COEFFS} finite numbers, the first non-zero"
                if s.kind == "axis_pair":
                    rng = "two different of " + ", ".join(AXIS_NAMES)
                if s.kind == "numbers":
                    rng = f"1 to {MAX_DK_CANDIDATES} numbers {s.range_text()}"
                lines.append(
                    f"| `{s.path}` | {_doc_type(s)} | {s.unit or '—'} | {rng or '—'} | {_doc_default(s)} | {desc} |"
                )
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":  # pragma: no cover
    print(schema_markdown(), end="")
