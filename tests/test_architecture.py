"""The layers hold: the tree is the architecture (a package per layer, at most 16 entries at the
top of ``python/profrobot``, each one drawn in docs/architecture.md's tree), no import cycle anywhere in profrobot's import graph nor among the
bench scripts (module-level and ``if TYPE_CHECKING:`` imports count: a type is a dependency; a
lazy import inside a function does not), no module reaching into another package's private
names. (Every public name is documented: tests/test_docs.py.)

import-linter (``lint-imports`` in ``.ci/run``, contracts in ``pyproject.toml``) checks the layers
and private *modules*; these tests check what it cannot see: cycles through package
``__init__``s and private *names* (``from .dataset import _round``, ``model._render(...)``).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path



ROOT = Path(__file__).resolve().parents[1]      # the checkout (the package may be installed elsewhere)
PKG = ROOT / "python" / "profrobot"


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    out["profrobot._core"] = PKG / "_core.pyi"   # the native module, described by its stub
    return out


def _package_of(module: str, path: Path) -> str:
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _resolve(module: str, path: Path, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = _package_of(module, path).split(".")
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _module_level_nodes(tree: ast.AST):
    """Every node executed when the module is imported, ``if TYPE_CHECKING:`` blocks included
    (annotations are dependencies too), function bodies excluded (a lazy import runs later)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            stack.append(child)


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the profrobot modules it imports at module level (``if TYPE_CHECKING:`` blocks
    included, function bodies not)."""
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for m, p in modules.items():
        for node in _module_level_nodes(ast.parse(p.read_text(), str(p))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                src = _resolve(m, p, node)
                # `from pkg import sub` imports the submodule when there is one, else a name of pkg
                targets = [f"{src}.{a.name}" if f"{src}.{a.name}" in modules else src for a in node.names]
            for t in targets:
                while t and t not in modules:   # a name inside a module: the module
                    t = t.rpartition(".")[0]
                if t and t != m:
                    graph[m].add(t)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_no_import_cycle_anywhere():
    graph = _imports(_modules())
    # the facade imports its parts eagerly; a part importing the facade back is a cycle
    assert _cycles(graph) == []


def test_the_tree_is_the_architecture():
    """At most 16 ``.py`` files and folders at the top of the package: the layers, not their
    modules; and they are the tree docs/architecture.md draws, no more, no fewer."""
    top = sorted(p.name for p in PKG.iterdir()
                 if (p.is_dir() and p.name != "__pycache__") or p.suffix == ".py")
    assert len(top) <= 16, f"{len(top)} entries at the top of python/profrobot: {top}"
    page = (ROOT / "docs" / "architecture.md").read_text()
    tree = page.split("python/profrobot/", 1)[1].split("```", 1)[0]
    drawn = set(re.findall(r"[├└]── ([\w.]+(?:, [\w.]+)*)", tree))
    drawn = {n.rstrip("/") for entry in drawn for n in entry.split(", ")} | {"__init__.py"}
    assert drawn == {n for n in top}, f"drawn {sorted(drawn)}, found {top}"
    # every folder is a package (a layer), none is a bare directory
    assert all((PKG / n / "__init__.py").is_file() for n in top if (PKG / n).is_dir()), top


def test_a_type_checking_import_back_is_a_cycle():
    """The cycle test reads ``if TYPE_CHECKING:`` imports (a mixin importing its class back for
    its annotations is the circle it must catch) and skips imports inside functions."""
    src = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import B\ndef f():\n    from .c import C\n"
    tree = ast.parse(src)
    found = {n.module for n in _module_level_nodes(tree) if isinstance(n, ast.ImportFrom)}
    assert found == {"typing", "b"}


def test_no_import_cycle_among_the_benches():
    """The bench scripts import shared helpers from ``benches/common.py``, never each other in a circle."""
    benches = {p.stem: p for p in (ROOT / "benches").glob("*.py")}
    graph: dict[str, set[str]] = {b: set() for b in benches}
    for b, p in benches.items():
        for node in _module_level_nodes(ast.parse(p.read_text(), str(p))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            graph[b] |= {n.split(".")[0] for n in names if n.split(".")[0] in benches and n.split(".")[0] != b}
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_cycles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


_PRIVATE = re.compile(r"^_[A-Za-z0-9]\w*$")   # _name, not __dunder__


def _private_definitions(modules: dict[str, Path]) -> dict[str, set[str]]:
    """package -> the private names its modules define (functions, classes, attributes assigned
    on any object, module-level names)."""
    out: dict[str, set[str]] = {}
    for m, p in modules.items():
        names = out.setdefault(_package_of(m, p), set())
        for node in ast.walk(ast.parse(p.read_text(), str(p))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
    return out


def _private_name_uses(modules: dict[str, Path]) -> list[str]:
    """``from X import _name`` where X is in another package, and ``obj._name`` where no module
    of this package defines ``_name`` (so it belongs to another package's object)."""
    bad = []
    defined = _private_definitions(modules)
    # the native module's private names (``RobotModel._from_state``) belong to the whole package
    native = _private_definitions({"profrobot._core": modules["profrobot._core"]})["profrobot"]
    for m, p in modules.items():
        if p.suffix == ".pyi":
            continue
        tree = ast.parse(p.read_text(), str(p))
        pkg = _package_of(m, p)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                src = _resolve(m, p, node)
                if not src.startswith("profrobot"):
                    continue
                src_pkg = src if src in modules and modules[src].name == "__init__.py" else src.rpartition(".")[0]
                for a in node.names:
                    target = f"{src}.{a.name}"
                    target_pkg = src if target in modules else src_pkg
                    if _PRIVATE.match(a.name) and target_pkg != pkg and not (target == "profrobot._core"):
                        bad.append(f"{m}: from {src} import {a.name}")
            elif (isinstance(node, ast.Attribute) and _PRIVATE.match(node.attr) and node.attr not in defined[pkg]
                  and node.attr not in native
                  and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))):
                bad.append(f"{m}:{node.lineno}: {ast.unparse(node)}")
    return bad


def test_no_module_reaches_into_another_packages_private_names():
    assert _private_name_uses(_modules()) == []
