"""README.md runs as written: every ``python`` block (the API in five lines with the shipped weights; the data
readers on the files they name, made here) and the ``cosemdepth splits midair`` command the second one needs."""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent / "data"))
from _writers import write_midair  # noqa: E402

from cosemdepth.cli.main import main  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def run_block(code: str) -> dict:
    ns: dict = {}
    exec(compile(code, str(README), "exec"), ns)
    return ns


def test_the_readme_has_the_blocks_run_here():
    api, data = blocks("python")  # exactly two: a new block needs its own run below
    assert "out, state = model.step(rgb, rot, trans, intrinsics, reset, None)" in api
    assert "seq = model.infer(frames, (rots, transes), intrinsics)" in api
    assert 'open_dataset("midair", "data/MidAir"' in data and 'open_dataset("flight"' in data


def test_the_python_api_lines_run_as_written(monkeypatch):
    monkeypatch.chdir(ROOT)  # the block names the shipped weights by their path in the repository
    ns = run_block(blocks("python")[0])
    out, seq = ns["out"], ns["seq"]
    assert ns["model"].config.levels == 5 and ns["model"].config.num_classes == 7
    assert out.depth.shape == (1, 1, 128, 128) and out.labels.shape == (1, 128, 128)
    assert out.semantic.shape == (1, 7, 128, 128)
    assert torch.allclose(out.semantic.sum(1), torch.ones(1, 128, 128), atol=1e-5)  # probabilities
    assert torch.equal(out.labels, out.semantic.argmax(1))
    assert seq.depth.shape == (1, 4, 1, 128, 128) and torch.isfinite(seq.depth).all()
    assert seq.labels.shape == (1, 4, 128, 128) and torch.equal(seq.labels, seq.semantic.argmax(2))  # classes
    assert isinstance(
        ns["state"], type(ns["model"].step(ns["rgb"], ns["rot"], ns["trans"], ns["intrinsics"], ns["reset"], None)[1])
    )


def test_what_the_readme_says_of_the_shared_tf_fixture_is_what_the_tests_do(tmp_path, monkeypatch):
    import importlib.util

    spec = importlib.util.spec_from_file_location("root_conftest", ROOT / "tests" / "conftest.py")
    conftest = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conftest)
    monkeypatch.setenv("COSEMDEPTH_FIXTURES", str(tmp_path))  # no shared fixture there
    monkeypatch.delenv("CI", raising=False)
    assert conftest.tfref_params() == ["tfref-64x96"]  # its tests are not collected: nothing is skipped
    monkeypatch.setenv("CI", "true")
    assert conftest.tfref_params() == ["tfref-64x96", "tfref-s128"]  # CI collects them: absent, they fail
    text = " ".join(README.read_text(encoding="utf-8").split())
    assert "is an extra check, run only where present (required when `CI=true`)" in text and "skipped" not in text


def test_the_data_lines_run_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    # the data the block names: a Mid-Air-format tree (trajectory 0 is a test trajectory by the paper's rule) and
    # the README's command for its split CSVs; a flight of three images named by their stamps with TUM poses
    write_midair(Path("data/MidAir"), {("Kite_training", "sunny"): [0, 1, 2]}, frames=12, size=32)
    (command,) = [
        line.split("#")[0]
        for block in blocks("bash")
        for line in block.splitlines()
        if line.startswith("cosemdepth splits midair")
    ]
    assert main(shlex.split(command)[1:]) == 0
    images = Path("my_flight/images")
    images.mkdir(parents=True)
    stamps = (1.0, 1.1, 1.2)
    for k, t in enumerate(stamps):
        Image.fromarray(np.full((24, 32, 3), 40 * k, np.uint8)).save(images / f"{t:.6f}.png")
    Path("my_flight/poses.txt").write_text("".join(f"{t:.6f} 0 0 {2 * k} 0 0 0 1\n" for k, t in enumerate(stamps)))
    ns = run_block(blocks("python")[1])
    item = ns["item"]
    assert item["rgb"].shape == (1, 3, 384, 384) and item["depth"].shape == (1, 1, 384, 384)
    assert item["semantic"].shape == (1, 384, 384) and item["intrinsics"].shape == (4,)
    assert bool(item["reset"][0])  # the first row of a trajectory
    frames = list(ns["flight"])
    assert len(frames) == 3
    np.testing.assert_allclose(frames[2]["trans"][0].numpy(), [0, 0, 2], atol=1e-6)  # 2 m forward per frame
