"""The streaming contract is declared once (``models/protocol.py``): every streaming path implements it with the same
step signature, describes itself with the attributes it names (no attribute forwarding), and every ``model``
parameter of the package is typed."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest
import torch

from cosemdepth import Streamer, build_model
from cosemdepth.export.runtime import OnnxModel
from cosemdepth.inference import FastModel
from cosemdepth.inference.engine import FastEngine
from cosemdepth.models import SceneModel, StreamingModel
from cosemdepth.operating_point import OperatingPoint

SRC = Path(__file__).resolve().parents[2] / "src" / "cosemdepth"
STEP = list(inspect.signature(StreamingModel.step).parameters)
INFER = list(inspect.signature(StreamingModel.infer).parameters)


@pytest.mark.parametrize("cls", [SceneModel, FastModel, FastEngine, OnnxModel])
def test_every_path_has_the_protocol_s_step(cls):
    assert list(inspect.signature(cls.step).parameters) == STEP
    assert ":class:`~cosemdepth.models.protocol.StreamingModel`" in " ".join(cls.step.__doc__.split())


def test_the_policy_s_step_is_the_protocol_s_without_decoders():
    """The Streamer chooses the decoders of each frame itself; everything else, the ground-truth guide included, is
    the protocol's; its own input, the pixels an undistorted image has, is keyword-only after them."""
    params = inspect.signature(Streamer.step).parameters
    assert list(params) == [*(p for p in STEP if p != "decoders"), "source_valid"]
    assert params["source_valid"].kind is inspect.Parameter.KEYWORD_ONLY
    for cls in (SceneModel, FastModel, OnnxModel, Streamer):
        assert list(inspect.signature(cls.infer).parameters) == INFER, cls


def test_wrappers_describe_themselves_without_forwarding():
    torch.manual_seed(0)
    model = build_model(arch="cosemdepth", levels=2)
    model.operating_point = OperatingPoint((32, 32), (16.0, 16.0))
    fast = FastModel(model)
    streamer = Streamer(fast, "every-frame")
    for wrapper in (fast, streamer, OnnxModel.__new__(OnnxModel)):
        assert not hasattr(type(wrapper), "__getattr__"), type(wrapper)
    for m in (model, fast, streamer):
        assert isinstance(m, StreamingModel)
        assert m.config is model.config and m.operating_point is model.operating_point
        assert list(m.decoders) == ["depth", "semantic"]
        assert next(iter(m.parameters())) is next(iter(model.parameters()))
    assert not hasattr(streamer, "encoder")  # what the protocol does not name is not there


def test_the_policy_hands_the_ground_truth_depth_to_the_model():
    """A model whose semantic decoder warps with the ground-truth depth streams through the Streamer with
    ``guide_depth``: the same outputs as the model's own infer with it."""
    torch.manual_seed(0)
    model = build_model(arch="cosemdepth", levels=2, semantic_time="gt").eval()
    g = torch.Generator().manual_seed(1)
    frames = torch.rand(3, 3, 16, 16, generator=g)
    gt = 5 + 20 * torch.rand(3, 1, 16, 16, generator=g)
    rot = torch.tensor([[1.0, 0, 0, 0]]).repeat(3, 1)
    trans = torch.tensor([[0.0, 0, 0], [0, 0, 1], [0, 0, 1]])
    k = torch.tensor([8.0, 8.0, 8.0, 8.0])
    ref = model.infer(frames, (rot, trans), k, guide_depth=gt)
    got = Streamer(model, "every-frame").infer(frames, (rot, trans), k, guide_depth=gt)
    torch.testing.assert_close(got.semantic, ref.semantic)
    with pytest.raises(ValueError, match="guide_depth"):  # and the model asks for it
        Streamer(model, "every-frame").infer(frames, (rot, trans), k)


def untyped_model_parameters(root: Path = SRC) -> list[str]:
    """``file:line function`` of every parameter named ``model`` without a type annotation."""
    out = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                a = node.args
                for arg in (*a.posonlyargs, *a.args, *a.kwonlyargs):
                    if arg.arg == "model" and arg.annotation is None:
                        out.append(f"{path.relative_to(root)}:{arg.lineno} {getattr(node, 'name', 'lambda')}")
    return out


def test_every_model_parameter_is_typed(tmp_path):
    (tmp_path / "m.py").write_text("def f(model, x: int):\n    return lambda model: model\n")
    assert untyped_model_parameters(tmp_path) == ["m.py:1 f", "m.py:2 lambda"]  # the scanner sees them
    assert untyped_model_parameters() == []
