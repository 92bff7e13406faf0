"""The package's module graph has no cycle: every import of every module under src/cosemdepth, read statically
(module level and function-local, absolute and relative), is an edge; the graph must be acyclic."""

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "cosemdepth"


def module_names() -> dict[str, Path]:
    out = {}
    for path in sorted((SRC / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module an ``ImportFrom`` names (relative levels resolved against ``module``)."""
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(module: str, path: Path, known: set[str]) -> set[str]:
    """The package modules ``module`` imports anywhere in its body: ``from X import name`` is an edge to
    ``X.name`` when that is a module, else to ``X``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    is_package = path.name == "__init__.py"
    edges = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = resolve(module, is_package, node)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:  # "import cosemdepth.x.y as z" of a name inside a module: the module
                t = t.rpartition(".")[0]
            if t.startswith(PACKAGE) and t != module:
                edges.add(t)
    return edges


def graph() -> dict[str, set[str]]:
    mods = module_names()
    return {m: imports_of(m, p, set(mods)) for m, p in mods.items()}


def find_cycle(g: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``g`` as a path ``[a, b, ..., a]``, or None (iterative DFS, three colours)."""
    colour = {m: 0 for m in g}
    for root in g:
        if colour[root]:
            continue
        stack = [(root, iter(sorted(g[root])))]
        path = [root]
        colour[root] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                colour[node] = 2
                stack.pop()
                path.pop()
            elif colour.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            elif colour.get(nxt) == 0:
                colour[nxt] = 1
                path.append(nxt)
                stack.append((nxt, iter(sorted(g[nxt]))))
    return None


def test_the_scanner_sees_relative_function_local_and_package_imports():
    g = graph()
    assert "cosemdepth.models.model" in g["cosemdepth.models"]  # from .model import ... in a package __init__
    assert "cosemdepth.config" in g["cosemdepth.models.model"]  # from ..config import ...
    assert "cosemdepth.models" in g["cosemdepth.checkpoints.model_io"]  # a function-local import
    assert "cosemdepth.models.model" in g["cosemdepth.inference.fast_model"]  # inference sits above models
    assert not any(m.startswith("cosemdepth.inference") for m in set().union(*(g[m] for m in g if m.startswith("cosemdepth.models"))))


@pytest.mark.parametrize(
    "edges, cycle",
    [({"a": {"b"}, "b": {"c"}, "c": set()}, None), ({"a": {"b"}, "b": {"c"}, "c": {"a"}}, ["a", "b", "c", "a"]),
     ({"a": {"b"}, "b": {"b2"}, "b2": {"b"}}, ["b", "b2", "b"])],
)
def test_cycle_finder_on_hand_made_graphs(edges, cycle):
    assert find_cycle(edges) == cycle


def test_no_import_cycle_in_the_package():
    cycle = find_cycle(graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)
