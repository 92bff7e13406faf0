"""The public API surface: every subpackage declares ``__all__``, every name in it resolves and is documented, and the
top-level API is pinned so that a name added or removed by accident fails here."""

import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import pytest

import cosemdepth

SRC = Path(cosemdepth.__file__).parent

#: The top-level names: the five-line API (load_model, its model's step and infer) and the names around it.
TOP_LEVEL = ["ModelConfig", "StreamPolicy", "Streamer", "__version__", "build_model", "load_model", "save_model"]


def public_packages() -> list[str]:
    names = ["cosemdepth"]
    for info in pkgutil.walk_packages([str(SRC)], "cosemdepth."):
        if info.ispkg and not any(part.startswith("_") for part in info.name.split(".")):
            names.append(info.name)
    return sorted(names)


PACKAGES = public_packages()


def package_folder(package: str) -> Path:
    return SRC.joinpath(*package.split(".")[1:])


def constant_doc_comment(folder: Path, name: str) -> str | None:
    """The ``#:`` comment above an assignment of ``name`` in the modules under ``folder`` (None: no such comment)."""
    assign = re.compile(rf"^(?:\w+\s*,\s*)*{re.escape(name)}(?:\s*,\s*\w+)*\s*(?::[^=]+)?=")
    for path in sorted(folder.rglob("*.py")):
        lines = path.read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            if assign.match(line):
                comment = []
                while i > 0 and lines[i - 1].startswith("#:"):
                    i -= 1
                    comment.insert(0, lines[i][2:].strip())
                if comment:
                    return " ".join(comment)
    return None


def test_the_package_list_is_what_the_source_tree_holds():
    assert {"cosemdepth.inference", "cosemdepth.models", "cosemdepth.data.midair", "cosemdepth.cli"} <= set(PACKAGES)
    assert not [p for p in PACKAGES if "._" in p]


@pytest.mark.parametrize("package", PACKAGES)
def test_every_name_in_all_resolves_and_is_documented(package):
    mod = importlib.import_module(package)
    assert (mod.__doc__ or "").strip(), f"{package} has no docstring"
    names = getattr(mod, "__all__", None)
    assert isinstance(names, (list, tuple)) and names, f"{package} declares no __all__"
    assert len(set(names)) == len(names), f"{package}.__all__ repeats a name"
    undocumented = []
    for name in names:
        assert not name.startswith("_") or (name.startswith("__") and name.endswith("__")), (package, name)
        obj = getattr(mod, name)  # raises AttributeError for a name that does not resolve
        if hasattr(mod, "__path__") and (Path(mod.__path__[0]) / f"{name}.py").exists():
            # importing a submodule of the same name (its first import) must not replace what the name gives
            importlib.import_module(f"{package}.{name}")
            assert getattr(mod, name) is obj, f"{package}.{name} is shadowed by its module"
        if name.startswith("__"):
            continue
        if inspect.ismodule(obj) or inspect.isclass(obj) or inspect.isroutine(obj):
            doc = obj.__doc__ or ""
            generated = inspect.isclass(obj) and doc.startswith(f"{obj.__name__}(")  # a dataclass's signature
            if not doc.strip() or generated:
                undocumented.append(name)
        elif constant_doc_comment(package_folder(package), name) is None:
            undocumented.append(name)
    assert not undocumented, f"{package}: undocumented public names {undocumented}"


def test_the_doc_comment_finder_reads_tuple_and_annotated_assignments_and_misses_plain_ones(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "m.py").write_text(
        "#: two lines\n#: of comment\nA, B = 1, 2\n"
        "#: typed\nTABLE: dict[str, int] = {}\n"
        "PLAIN = 3\n"
        "# not a doc comment\nHASHED = 4\n"
        "#: the name as a prefix of another\nPLAINER = 5\n"
    )
    assert constant_doc_comment(tmp_path, "A") == constant_doc_comment(tmp_path, "B") == "two lines of comment"
    assert constant_doc_comment(tmp_path, "TABLE") == "typed"
    assert constant_doc_comment(tmp_path, "PLAIN") is None
    assert constant_doc_comment(tmp_path, "HASHED") is None
    assert constant_doc_comment(tmp_path, "MISSING") is None


def test_the_top_level_api_is_pinned():
    assert sorted(cosemdepth.__all__) == TOP_LEVEL
    for name in TOP_LEVEL:
        getattr(cosemdepth, name)
    with pytest.raises(AttributeError, match="no attribute 'FastModel'"):
        cosemdepth.FastModel  # noqa: B018  (reached through cosemdepth.inference, not the top level)


def test_the_model_of_load_model_has_the_reference_model_s_step_and_infer():
    from cosemdepth.inference import FastModel
    from cosemdepth.models import SceneModel

    for method in ("step", "infer"):
        fast, ref = inspect.signature(getattr(FastModel, method)), inspect.signature(getattr(SceneModel, method))
        assert list(fast.parameters) == list(ref.parameters), method
        assert [p.default for p in fast.parameters.values()] == [p.default for p in ref.parameters.values()], method
    assert inspect.signature(cosemdepth.load_model).parameters["mode"].default == "fast"
