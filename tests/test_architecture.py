"""The layers of ilcnc, checked over the import graph (``docs/architecture.md``).

Every ``import`` statement of the package counts, also those inside functions (a lazy import is still a
dependency); imports under ``if TYPE_CHECKING:`` count for the direction of the layers but not for cycles
(they never run). A new upward import, cycle or import of another module's private name fails here.
"""

from __future__ import annotations

import ast
import importlib
import warnings
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "ilcnc"

#: Bottom first. A module may import from its own layer's package or from any layer below.
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("base", ("ilcnc.errors", "ilcnc.units", "ilcnc.outcomes", "ilcnc.fileio", "ilcnc.jsonout", "ilcnc.wording",
              "ilcnc._jit", "ilcnc._threads", "ilcnc._memory", "ilcnc._lazy", "ilcnc._moved")),
    ("data", ("ilcnc.program", "ilcnc.profile", "ilcnc.axislog")),  # siblings: none imports another
    ("contour", ("ilcnc.contour",)),
    ("vcnc", ("ilcnc.vcnc",)),
    ("learning", ("ilcnc.learning",)),
    ("shop", ("ilcnc.shop",)),
    ("cli", ("ilcnc.cli", "ilcnc.cli_options", "ilcnc.cli_output", "ilcnc.cli_linuxcnc", "ilcnc.cli_values",
             "ilcnc.__main__", "ilcnc")),
]

#: Modules above ~1,200 lines, each one concept (issue 19 asks to say which and why).
LARGE_MODULES = {
    "ilcnc.program.heidenhain": "the Klartext interpreter: one class (1,150 lines) holding the control's modal state"
                                " (plane, datum shift, Q parameters, the held move that RND/CHF/APPR/DEP shorten) that"
                                " every block kind reads and changes; lexer, formulas and writer are their own modules",
}
MAX_LINES = 1200


def _modules() -> dict[str, Path]:
    mods = {}
    for p in ROOT.rglob("*.py"):
        parts = p.relative_to(ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = p
    return mods


MODULES = _modules()


def _layer(mod: str) -> tuple[int, str]:
    best = (-1, "", "")
    for i, (_name, prefixes) in enumerate(LAYERS):
        for pre in prefixes:
            inside = mod == pre or (pre != "ilcnc" and mod.startswith(pre + "."))
            if inside and len(pre) > len(best[2]):
                best = (i, pre, pre)
    assert best[0] >= 0, f"{mod} is in no layer: add it to LAYERS and docs/architecture.md"
    return best[0], best[1]


def _type_checking_lines(tree: ast.Module) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for sub in node.body:
                for n in ast.walk(sub):
                    if hasattr(n, "lineno"):
                        lines.add(n.lineno)
    return lines


def _imports() -> list[tuple[str, str, str | None, bool, int]]:
    """(importer, imported module, imported name or None, type-checking only, line) for every ilcnc import."""
    out = []
    for name, p in MODULES.items():
        tree = ast.parse(p.read_text(encoding="utf-8"))
        tc = _type_checking_lines(tree)
        pkg = name if p.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if not (target == "ilcnc" or target.startswith("ilcnc.")):
                    continue
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    if sub in MODULES:
                        out.append((name, sub, None, node.lineno in tc, node.lineno))
                    else:
                        out.append((name, target, a.name, node.lineno in tc, node.lineno))
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("ilcnc"):
                        out.append((name, a.name, None, node.lineno in tc, node.lineno))
    return out


IMPORTS = _imports()


def test_every_import_points_down_the_layers() -> None:
    bad = []
    for src, dst, _n, _tc, line in IMPORTS:
        if dst == src or dst not in MODULES:
            continue
        (ls, ps), (ld, pd) = _layer(src), _layer(dst)
        if ld > ls or (ld == ls and ps != pd and LAYERS[ls][0] != "base" and LAYERS[ls][0] != "cli"):
            bad.append(f"{MODULES[src].relative_to(ROOT.parent)}:{line}: {src} ({LAYERS[ls][0]}) imports {dst}"
                       f" ({LAYERS[ld][0]})")
    assert not bad, "imports that point up (or across) the layers:\n" + "\n".join(bad)


def test_no_import_cycle() -> None:
    graph: dict[str, set[str]] = defaultdict(set)
    for src, dst, _n, tc, _line in IMPORTS:
        if not tc and dst in MODULES and dst != src and not (MODULES[dst].name == "__init__.py"
                                                              and src.startswith(dst + ".")):
            graph[src].add(dst)
    # Tarjan's strongly connected components
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in list(MODULES):
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_no_private_name_crosses_a_module() -> None:
    bad = [f"{src} imports {name} from {dst}" for src, dst, name, _tc, _line in IMPORTS
           if name and name.startswith("_") and not name.startswith("__") and dst != src]
    assert not bad, "private names imported across modules (make them public where shared):\n" + "\n".join(bad)


def test_modules_stay_one_concept_in_size() -> None:
    sizes = {m: len(p.read_text(encoding="utf-8").splitlines()) for m, p in MODULES.items()}
    over = {m: n for m, n in sizes.items() if n > MAX_LINES and m not in LARGE_MODULES}
    assert not over, f"modules above {MAX_LINES} lines (split them, or say in LARGE_MODULES why not): {over}"
    assert all(sizes.get(m, 0) > MAX_LINES for m in LARGE_MODULES), "LARGE_MODULES lists a module that is small now"


@pytest.mark.parametrize("package", ["ilcnc.axislog", "ilcnc.contour", "ilcnc.vcnc", "ilcnc.learning",
                                     "ilcnc.shop", "ilcnc.profile"])
def test_a_package_exports_exactly_its_modules_public_names(package: str) -> None:
    pkg = importlib.import_module(package)
    want = {}
    for mod in MODULES:
        if mod.startswith(package + ".") and not mod.endswith("__main__"):
            m = importlib.import_module(mod)
            for n in getattr(m, "__all__", ()):
                want[n] = mod
                assert getattr(m, n) is not None
    assert sorted(want) == pkg.__all__
    for n, mod in want.items():
        assert getattr(pkg, n) is getattr(importlib.import_module(mod), n), n
    with pytest.raises(AttributeError):
        pkg.no_such_name  # noqa: B018


def test_moved_modules_answer_on_their_old_paths_with_a_warning() -> None:
    from ilcnc._moved import MOVED

    for old, new in MOVED.items():
        assert f"ilcnc.{new}" in MODULES, new
        assert f"ilcnc.{old}" not in MODULES, f"ilcnc/{old}.py is back: drop it from MOVED"
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        old = importlib.import_module("ilcnc.simulate")
        from ilcnc.stream import simulate_streamed  # noqa: F401  (the 'from' form works too)
    assert old is importlib.import_module("ilcnc.vcnc.simulate")
    assert any(issubclass(w.category, DeprecationWarning) and "ilcnc.vcnc.simulate" in str(w.message) for w in got)


def test_own_code_and_tests_use_the_new_paths() -> None:
    from ilcnc._moved import MOVED

    here = Path(__file__).resolve()
    bad = []
    for p in list(ROOT.rglob("*.py")) + list(here.parent.rglob("*.py")) + list((ROOT.parent / "bench").glob("*.py")):
        if p == here or p.name == "_moved.py":
            continue
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            mods = []
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                mods = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            bad += [f"{p.name}:{node.lineno}: {m}" for m in mods
                    if m.startswith("ilcnc.") and m.split(".")[1] in MOVED and m.count(".") == 1]
    assert not bad, "old import paths:\n" + "\n".join(bad)
