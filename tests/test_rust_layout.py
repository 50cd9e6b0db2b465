"""The Rust core's layout (``rust/``): modules in folders by concern, the folders layered without a
cycle, and every module listed in ``rust/lib.rs``'s doc table.

Reads the sources only (standard library, no build). ``lib.rs``'s table has one row per module,
lowest layer first: the top-level modules (the crate-root leaves and the folders), each with the
top-level modules it ``uses`` and those only its unit tests also use, a folder's row followed by
its modules' (``folder::module``). The code is held to that table:

- ``rust/`` keeps at most ``MAX_TOP_FILES`` ``.rs`` files at its top (``lib.rs`` and crate-wide
  leaves); everything else is in a folder with a ``mod.rs``;
- the top-level modules a top-level module's code names (``crate::x``, ``crate::{x, ..}``, or a
  crate-root re-export such as ``crate::RobotModel``) are exactly its ``uses``, all in earlier
  rows, so there is no cycle; code under ``#[cfg(test)]`` may also name its ``tests also use``;
- every ``mod x;`` declared anywhere is a row of the table, and every row is a module.
"""

from __future__ import annotations

import re
from pathlib import Path

RUST = Path(__file__).resolve().parents[1] / "rust"
LIB = RUST / "lib.rs"
MAX_TOP_FILES = 8

_IDENT = r"[A-Za-z_][A-Za-z0-9_]*"


_RAW_STRING = re.compile(r'b?r(#*)"')
_CHAR = re.compile(r"'(?:\\u\{[0-9a-fA-F]+\}|\\.|[^\\'\n])'")
_SPECIAL = re.compile(r"//|/\*|\"|'|\bb?r#*\"")


def strip_comments_and_literals(src: str) -> str:
    """``src`` with comments, string and char literals blanked (newlines kept), so that neither a
    brace nor a path inside them counts."""
    out = []
    i, n = 0, len(src)

    def blank(text: str) -> str:
        return re.sub(r"[^\n]", " ", text)

    while (m := _SPECIAL.search(src, i)) is not None:
        out.append(src[i : m.start()])
        i, token = m.start(), m.group(0)
        if token == "//":
            j = src.find("\n", i)
            j = n if j < 0 else j
        elif token == "/*":
            depth, j = 1, i + 2
            while j < n and depth:
                if src.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif src.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
        elif token == '"':
            j = i + 1
            while j < n and src[j] != '"':
                j += 2 if src[j] == "\\" else 1
            j += 1
        elif token == "'":
            c = _CHAR.match(src, i)
            j = c.end() if c else i + 1  # a lifetime's quote: kept
            if not c:
                out.append("'")
                i = j
                continue
        else:  # a raw string
            r = _RAW_STRING.match(src, i)
            end = src.find('"' + r.group(1), r.end())
            j = n if end < 0 else end + 1 + len(r.group(1))
        out.append(blank(src[i:j]))
        i = j
    out.append(src[i:])
    return "".join(out)


_CFG_TEST = re.compile(r"#\s*\[\s*cfg\s*\(\s*test\s*\)\s*\]")


def split_test_code(code: str) -> tuple[str, str]:
    """(the code outside ``#[cfg(test)]`` items, the code of those items), from stripped code."""
    prod, test = list(code), []
    for m in _CFG_TEST.finditer(code):
        i, depth = m.end(), 0
        while i < len(code):
            c = code[i]
            if c in "([":
                depth += 1
            elif c in ")]":
                depth -= 1
            elif depth == 0 and c in ";,":
                i += 1
                break
            elif depth == 0 and c == "{":
                braces = 0
                while i < len(code):
                    braces += {"{": 1, "}": -1}.get(code[i], 0)
                    i += 1
                    if braces == 0:
                        break
                break
            i += 1
        test.append(code[m.start() : i])
        prod[m.start() : i] = [" "] * (i - m.start())
    return "".join(prod), "\n".join(test)


def root_reexports() -> dict[str, str]:
    """The crate-root ``pub use`` names, each mapped to the top-level module it comes from."""
    names = {}
    code = strip_comments_and_literals(LIB.read_text())
    for m in re.finditer(rf"pub\s+use\s+(?:crate::)?({_IDENT})::([^;]*);", code):
        tail = m.group(2)
        inner = tail[tail.index("{") + 1 : tail.rindex("}")] if "{" in tail else tail
        for part in inner.split(","):
            name = part.strip().split("::")[-1].split(" as ")[-1].strip()
            if name:
                names[name] = m.group(1)
    return names


def crate_references(code: str, tops: set[str], reexports: dict[str, str]) -> set[str]:
    """The top-level modules that stripped ``code`` names through ``crate::``."""
    found = set()
    for m in re.finditer(rf"\bcrate\s*::\s*(\{{|{_IDENT})", code):
        if m.group(1) == "{":
            depth, i, start, items = 1, m.end(), m.end(), []
            while i < len(code) and depth:
                if code[i] == "{":
                    depth += 1
                elif code[i] == "}":
                    depth -= 1
                elif code[i] == "," and depth == 1:
                    items.append(code[start:i])
                    start = i + 1
                i += 1
            items.append(code[start : i - 1])
            names = [re.match(rf"\s*({_IDENT})?", item).group(1) for item in items]
        else:
            names = [m.group(1)]
        for name in filter(None, names):
            if name in tops:
                found.add(name)
            elif name in reexports:
                found.add(reexports[name])
    return found


def top_level_of(path: Path) -> str | None:
    """The top-level module a source file belongs to (None: ``lib.rs``)."""
    rel = path.relative_to(RUST)
    if rel == Path("lib.rs"):
        return None
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def sources() -> list[Path]:
    return sorted(RUST.rglob("*.rs"))


def doc_table() -> list[list[str]]:
    """The rows of ``lib.rs``'s module table, cells stripped (header and rule left out)."""
    rows = []
    for line in LIB.read_text().splitlines():
        text = line.removeprefix("//!").strip()
        if not line.startswith("//!") or not text.startswith("|"):
            continue
        cells = [c.strip() for c in text.strip("|").split("|")]
        if cells[0] == "module" or set(cells[0]) <= set("-: "):
            continue
        rows.append(cells)
    return rows


def _names(cell: str) -> list[str]:
    return re.findall(r"`([A-Za-z_][A-Za-z0-9_:]*)`", cell)


def table() -> tuple[list[str], dict[str, set[str]], dict[str, set[str]], dict[str, str]]:
    """(top-level modules bottom to top, their uses, their tests' extra uses, concern of every module)."""
    order, uses, test_uses, concern = [], {}, {}, {}
    for cells in doc_table():
        assert len(cells) == 4, f"lib.rs's table: a row needs 4 cells (module, concern, uses, tests also use): {cells}"
        (name,) = _names(cells[0]) or [None]
        assert name, f"lib.rs's table: no `module` in {cells[0]!r}"
        concern[name] = cells[1]
        if "::" not in name:
            order.append(name)
            uses[name] = set(_names(cells[2]))
            test_uses[name] = set(_names(cells[3]))
        else:
            assert not cells[2] and not cells[3], f"lib.rs's table: only top-level rows say what they use ({name})"
    return order, uses, test_uses, concern


def graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(what each top-level module's code uses, what its ``#[cfg(test)]`` code uses)."""
    files = sources()
    tops = {t for t in map(top_level_of, files) if t}
    reexports = root_reexports()
    prod: dict[str, set[str]] = {t: set() for t in tops}
    test: dict[str, set[str]] = {t: set() for t in tops}
    for path in files:
        top = top_level_of(path)
        if top is None:
            continue
        code = strip_comments_and_literals(path.read_text())
        assert "super::super" not in code, f"{path}: reach other folders through `crate::`, not `super::super`"
        outside, inside = split_test_code(code)
        prod[top] |= crate_references(outside, tops, reexports) - {top}
        test[top] |= crate_references(inside, tops, reexports) - {top}
    return prod, test


def declared_modules() -> set[str]:
    """Every ``mod x;`` of the crate as its path from the root (``folder::x``)."""
    found = set()
    for path in sources():
        rel = path.relative_to(RUST)
        parent = list(rel.parts[:-1]) if rel.name in ("mod.rs", "lib.rs") else [*rel.parts[:-1], rel.stem]
        code = strip_comments_and_literals(path.read_text())
        for m in re.finditer(rf"(?m)^\s*(?:pub(?:\s*\([^)]*\))?\s+)?mod\s+({_IDENT})\s*;", code):
            found.add("::".join([*parent, m.group(1)]))
    return found


def find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(edges):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_rust_top_holds_lib_and_a_few_leaves_the_rest_in_folders():
    top_files = sorted(p.name for p in RUST.glob("*.rs"))
    assert "lib.rs" in top_files
    assert len(top_files) <= MAX_TOP_FILES, f"rust/ holds {len(top_files)} .rs files at its top: {top_files}"
    for folder in sorted(p for p in RUST.rglob("*") if p.is_dir()):
        assert (folder / "mod.rs").is_file(), f"{folder}: a folder module is folder/mod.rs"
        assert not folder.with_suffix(".rs").exists(), f"{folder}.rs beside {folder}/: use {folder}/mod.rs"
        assert list(folder.glob("*.rs")), f"{folder}: empty"
    order, _, _, _ = table()
    tops = {t for t in map(top_level_of, sources()) if t}
    assert set(order) == tops, f"lib.rs's table's top-level rows {sorted(order)} against rust/'s {sorted(tops)}"


def test_top_level_modules_use_only_those_below_them_no_cycle():
    order, uses, test_uses, _ = table()
    prod, test = graph()
    rank = {name: i for i, name in enumerate(order)}
    for name in order:
        assert prod[name] == uses[name], (
            f"{name}'s code uses {sorted(prod[name])}; lib.rs's table says {sorted(uses[name])}"
            f" (a use not in the table is a new dependency; a folder may use only folders below it)"
        )
        below = {u for u in uses[name] if rank.get(u, len(order)) < rank[name]}
        assert below == uses[name], f"{name} uses {sorted(uses[name] - below)}, not below it in lib.rs's table"
        extra = test[name] - uses[name]
        assert extra == test_uses[name], (
            f"{name}'s unit tests also use {sorted(extra)}; lib.rs's table says {sorted(test_uses[name])}"
        )
    assert find_cycle(prod) is None, f"module cycle between top-level modules: {' -> '.join(find_cycle(prod))}"


def test_every_module_is_in_lib_rs_table():
    _, _, _, concern = table()
    declared = declared_modules()
    missing = sorted(declared - set(concern))
    assert not missing, f"modules missing from lib.rs's doc table: {missing}"
    stale = sorted(set(concern) - declared)
    assert not stale, f"lib.rs's doc table lists modules that do not exist: {stale}"
    blank = sorted(name for name, text in concern.items() if not text)
    assert not blank, f"lib.rs's doc table gives no concern for {blank}"


# The checker itself, on made-up code: it must see what the layout rules are about.


def test_checker_sees_crate_paths_outside_comments_strings_and_tests():
    src = """
use crate::render::splat::Cutoff; // crate::ik in a comment
use crate::{model::RobotModel, joints};
/* crate::planning */ const S: &str = "crate::bindings {";
fn f() -> char { '{' }
fn g() { crate::RobotModel::new(); }
#[cfg(test)]
mod tests {
    use crate::planning::motion;
    fn h() { let s = "}"; }
}
fn after() { crate::geometry::hull::Hull::new(); }
"""
    tops = {"render", "model", "joints", "planning", "ik", "bindings", "geometry"}
    outside, inside = split_test_code(strip_comments_and_literals(src))
    assert crate_references(outside, tops, {"RobotModel": "model"}) == {"render", "model", "joints", "geometry"}
    assert crate_references(inside, tops, {}) == {"planning"}


def test_checker_finds_a_cycle():
    assert find_cycle({"collision": {"model"}, "model": {"geometry"}}) is None
    assert find_cycle({"collision": {"render"}, "render": {"splat"}, "splat": {"collision"}})
