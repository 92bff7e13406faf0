"""Checkpoints: round trip, manifest validation of damaged checkpoints, temp-folder cleanup, keep-last-K, best."""

from __future__ import annotations

import json
import random

import numpy as np
import pytest
import torch

from cosemdepth.errors import CheckpointError
from cosemdepth.models import build_model
from cosemdepth.models.config import ModelConfig
from cosemdepth.training.checkpoint import (
    REQUIRED_FILES,
    CheckpointManager,
    get_rng_state,
    load_checkpoint,
    read_model_state,
    set_rng_state,
    validate_checkpoint,
)
from cosemdepth.training.rundir import recover_best, save_best

CFG = ModelConfig(arch="m4semantic", levels=2, num_classes=3)


def _model_and_optimizer():
    model = build_model(CFG)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    x = torch.rand(1, 2, 3, 16, 16)
    out = model.forward_sequence(
        x, torch.tensor([[[1.0, 0, 0, 0]] * 2]), torch.zeros(1, 2, 3), torch.tensor([[8.0, 8, 8, 8]])
    )
    out.semantic[0].sum().backward()
    opt.step()
    return model, opt


def _save(mgr, model, opt, step, **state):
    return mgr.save(
        model_state=model.state_dict(),
        model_config=CFG,
        optimizer_state=opt.state_dict(),
        trainer_state={"step": step, "epoch": 0, **state},
        rng_state=get_rng_state(),
    )


def test_round_trip(tmp_path):
    model, opt = _model_and_optimizer()
    mgr = CheckpointManager(tmp_path / "ck", keep_last=3)
    path = _save(mgr, model, opt, 7, best={"miou": 0.5}, nan=float("nan"))
    assert path.name == "ckpt-00000007"
    manifest = validate_checkpoint(path)
    assert set(REQUIRED_FILES) <= set(manifest["files"]) and manifest["step"] == 7
    for name, info in manifest["files"].items():
        assert (path / name).stat().st_size == info["size"]
    ck = load_checkpoint(path)
    for k, v in model.state_dict().items():
        assert torch.equal(ck.model[k], v)
    fresh = torch.optim.Adam(build_model(CFG).parameters(), lr=1e-3)
    fresh.load_state_dict(ck.optimizer)
    for a, b in zip(fresh.state_dict()["state"].values(), opt.state_dict()["state"].values()):
        assert torch.equal(a["exp_avg"], b["exp_avg"]) and torch.equal(a["exp_avg_sq"], b["exp_avg_sq"])
    assert ck.step == 7 and ck.state["best"] == {"miou": 0.5} and ck.state["nan"] is None  # strict JSON
    # the checkpoint folder is also a model folder in our format
    meta = json.loads((path / "config.json").read_text())
    assert meta["format"] == "cosemdepth" and meta["model"] == CFG.to_dict() and meta["source"]["step"] == 7
    assert set(read_model_state(path)) == set(model.state_dict())


def test_rng_state_round_trip():
    state = get_rng_state()
    a = (random.random(), np.random.rand(), torch.rand(3))
    set_rng_state(state)
    b = (random.random(), np.random.rand(), torch.rand(3))
    assert a[0] == b[0] and a[1] == b[1] and torch.equal(a[2], b[2])


@pytest.mark.parametrize("damage", ["truncate", "flip", "delete", "no_manifest", "bad_manifest"])
def test_damaged_checkpoints_are_detected_and_skipped(tmp_path, damage):
    model, opt = _model_and_optimizer()
    mgr = CheckpointManager(tmp_path / "ck", keep_last=5)
    good = _save(mgr, model, opt, 2)
    newest = _save(mgr, model, opt, 4)
    target = newest / "optimizer.pt"
    if damage == "truncate":
        data = target.read_bytes()
        target.write_bytes(data[: len(data) // 2])
    elif damage == "flip":
        data = bytearray(target.read_bytes())
        data[len(data) // 2] ^= 0xFF
        target.write_bytes(bytes(data))
    elif damage == "delete":
        target.unlink()
    elif damage == "no_manifest":
        (newest / "manifest.json").unlink()
    else:
        (newest / "manifest.json").write_text("{not json")
    with pytest.raises(CheckpointError):
        validate_checkpoint(newest)
    with pytest.raises(CheckpointError):
        load_checkpoint(newest)
    before = {p.name: p.read_bytes() for p in newest.iterdir()}
    events = []
    mgr.log = lambda kind, **f: events.append((kind, f))
    assert mgr.latest_valid() == good
    assert not newest.exists()
    # moved aside, never deleted: the damaged files as they were, out of the checkpoints' namespace
    aside = newest.with_name("ckpt-00000004.corrupt-1")
    assert {p.name: p.read_bytes() for p in aside.iterdir()} == before
    assert mgr.moved_aside == mgr.set_aside() == [aside] and [s for s, _ in mgr.list()] == [2]
    assert events and events[0][0] == "checkpoint_invalid" and events[0][1]["step"] == 4
    assert events[0][1]["moved_to"] == str(aside)


def test_a_second_invalid_checkpoint_of_the_same_step_is_moved_aside_beside_the_first(tmp_path):
    model, opt = _model_and_optimizer()
    mgr = CheckpointManager(tmp_path / "ck", keep_last=5)
    for n in (1, 2):
        (_save(mgr, model, opt, 3) / "manifest.json").write_text("{not json")
        assert mgr.latest_valid() is None
    assert [p.name for p in mgr.set_aside()] == ["ckpt-00000003.corrupt-1", "ckpt-00000003.corrupt-2"]
    _save(mgr, model, opt, 4)
    mgr.keep_last = 1
    mgr.prune()  # pruning keeps the newest checkpoints and never touches those moved aside
    assert [s for s, _ in mgr.list()] == [4] and len(mgr.set_aside()) == 2


def test_keep_last_and_temp_cleanup(tmp_path):
    model, opt = _model_and_optimizer()
    mgr = CheckpointManager(tmp_path / "ck", keep_last=2)
    for s in (1, 2, 3, 4):
        _save(mgr, model, opt, s)
    assert [s for s, _ in mgr.list()] == [3, 4]
    stale = tmp_path / "ck" / ".tmp-ckpt-00000005-123"
    stale.mkdir()
    (stale / "model.safetensors").write_bytes(b"partial")
    mgr.cleanup()
    assert not stale.exists() and [s for s, _ in mgr.list()] == [3, 4]


def test_saving_the_same_step_again_replaces_it(tmp_path):
    model, opt = _model_and_optimizer()
    mgr = CheckpointManager(tmp_path / "ck", keep_last=2)
    _save(mgr, model, opt, 3, tag="first")
    p = _save(mgr, model, opt, 3, tag="second")
    assert load_checkpoint(p).state["tag"] == "second"
    assert sorted(x.name for x in (tmp_path / "ck").iterdir()) == ["ckpt-00000003"]


def test_a_failed_write_leaves_no_temporary_folder(tmp_path, monkeypatch):
    model, opt = _model_and_optimizer()
    mgr = CheckpointManager(tmp_path / "ck", keep_last=2)

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", boom)
    with pytest.raises(OSError, match="disk full"):
        _save(mgr, model, opt, 1)
    assert list((tmp_path / "ck").iterdir()) == []


def test_best_swap_and_recovery(tmp_path):
    model, _ = _model_and_optimizer()
    best = save_best(tmp_path, model.state_dict(), CFG, {"miou": 0.25}, {"step": 3})
    assert json.loads((best / "metrics.json").read_text())["miou"] == 0.25
    save_best(tmp_path, model.state_dict(), CFG, {"miou": 0.5}, {"step": 6})
    assert json.loads((best / "metrics.json").read_text())["step"] == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best"]
    # a crash between the two renames of the swap: the old best is put back
    best.rename(tmp_path / ".old-best-99")
    (tmp_path / ".tmp-best-99").mkdir()
    recover_best(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best"]
    assert json.loads((best / "metrics.json").read_text())["step"] == 6
