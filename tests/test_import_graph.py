"""The package's module graph: every import of every module under src/cosemdepth, read statically (module level and
function-local, absolute and relative), is an edge. The graph must be acyclic, and no module may import a module of a
higher layer (docs/architecture.md), at module level or inside a function: a function-local import is how an upward
dependency hides from a cycle check until the day the lower module is imported first."""

import ast
import textwrap
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "cosemdepth"

#: The layers of src/cosemdepth, lowest first (docs/architecture.md). A module may import its own layer and the
#: ones below. A module belongs to the entry that names it or its longest enclosing package (the root package
#: ``cosemdepth`` itself, its version and lazy attribute table, only by name).
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "base",
        (
            "cosemdepth",
            "cosemdepth._lazy",
            "cosemdepth.errors",
            "cosemdepth.defaults",
            "cosemdepth.coerce",
            "cosemdepth.plugins",
            "cosemdepth.models.config",
            "cosemdepth.models.registry",
            "cosemdepth.workers",
            "cosemdepth.devices",
            "cosemdepth.optional",
            "cosemdepth.operating_point",
            "cosemdepth.output_safety",
        ),
    ),
    ("maths", ("cosemdepth.geometry", "cosemdepth.ops")),
    ("models", ("cosemdepth.models",)),
    (
        "engines, model folders, readers",
        (
            "cosemdepth.inference",
            "cosemdepth.checkpoints",
            "cosemdepth.camera",
            "cosemdepth.data",
            "cosemdepth.flightlogs",
            "cosemdepth.synthair",
            "cosemdepth.robotics",
        ),
    ),
    (
        "measures and render",
        (
            "cosemdepth.measures",
            "cosemdepth.render",
        ),
    ),
    ("tasks and decoders", ("cosemdepth.tasks", "cosemdepth.decoders")),
    ("streaming", ("cosemdepth.streaming",)),
    (
        "jobs",
        (
            "cosemdepth.evaluation",
            "cosemdepth.training",
            "cosemdepth.export",
            "cosemdepth.bench",
            "cosemdepth.jobs",
            "cosemdepth.ros2",
        ),
    ),
    ("front ends", ("cosemdepth.cli", "cosemdepth.demo", "cosemdepth.__main__")),
)


def module_names(src: Path = SRC, package: str = PACKAGE) -> dict[str, Path]:
    out = {}
    for path in sorted((src / package).rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
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


def _imports(tree: ast.AST):
    """``(node, in_function)`` for every import statement of ``tree``; class bodies run at import, so only a
    function (or lambda) body makes an import function-local."""
    stack = [(tree, False)]
    while stack:
        node, local = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, local
        inner = local or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        stack.extend((child, inner) for child in ast.iter_child_nodes(node))


def imports_of(module: str, path: Path, known: set[str], package: str = PACKAGE) -> dict[str, bool]:
    """The package modules ``module`` imports anywhere in its body, each with whether every import of it is inside a
    function: ``from X import name`` is an edge to ``X.name`` when that is a module, else to ``X``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    is_package = path.name == "__init__.py"
    edges: dict[str, bool] = {}
    for node, local in _imports(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            base = resolve(module, is_package, node)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        for t in targets:
            while t and t not in known:  # "import cosemdepth.x.y as z" of a name inside a module: the module
                t = t.rpartition(".")[0]
            if (t == package or t.startswith(package + ".")) and t != module:
                edges[t] = edges.get(t, True) and local
    return edges


def graph(src: Path = SRC, package: str = PACKAGE) -> dict[str, dict[str, bool]]:
    """Module -> {imported module: only function-local}."""
    mods = module_names(src, package)
    return {m: imports_of(m, p, set(mods), package) for m, p in mods.items()}


def layer_of(module: str, layers=LAYERS, root: str = PACKAGE) -> int | None:
    """The index in ``layers`` of ``module``'s layer (None: in no layer)."""
    best, best_len = None, -1
    for i, (_, names) in enumerate(layers):
        for name in names:
            inside = module == name or (name != root and module.startswith(name + "."))
            if inside and len(name) > best_len:
                best, best_len = i, len(name)
    return best


def upward_imports(g: dict[str, dict[str, bool]], layers=LAYERS, root: str = PACKAGE) -> list[str]:
    """One line for each import of a module of a higher layer than the importer's."""
    out = []
    for module in sorted(g):
        low = layer_of(module, layers, root)
        for target, local in sorted(g[module].items()):
            high = layer_of(target, layers, root)
            if low is not None and high is not None and high > low:
                where = "inside a function (a function-local import)" if local else "at module level"
                out.append(f"{module} ({layers[low][0]}) imports {target} ({layers[high][0]}) {where}")
    return out


def find_cycle(g) -> list[str] | None:
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
                return path[path.index(nxt) :] + [nxt]
            elif colour.get(nxt) == 0:
                colour[nxt] = 1
                path.append(nxt)
                stack.append((nxt, iter(sorted(g[nxt]))))
    return None


def test_the_scanner_sees_relative_function_local_and_package_imports():
    g = graph()
    assert "cosemdepth.models.model" in g["cosemdepth.models"]  # from .model import ... in a package __init__
    assert "cosemdepth.models.config" in g["cosemdepth.models.model"]  # from .config import ...
    assert g["cosemdepth.models.config"] == {  # from ..x and from .x
        "cosemdepth.errors": False,
        "cosemdepth.coerce": False,
        "cosemdepth.models.registry": False,
    }
    assert g["cosemdepth.bench.accuracy"]["cosemdepth.export.runtime"] is True  # function-local
    assert g["cosemdepth.training.config"]["cosemdepth.data.registry"] is False  # module level
    assert "cosemdepth.models.model" in g["cosemdepth.inference.fast_model"]  # inference sits above models
    assert not any(
        m.startswith("cosemdepth.inference")
        for m in set().union(*(g[m] for m in g if m.startswith("cosemdepth.models")))
    )


@pytest.mark.parametrize(
    "edges, cycle",
    [
        ({"a": {"b"}, "b": {"c"}, "c": set()}, None),
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}}, ["a", "b", "c", "a"]),
        ({"a": {"b"}, "b": {"b2"}, "b2": {"b"}}, ["b", "b2", "b"]),
    ],
)
def test_cycle_finder_on_hand_made_graphs(edges, cycle):
    assert find_cycle(edges) == cycle


def test_no_import_cycle_in_the_package():
    cycle = find_cycle(graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_every_module_is_in_a_layer():
    assert [m for m in module_names() if layer_of(m) is None] == []
    assert layer_of("cosemdepth.models.config") == 0 and layer_of("cosemdepth.models.model") == 2
    assert layer_of("cosemdepth") == 0 and layer_of("cosemdepth.cli.train") == len(LAYERS) - 1
    assert layer_of("cosemdepth.models.registry") == 0  # the tables, read by the layers above it
    assert layer_of("cosemdepth.decoders.depth.task") == layer_of("cosemdepth.tasks.base")
    assert (
        layer_of("cosemdepth.measures.metrics") < layer_of("cosemdepth.tasks.base") < layer_of("cosemdepth.evaluation")
    )


def test_no_module_imports_a_higher_layer():
    up = upward_imports(graph())
    assert up == [], "imports of a higher layer:\n" + "\n".join(up)


def test_the_layer_check_catches_an_upward_function_local_import(tmp_path):
    """A synthetic package: ``low`` imports ``high`` inside a function (the import a cycle check misses until
    ``high`` imports ``low``), ``mid`` imports ``high`` at module level; ``high`` imports ``low`` (downward) both
    ways. Only the two upward imports are reported, each with where it is."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    files = {
        "__init__.py": "",
        "low.py": """
            import os

            class Reader:
                def names(self):
                    from .high import TABLE  # upward, hidden in a method
                    return TABLE
            """,
        "mid.py": "from pkg.high import TABLE\n",
        "high.py": """
            from . import low

            TABLE = {}

            def f():
                from .low import Reader
                return Reader, low
            """,
    }
    for name, text in files.items():
        (pkg / name).write_text(textwrap.dedent(text))
    layers = (("low", ("pkg", "pkg.low")), ("mid", ("pkg.mid",)), ("high", ("pkg.high",)))
    g = graph(tmp_path, "pkg")
    assert g["pkg.low"] == {"pkg.high": True} and g["pkg.high"] == {"pkg.low": False}
    assert find_cycle(g) == ["pkg.high", "pkg.low", "pkg.high"]  # (the cycle check sees it too, as a cycle)
    assert upward_imports(g, layers, "pkg") == [
        "pkg.low (low) imports pkg.high (high) inside a function (a function-local import)",
        "pkg.mid (mid) imports pkg.high (high) at module level",
    ]
    # without the downward import there is no cycle, and the layer check alone still catches the upward one
    (pkg / "high.py").write_text("TABLE = {}\n")
    g = graph(tmp_path, "pkg")
    assert find_cycle(g) is None
    assert upward_imports(g, layers, "pkg")[0] == (
        "pkg.low (low) imports pkg.high (high) inside a function (a function-local import)"
    )


def argparse_users(src: Path = SRC, package: str = PACKAGE) -> list[str]:
    """The modules of ``package`` that import :mod:`argparse` anywhere in their body."""
    out = []
    for module, path in module_names(src, package).items():
        for node, _ in _imports(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            if any(n == "argparse" or n.startswith("argparse.") for n in names):
                out.append(module)
                break
    return sorted(out)


def test_only_the_command_line_parses_arguments():
    """argparse lives in ``cli/``: below it, a command's options are frozen values built there, never a namespace."""
    users = argparse_users()
    assert "cosemdepth.cli.predict" in users  # the scanner sees it
    assert [m for m in users if not m.startswith("cosemdepth.cli.")] == []


def test_predict_reaches_the_model_without_the_command_line():
    """Below the argument parsing, predict (every source, flights included) never returns into ``cli/``: the modules
    its library run imports, transitively, hold no ``cosemdepth.cli`` module."""
    g = graph()
    seen, todo = set(), ["cosemdepth.jobs.predict"]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(g[m])
    assert {"cosemdepth.streaming.sources.flight", "cosemdepth.streaming.pipeline", "cosemdepth.models.model"} <= seen
    assert [m for m in seen if m == "cosemdepth.cli" or m.startswith("cosemdepth.cli.")] == []


@pytest.mark.parametrize(
    "importer, imported",
    [
        ("cosemdepth.tasks.base", "cosemdepth.training.losses"),  # a task reaching into the training job
        ("cosemdepth.tasks.base", "cosemdepth.evaluation.metrics"),
        ("cosemdepth.decoders.depth.task", "cosemdepth.evaluation.predict"),
        ("cosemdepth.decoders.semantic.task", "cosemdepth.streaming"),
        ("cosemdepth.models.model", "cosemdepth.decoders.depth.decoder"),  # the model naming a decoder
        ("cosemdepth.checkpoints.convert", "cosemdepth.decoders.semantic.tf_names"),
        ("cosemdepth.measures.losses", "cosemdepth.tasks.base"),
        ("cosemdepth.render.figures", "cosemdepth.decoders.depth"),
    ],
)
def test_the_package_layers_refuse_an_upward_import(importer, imported):
    """The package's own table on one-edge graphs: a task or decoder folder importing a job, the models or the
    conversion importing a decoder folder, a measure importing a task are each reported."""
    g = {importer: {imported: True}, imported: {}}
    low, high = LAYERS[layer_of(importer)][0], LAYERS[layer_of(imported)][0]
    assert upward_imports(g) == [
        f"{importer} ({low}) imports {imported} ({high}) inside a function (a function-local import)"
    ]
    assert upward_imports({imported: {importer: False}, importer: {}}) == []  # the other way is downward
