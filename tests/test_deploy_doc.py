"""docs/deploy.md: every function its inline code calls by a bare name is imported by one of its import lines (or
is a builtin), and every import line imports."""

import builtins
import importlib
import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "deploy.md"


def test_every_name_the_deploy_doc_calls_is_imported_by_the_doc():
    text = DOC.read_text(encoding="utf-8")
    imported = set()
    for module, names in re.findall(r"from (cosemdepth[\w.]*) import ([\w, ]+)", text):
        mod = importlib.import_module(module)
        for name in (n.strip() for n in names.split(",") if n.strip()):
            assert hasattr(mod, name), f"from {module} import {name}"
            imported.add(name)
    spans = re.findall(r"(?<!`)`([^`\n]+)`(?!`)", text)
    called = {m for s in spans for m in re.findall(r"(?<![\w.])([A-Za-z_]\w*)\(", s)}
    assert "export_onnx" in called
    unknown = sorted(n for n in called if n not in imported and not hasattr(builtins, n))
    assert unknown == [], f"called in docs/deploy.md without an import line: {unknown}"
