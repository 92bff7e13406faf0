"""docs/api.md: every ``python`` code block runs, in order, in one namespace (the first block excepted: it names
the shipped weights, which are replaced by a stand-in model in the runnable blocks)."""

import re
from pathlib import Path

import torch

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_api_doc_examples_run(tmp_path, monkeypatch, capsys):
    blocks = python_blocks(DOC.read_text())
    assert len(blocks) >= 5
    head = blocks[0]
    # the five-line summary: the names it uses are the real API
    for name in ("load_model", "model.step", "model.infer", "out.depth", "out.labels"):
        assert name in head
    monkeypatch.chdir(tmp_path)
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        ns: dict = {}
        for block in blocks[1:]:
            exec(compile(block, str(DOC), "exec"), ns)
    finally:
        torch.set_num_threads(old)
    assert "torch.Size([1, 1, 64, 96])" in capsys.readouterr().out
    assert ns["seq"].depth.shape == (4, 1, 64, 96)
