"""Transfer of weights into a model of another config (``train.init_from``, :mod:`cosemdepth.training.init`): the
rule on shapes, the values it writes, that a variant with new semantic inputs starts with exactly the source
model's outputs, and the trainer's use of it."""

import re

import pytest
import torch
import yaml

from cosemdepth.checkpoints.model_io import save_model
from cosemdepth.cli.main import main
from cosemdepth.errors import CheckpointError, ConfigError
from cosemdepth.export.check import synthetic_sequence
from cosemdepth.models import build_model
from cosemdepth.models.config import ModelConfig
from cosemdepth.training.checkpoint import read_model_state
from cosemdepth.training.events import read_events
from cosemdepth.training.init import check_transferable, plan_transfer, read_transfer_source, transfer_state_dict
from cosemdepth.training.trainer import Trainer


def test_the_plan_copies_equal_shapes_grows_input_channels_and_names_the_rest():
    source = {"a": (4, 3, 3, 3), "b": (4,), "grow": (8, 5, 3, 3), "old": (2, 2)}
    target = {"a": (4, 3, 3, 3), "b": (4,), "grow": (8, 9, 3, 3), "fresh": (6,)}
    plan = plan_transfer(source, target)
    assert plan.copied == ("a", "b") and plan.grown == (("grow", 5, 9),)
    assert plan.new == ("fresh",) and plan.dropped == ("old",)
    assert plan.summary("init_") == {
        "init_copied": 2,
        "init_grown": ["grow 5->9"],
        "init_new": ["fresh"],
        "init_dropped": ["old"],
    }


@pytest.mark.parametrize(
    "source, target",
    [
        ((8, 9, 3, 3), (8, 5, 3, 3)),  # fewer input channels
        ((8, 5, 3, 3), (6, 5, 3, 3)),  # other output channels
        ((8, 5, 3, 3), (8, 9, 1, 1)),  # other kernel
        ((4,), (6,)),  # a bias (no input channel dim)
        ((8, 5, 3, 3), (8, 5, 9)),  # other rank
    ],
)
def test_a_shape_change_that_is_not_more_input_channels_is_a_clear_error(source, target):
    with pytest.raises(CheckpointError) as e:
        plan_transfer({"w": source}, {"w": target}, origin="SRC")
    assert str(e.value) == (
        f"SRC: the weights do not transfer: w has shape {list(source)}, the target "
        f"{list(target)}; only a weight's input channels (dim 1) may grow"
    )


def test_the_transfer_copies_the_leading_channels_zeroes_the_new_ones_and_keeps_the_targets_own():
    src = {"w": torch.arange(2 * 3 * 1 * 1, dtype=torch.float64).view(2, 3, 1, 1), "b": torch.tensor([1.0, 2.0])}
    tgt = {"w": torch.full((2, 5, 1, 1), 7.0), "b": torch.zeros(2), "extra": torch.tensor([3.0])}
    out, plan = transfer_state_dict(src, tgt)
    assert list(out) == ["w", "b", "extra"] and out["w"].dtype == torch.float32
    assert out["w"][:, :, 0, 0].tolist() == [[0, 1, 2, 0, 0], [3, 4, 5, 0, 0]]
    assert out["b"].tolist() == [1.0, 2.0] and out["extra"].tolist() == [3.0]
    assert out["extra"] is not tgt["extra"] and plan.new == ("extra",)


def _stream(model, frames, guide=None):
    rgb, rot, trans, k = frames
    outs, state = [], None
    with torch.no_grad():
        for t in range(rgb.shape[1]):
            kw = {} if guide is None else {"guide_depth": guide[:, t]}
            out, state = model.step(
                rgb[:, t], rot[:, t], trans[:, t], k, torch.tensor([t == 0] * rgb.shape[0]), state, **kw
            )
            outs.append((out.depth, out.semantic))
    return outs


@pytest.mark.parametrize(
    "variant",
    [
        {"arch": "cosemdepth-t"},
        {"semantic_sncv": True},
        {"semantic_time": "gt"},
        {"arch": "cosemdepth-t", "semantic_sncv": True},
    ],
)
def test_a_variant_with_new_semantic_inputs_starts_with_the_source_models_outputs(variant):
    """Four streamed frames: depth and semantic probabilities of the transferred variant equal the source's (the
    same float operations on the old channels; the new ones multiply zero weights), while the variant's new inputs
    are not zero (frames 1-3 have a previous frame; the cost volume is never zero)."""
    torch.manual_seed(0)
    source = build_model(ModelConfig(levels=3)).eval()
    for p in source.parameters():  # trained weights are not the initialisation's: biases too
        p.data.add_(0.01 * torch.randn_like(p))
    target = build_model(ModelConfig(levels=3, **variant)).eval()
    state, plan = transfer_state_dict(source.state_dict(), target.state_dict())
    target.load_state_dict(state)
    grown = {k: (a, b) for k, a, b in plan.grown}
    n_new = 49 * target.config.semantic_sncv + 8 * (target.config.semantic_time != "off")
    assert sorted(grown) == [f"semantic_decoder.levels.{i}.refiner.convs.0.weight" for i in range(3)]
    assert all(b - a == n_new for a, b in grown.values()) and not plan.new and not plan.dropped
    frames = synthetic_sequence(2, 4, 32, 32, seed=3)
    guide = 5.0 + 20.0 * torch.rand(2, 4, 1, 32, 32) if variant.get("semantic_time") == "gt" else None
    want, got = _stream(source, frames), _stream(target, frames, guide)
    for t, ((d0, s0), (d1, s1)) in enumerate(zip(want, got)):
        assert torch.equal(d0, d1), f"depth of frame {t}"
        assert torch.equal(s0, s1), f"semantic of frame {t}"
    # the transfer is not trivially exact: a random init of the new channels changes the outputs
    for k in grown:
        target.state_dict()[k][:, grown[k][0] :].normal_(0, 0.05)
    assert not torch.allclose(_stream(target, frames, guide)[1][1], want[1][1], atol=1e-3)


def test_configs_that_would_move_channels_do_not_transfer():
    with pytest.raises(
        CheckpointError,
        match=re.escape("levels 3 (run: 4); only arch, semantic_sncv, semantic_time, pscv_dtype may differ"),
    ):
        check_transferable(ModelConfig(levels=3), ModelConfig(levels=4))
    with pytest.raises(CheckpointError, match=re.escape("sncv True (run: False)")):
        check_transferable(ModelConfig(sncv=True), ModelConfig(sncv=False))
    # the warped probabilities of a temporal source would land on the cost volume's channels of the target
    with pytest.raises(
        CheckpointError,
        match="inputs probs, other, features, previous_probs, previous_valid are not the leading inputs of the run's",
    ):
        check_transferable(ModelConfig(semantic_time="own"), ModelConfig(semantic_time="own", semantic_sncv=True))
    check_transferable(ModelConfig(semantic_sncv=True), ModelConfig(arch="cosemdepth-t", semantic_sncv=True))
    check_transferable(ModelConfig(arch="m4depth"), ModelConfig(arch="cosemdepth-t"))


def test_the_trainer_starts_from_the_transferred_weights_and_reports_the_grown_layers(tmp_path, tiny_config):
    torch.manual_seed(1)
    source = build_model(ModelConfig(levels=3))
    save_model(source, tmp_path / "src")
    Trainer(
        tiny_config(train__max_steps=1, model__arch="cosemdepth-t", train__init_from=str(tmp_path / "src")),
        tmp_path / "ft",
        console=False,
    ).fit()
    got = read_model_state(tmp_path / "ft" / "checkpoints" / "ckpt-00000000")
    want, _ = transfer_state_dict(
        source.state_dict(), build_model(ModelConfig(arch="cosemdepth-t", levels=3)).state_dict()
    )
    assert got.keys() == want.keys() and all(torch.equal(got[k], want[k]) for k in got)
    start = next(e for e in read_events(tmp_path / "ft" / "events.jsonl") if e["kind"] == "start")
    assert start["init_from"] == str(tmp_path / "src") and start["init_new"] == [] and start["init_copied"] > 0
    # N + 4 + C_l input channels (7 classes; 16, 32, 64 encoder channels), N + 1 more for S^{t-1} and its validity
    assert start["init_grown"] == [
        f"semantic_decoder.levels.{i}.refiner.convs.0.weight {c}->{c + 8}" for i, c in enumerate((27, 43, 75))
    ]


def test_weights_that_do_not_transfer_fail_before_anything_is_written(tmp_path, tiny_config):
    save_model(build_model(ModelConfig(arch="cosemdepth-t", levels=3)), tmp_path / "t")
    with pytest.raises(CheckpointError) as e:  # the temporal inputs cannot be dropped
        Trainer(tiny_config(train__init_from=str(tmp_path / "t")), tmp_path / "bad", console=False)
    assert str(e.value) == (
        f"train.init_from: {tmp_path / 't'}: the weights do not transfer: the semantic "
        "refiners' inputs probs, other, features, previous_probs, previous_valid are not the "
        "leading inputs of the run's (probs, other, features)"
    )
    with pytest.raises(CheckpointError, match="train.init_from: .*not found"):
        read_transfer_source(str(tmp_path / "missing"), ModelConfig(levels=3))
    with pytest.raises(ConfigError, match="train.init_weights and train.init_from: give one of them"):
        tiny_config(train__init_from="a", train__init_weights="b")
    assert not (tmp_path / "bad").exists()


def test_the_init_from_flag_sets_the_key(capsys, tmp_path):
    assert (
        main(["train", "--out", str(tmp_path / "x"), "--dataset", "toy", "--init-from", "weights/m", "--print-config"])
        == 0
    )
    assert yaml.safe_load(capsys.readouterr().out)["train"]["init_from"] == "weights/m"
