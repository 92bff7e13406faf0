"""The training loop in-process: determinism, exact resume, the non-finite guard (skip, deferred checkpoint,
rollback, giving up), validation and the best model."""

from __future__ import annotations

import json
import math
import re
import time

import pytest
import torch

from cosemdepth.checkpoints.convert import convert_checkpoint
from cosemdepth.data.toy import ToyDataset
from cosemdepth.errors import CheckpointError
from cosemdepth.training.checkpoint import load_checkpoint, read_model_state, validate_checkpoint
from cosemdepth.training.events import read_events
from cosemdepth.training.trainer import NonFiniteGuard, Trainer, TrainingDiverged, learning_rate


def _weights(trainer: Trainer) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in trainer.model.state_dict().items()}


def _equal(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_guard_counts_streaks():
    g = NonFiniteGuard(3)
    assert [g.record(f) for f in (False, True, False, False, False)] == ["skip", "ok", "skip", "skip", "rollback"]


def test_learning_rate_steps(tiny_config):
    cfg = tiny_config(train__lr=1e-3, train__lr_decay_epochs=[2, 4], train__lr_decay=0.5)
    assert [learning_rate(cfg, e) for e in range(6)] == [1e-3, 1e-3, 5e-4, 5e-4, 2.5e-4, 2.5e-4]


def test_same_seed_same_weights_and_exact_resume(tmp_path, tiny_config):
    """Two trainings of one config and seed give identical weights, even when the second one is stopped in the
    middle of an epoch and resumed from its checkpoint by a new Trainer."""
    cfg6 = tiny_config(train__max_steps=6, train__checkpoint_every=100)
    a = Trainer(cfg6, tmp_path / "a", console=False)
    a.fit()

    first = Trainer(tiny_config(train__max_steps=3, train__checkpoint_every=100), tmp_path / "c", console=False)
    first.fit()
    assert first.state.epoch == 0 and first.state.batch_in_epoch == 3  # stopped mid-epoch (4 steps per epoch)
    assert not _equal(_weights(first), _weights(a))
    resumed = Trainer(cfg6, tmp_path / "c", console=False)
    assert resumed.resuming
    resumed.fit()
    assert _equal(_weights(resumed), _weights(a))
    events = read_events(tmp_path / "c" / "events.jsonl")
    kinds = [e["kind"] for e in events]
    assert kinds.count("start") == 1 and kinds.count("resume") == 1 and "config_changed" in kinds
    assert next(e for e in events if e["kind"] == "resume")["step"] == 3


def test_a_rerun_whose_checkpoints_are_all_invalid_moves_them_aside_and_says_it_starts_over(
    tmp_path, tiny_config, capsys
):
    cfg = tiny_config(train__max_steps=2, train__checkpoint_every=100)
    Trainer(cfg, tmp_path / "run", console=False).fit()
    ckpts = sorted((tmp_path / "run" / "checkpoints").iterdir())
    assert [p.name for p in ckpts] == ["ckpt-00000000", "ckpt-00000002"]
    for p in ckpts:  # every checkpoint damaged
        (p / "optimizer.pt").write_bytes(b"damaged")
    rerun = Trainer(cfg, tmp_path / "run", console=True)
    rerun.fit()
    err = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    aside = [p.with_name(p.name + ".corrupt-1") for p in reversed(ckpts)]  # newest first, as they were checked
    assert err == [
        f"cosemdepth train: warning: {tmp_path / 'run'}: no valid checkpoint to resume from (its invalid checkpoints "
        f"were moved aside: {', '.join(str(p) for p in sorted(aside))}); starting again from step 0"
    ]
    assert all((p / "optimizer.pt").read_bytes() == b"damaged" for p in aside)  # kept as they were
    kinds = [e["kind"] for e in read_events(tmp_path / "run" / "events.jsonl")]
    assert kinds.count("start") == 2 and kinds.index("start_over") < len(kinds) - kinds[::-1].index("start") - 1
    assert rerun.state.step == 2 and validate_checkpoint(tmp_path / "run" / "checkpoints" / "ckpt-00000002")


def test_nonfinite_steps_are_skipped_then_rolled_back(tmp_path, tiny_config):
    """Injected NaN losses at steps 2, 4 (isolated: skipped) and 6, 7, 8 (three in a row: rollback)."""
    cfg = tiny_config(
        train__epochs=3,
        train__max_steps=10,
        train__checkpoint_every=4,
        train__nonfinite_patience=3,
        debug__inject_nonfinite_steps=[2, 4, 6, 7, 8],
    )
    checks = []
    trainer = None
    last_weights = {}

    def listen(event):
        kind = event["kind"]
        if kind == "train":  # a good step: remember the weights it produced
            last_weights["w"] = _weights(trainer)
            last_weights["step"] = event["step"]
        elif kind == "nonfinite_step":
            # no update: the weights are those of the last good step (or of the last checkpoint)
            checks.append(("skip", event["step"], _equal(_weights(trainer), last_weights["w"])))
        elif kind == "rollback":
            ck = load_checkpoint(event["checkpoint"])
            same = _equal(_weights(trainer), ck.model)
            adam_steps = {int(s["step"]) for s in trainer.optimizer.state_dict()["state"].values()}
            ck_steps = {int(s["step"]) for s in ck.optimizer["state"].values()}
            checks.append(("rollback", event["to_step"], same and adam_steps == ck_steps))
            last_weights["w"] = ck.model

    trainer = Trainer(cfg, tmp_path / "run", console=False, listeners=[listen])
    summary = trainer.fit()
    events = read_events(tmp_path / "run" / "events.jsonl")
    bad = [(e["step"], e["action"]) for e in events if e["kind"] == "nonfinite_step"]
    assert bad == [(2, "skip"), (4, "skip"), (6, "skip"), (7, "skip"), (8, "rollback")]
    # the checkpoint of step 4 (a bad step) was deferred to step 5, the last good one before the rollback
    assert any(e["kind"] == "checkpoint_deferred" and e["step"] == 4 for e in events)
    saved = [e["step"] for e in events if e["kind"] == "checkpoint"]
    assert 4 not in saved and 5 in saved
    rollbacks = [e for e in events if e["kind"] == "rollback"]
    assert len(rollbacks) == 1 and rollbacks[0]["to_step"] == 5 and rollbacks[0]["from_step"] == 8
    assert checks and all(ok for _, _, ok in checks), checks
    assert [c[0] for c in checks].count("rollback") == 1
    # training went on after the rollback to the end, with finite weights
    assert summary["step"] == 10 and events[-1]["kind"] == "done"
    assert all(torch.isfinite(v).all() for v in trainer.model.state_dict().values())
    assert max(e["step"] for e in events if e["kind"] == "train") == 10
    # the data after the rollback is drawn in a new order (salted), recorded in the checkpoints
    assert load_checkpoint(tmp_path / "run" / "checkpoints" / "ckpt-00000010").state["data_salt"] == 1


def test_gives_up_after_max_rollbacks(tmp_path, tiny_config):
    cfg = tiny_config(
        train__max_steps=8, train__nonfinite_patience=2, train__max_rollbacks=0, debug__inject_nonfinite_steps=[2, 3]
    )
    with pytest.raises(TrainingDiverged, match="rollback"):
        Trainer(cfg, tmp_path / "run", console=False).fit()
    events = read_events(tmp_path / "run" / "events.jsonl")
    assert events[-1]["kind"] == "error" and "TrainingDiverged" in events[-1]["error"]


def test_validation_best_model_and_checkpoints(tmp_path, tiny_config):
    """Validation after each epoch, on 4-frame windows, last frame only; the best model is a model folder."""
    cfg = tiny_config(
        train__max_steps=8,
        train__validate_every_epochs=1,
        train__checkpoint_every=0,
        train__keep_last=2,
        train__best="abs_rel",
        train__image_every=4,
        train__log_every=2,
    )
    trainer = Trainer(cfg, tmp_path / "run", console=False)
    trainer.fit()
    events = read_events(tmp_path / "run" / "events.jsonl")
    vals = [e for e in events if e["kind"] == "validation"]
    assert [v["step"] for v in vals] == [4, 8]
    # 8 windows of 4 frames: one metric frame per window
    assert all(
        v["metrics"]["frames"] == 8 and v["metrics"]["depth_frames"] == 8 and v["metrics"]["semantic_frames"] == 8
        for v in vals
    )
    bests = [e for e in events if e["kind"] == "best"]
    expected = [4] + ([8] if vals[1]["metrics"]["abs_rel"] < vals[0]["metrics"]["abs_rel"] else [])
    assert [b["step"] for b in bests] == expected
    best_dir = tmp_path / "run" / "best"
    metrics = json.loads((best_dir / "metrics.json").read_text())
    assert metrics["step"] == expected[-1] and metrics["rule"] == "abs_rel"
    state = read_model_state(best_dir)
    ck = load_checkpoint(tmp_path / "run" / "checkpoints" / f"ckpt-{expected[-1]:08d}")
    assert _equal(state, ck.model)  # the best model is the model of that validation's step
    # epoch-end checkpoints only, the newest two kept, all valid
    kept = sorted(p.name for p in (tmp_path / "run" / "checkpoints").iterdir())
    assert kept == ["ckpt-00000004", "ckpt-00000008"]
    for name in kept:
        validate_checkpoint(tmp_path / "run" / "checkpoints" / name)
    # TensorBoard: losses, learning rate, metrics, and pictures of depth and labels (true and predicted)
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(tmp_path / "run" / "tensorboard")).Reload()
    scalars = set(acc.Tags()["scalars"])
    assert {
        "train/loss_total",
        "train/loss_depth",
        "train/loss_semantic",
        "train/lr",
        "val/abs_rel",
        "val/miou",
        "val/rmse",
        "val/iou/0",
    } <= scalars
    assert [e.step for e in acc.Scalars("train/loss_total")] == [2, 4, 6, 8]
    images = acc.Tags()["images"]
    train_tag = next(t for t in images if t.startswith("train/"))
    val_tag = next(t for t in images if t.startswith("val/"))
    pics = acc.Images(train_tag)
    assert [p.step for p in pics] == [4, 8] and (pics[0].width, pics[0].height) == (5 * 16, 16)
    assert [p.step for p in acc.Images(val_tag)] == [4, 8]


def test_validation_uses_only_the_last_frame_of_each_window(tiny_config):
    """run_window's output is the streaming model's last frame, equal to the sequence forward at that frame."""
    from cosemdepth.data.toy import ToyDataset
    from cosemdepth.models import build_model
    from cosemdepth.ops.resample import resize_nn2
    from cosemdepth.training.data import collate
    from cosemdepth.training.validation import run_window

    cfg = tiny_config()
    model = build_model(cfg.model).eval()
    batch = collate([ToyDataset(length=2, size=(32, 32), split="val")[i] for i in range(2)])
    with torch.no_grad():
        last = run_window(model, batch)
        seq = model.forward_sequence(batch["rgb"], batch["rot"], batch["trans"], batch["intrinsics"])
    torch.testing.assert_close(last.depth, resize_nn2(seq.depth[0][:, -1], (32, 32)))
    torch.testing.assert_close(last.semantic, resize_nn2(seq.semantic[0][:, -1], (32, 32)))


@pytest.mark.parametrize("arch", ["m4depth", "m4semantic"])
def test_single_task_models_train(tmp_path, tiny_config, arch):
    cfg = tiny_config(model__arch=arch, train__max_steps=2, train__validate_every_epochs=1)
    summary = Trainer(cfg, tmp_path / arch, console=False).fit()
    metrics = summary["last_validation"]
    assert ("miou" in metrics) == (arch == "m4semantic") and ("abs_rel" in metrics) == (arch == "m4depth")
    assert (tmp_path / arch / "best" / "model.safetensors").is_file()


def test_weighted_mix_of_two_datasets(tmp_path, tiny_config):
    cfg = tiny_config(
        train__max_steps=2,
        data__train__1__name="toy",
        data__train__1__weight=3.0,
        data__train__1__options={"length": 4, "shift": 1},
        data__mix_length=12,
    )
    trainer = Trainer(cfg, tmp_path / "mix", console=False)
    assert len(trainer.train_set) == 12
    sources = [int(trainer.train_set[i]["source"]) for i in range(12)]
    assert set(sources) <= {0, 1} and sources.count(1) > sources.count(0)  # weight 3 vs 1
    trainer.fit()


def test_bf16_autocast_keeps_the_loss_in_float32(tiny_config, bf16_cpu):
    """The model and the loss work under bf16 autocast; the loss stays float32 (CPU autocast, as train.bf16 uses)."""
    from cosemdepth.data.toy import ToyDataset
    from cosemdepth.models import build_model
    from cosemdepth.training.data import collate
    from cosemdepth.training.trainer import compute_loss

    cfg = tiny_config(train__bf16=True)
    model = build_model(cfg.model)
    batch = collate([ToyDataset(length=2, size=(32, 32))[i] for i in range(2)])
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = model(batch["rgb"], batch["rot"], batch["trans"], batch["intrinsics"], batch["reset"])
    assert out.semantic[0].dtype == torch.bfloat16
    terms = compute_loss(out, batch, cfg)
    assert terms.total.dtype == torch.float32 and torch.isfinite(terms.total)
    terms.total.backward()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_compute_loss_applies_the_configured_class_weights(tiny_config):
    """train.semantic_class_weights reaches the semantic loss: the trainer's loss is the weighted one."""
    from cosemdepth.data.toy import ToyDataset
    from cosemdepth.measures.losses import semantic_loss
    from cosemdepth.models import build_model
    from cosemdepth.training.data import collate
    from cosemdepth.training.trainer import compute_loss

    cfg = tiny_config()
    weights = tuple(float(c + 1) for c in range(cfg.model.num_classes))
    weighted_cfg = tiny_config(train__semantic_class_weights=weights)
    model = build_model(cfg.model)
    batch = collate([ToyDataset(length=2, size=(32, 32))[i] for i in range(2)])
    with torch.no_grad():
        out = model(batch["rgb"], batch["rot"], batch["trans"], batch["intrinsics"], batch["reset"])
    plain, weighted = compute_loss(out, batch, cfg), compute_loss(out, batch, weighted_cfg)
    expected = semantic_loss(out.semantic, batch["semantic"], class_weights=weights)
    assert float(weighted.semantic) == pytest.approx(float(expected), rel=1e-6)
    assert float(weighted.semantic) != pytest.approx(float(plain.semantic), rel=1e-5)
    assert float(weighted.depth) == float(plain.depth)


#: bfloat16's unit roundoff: 8 significant bits.
BF16_U = 2.0**-8


def _loss_and_grads(model, batch, cfg, bf16: bool):
    from cosemdepth.training.trainer import bf16_autocast, compute_loss

    model.zero_grad(set_to_none=True)
    with bf16_autocast(torch.device("cpu"), bf16):
        out = model(batch["rgb"], batch["rot"], batch["trans"], batch["intrinsics"], batch["reset"])
    terms = compute_loss(out, batch, cfg)
    terms.total.backward()
    grads = {n: p.grad.detach().clone() for n, p in model.named_parameters() if p.grad is not None}
    return terms, out, grads


def test_bf16_cpu_training_step_is_close_to_float32(tiny_config, bf16_cpu):
    """train.bf16 on the CPU: the same loss and gradient as float32 within bfloat16's rounding.

    Bounds, from the unit roundoff u = 2^-8 (not tuned to the measurement):
      * loss: the mean over ~10^4 output pixels, each rounded about once: |relative error| <= u;
      * gradient (all parameters as one vector): each convolution on the longest path rounds its input in the
        forward and its output gradient in the backward, errors adding like a random walk over 2 n roundings:
        ||g_bf16 - g_fp32|| / ||g_fp32|| <= sqrt(2 n) u, n = 2 L encoder + 7 L refiner convolutions (L levels).
    Measured (levels 3, 32 px, batch 2): 0.16 u and 4.1 u (bound 7.3 u); float32 against float64 on the same
    batch: 8e-6 u and 7e-3 u, so the float32 side is exact at this scale. Parameters whose true gradient is ~0 (a
    bias followed by a normalisation) are why no per-parameter bound is used."""
    import math

    from cosemdepth.data.toy import ToyDataset
    from cosemdepth.models import build_model
    from cosemdepth.training.data import collate

    cfg = tiny_config(data__size=32)
    torch.manual_seed(0)
    model = build_model(cfg.model).train()
    batch = collate([ToyDataset(length=2, size=(32, 32))[i] for i in range(2)])
    t32, _, g32 = _loss_and_grads(model, batch, cfg, bf16=False)
    t16, out16, g16 = _loss_and_grads(model, batch, cfg, bf16=True)
    assert out16.semantic[0].dtype == torch.bfloat16  # the forward really ran in bfloat16
    assert all(p.dtype == torch.float32 for p in model.parameters())  # float32 master weights
    assert all(g.dtype == torch.float32 for g in g16.values())  # and float32 gradients for Adam
    assert t16.total.dtype == torch.float32 and set(g16) == set(g32)
    levels = cfg.model.levels
    n = 2 * levels + 7 * levels
    loss_rel = abs(t16.total.item() - t32.total.item()) / abs(t32.total.item())
    diff = math.sqrt(sum(float((g16[k] - g32[k]).double().pow(2).sum()) for k in g32))
    norm = math.sqrt(sum(float(g.double().pow(2).sum()) for g in g32.values()))
    assert loss_rel <= BF16_U
    assert diff / norm <= math.sqrt(2 * n) * BF16_U
    assert diff > 0  # bf16 did change the arithmetic


def test_loss_is_float32_even_inside_autocast(tiny_config, bf16_cpu):
    """compute_loss switches autocast off: inside a bf16 autocast region it returns the same float32 value as
    outside it, for bf16 predictions."""
    from cosemdepth.data.toy import ToyDataset
    from cosemdepth.models import build_model
    from cosemdepth.training.data import collate
    from cosemdepth.training.trainer import compute_loss

    cfg = tiny_config()
    model = build_model(cfg.model)
    batch = collate([ToyDataset(length=2, size=(16, 16))[i] for i in range(2)])
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        out = model(batch["rgb"], batch["rot"], batch["trans"], batch["intrinsics"], batch["reset"])
        inside = compute_loss(out, batch, cfg)
    outside = compute_loss(out, batch, cfg)
    assert out.semantic[0].dtype == torch.bfloat16
    for t in (inside, outside):
        assert t.total.dtype == t.depth.dtype == t.semantic.dtype == torch.float32
    assert float(inside.total) == float(outside.total)


def test_trainer_bf16_on_cpu_runs_and_keeps_float32_weights(tmp_path, tiny_config, bf16_cpu):
    from cosemdepth.training.checkpoint import load_checkpoint

    cfg = tiny_config(train__bf16=True, train__max_steps=2, train__device="cpu")
    summary = Trainer(cfg, tmp_path / "bf", console=False).fit()
    events = read_events(tmp_path / "bf" / "events.jsonl")
    assert next(e for e in events if e["kind"] == "start")["bf16_autocast"] is True
    losses = [e["loss_total"] for e in events if e["kind"] == "train"]
    assert len(losses) == 2 and all(math.isfinite(v) for v in losses)
    ck = load_checkpoint(summary["checkpoint"])
    assert ck.model and all(v.dtype == torch.float32 for v in ck.model.values() if v.is_floating_point())


def test_train_events_log_the_wait_for_data(tmp_path, tiny_config):
    """A loader that takes at least 0.05 s per item (batch 2, no workers): every step waited at least 0.1 s."""

    class Slow(ToyDataset):
        def __getitem__(self, i):
            time.sleep(0.05)
            return super().__getitem__(i)

    cfg = tiny_config(train__max_steps=3, train__epochs=1)
    slow = Slow(length=8, seq_len=cfg.data.seq_len, size=cfg.data.size, num_classes=cfg.model.num_classes, seed=0)
    Trainer(cfg, tmp_path / "run", train_dataset=slow, console=False).fit()
    waits = [e["data_wait_s"] for e in read_events(tmp_path / "run" / "events.jsonl") if e["kind"] == "train"]
    assert len(waits) == 3 and all(w >= 0.1 for w in waits)


def test_worker_processes_and_resume_give_the_batches_of_the_main_process(tmp_path, tiny_config):
    """Three epochs of a weighted mix (items drawn by epoch) in one continuous stream: with 2 long-lived worker
    processes, stopped in the middle of epoch 1 and resumed, the losses and weights are bitwise those of a run that
    loads in the main process."""
    mix = dict(
        train__epochs=3,
        train__checkpoint_every=100,
        data__train__1__name="toy",
        data__train__1__weight=2.0,
        data__train__1__options={"length": 4, "shift": 1},
        data__mix_length=8,
    )
    ref = Trainer(tiny_config(**mix), tmp_path / "ref", console=False)
    ref.fit()
    Trainer(tiny_config(data__num_workers=2, train__max_steps=6, **mix), tmp_path / "w", console=False).fit()
    resumed = Trainer(tiny_config(data__num_workers=2, **mix), tmp_path / "w", console=False)
    resumed.fit()
    assert _equal(_weights(resumed), _weights(ref))

    def losses(run):
        return {
            e["step"]: e["loss_total"] for e in read_events(tmp_path / run / "events.jsonl") if e["kind"] == "train"
        }

    want = losses("ref")
    assert sorted(want) == list(range(1, 13)) and losses("w") == want
    ends = [e["step"] for e in read_events(tmp_path / "w" / "events.jsonl") if e["kind"] == "epoch_end"]
    assert ends == [4, 8, 12]


def test_init_weights_start_a_new_run_from_given_weights_and_a_resume_ignores_them(tmp_path, tiny_config):
    """``train.init_weights``: the step-0 checkpoint of the new run holds exactly the given weights (here a
    checkpoint folder of another run); a plain run of the same seed does not; resuming never reads them again."""
    Trainer(tiny_config(train__max_steps=2, train__seed=5), tmp_path / "src", console=False).fit()
    source_dir = tmp_path / "src" / "checkpoints" / "ckpt-00000002"
    source = read_model_state(source_dir)

    cfg = tiny_config(train__max_steps=2, train__init_weights=str(source_dir))
    Trainer(cfg, tmp_path / "ft", console=False).fit()
    assert _equal(read_model_state(tmp_path / "ft" / "checkpoints" / "ckpt-00000000"), source)
    start = next(e for e in read_events(tmp_path / "ft" / "events.jsonl") if e["kind"] == "start")
    assert start["init_weights"] == str(source_dir)
    Trainer(tiny_config(train__max_steps=2), tmp_path / "plain", console=False).fit()
    assert not _equal(read_model_state(tmp_path / "plain" / "checkpoints" / "ckpt-00000000"), source)

    for p in source_dir.iterdir():  # the weights are gone: a resume must not need them
        p.unlink()
    resumed = Trainer(
        tiny_config(train__max_steps=4, train__init_weights=str(source_dir)), tmp_path / "ft", console=False
    )
    assert resumed.resuming
    assert resumed.fit()["step"] == 4


def test_init_weights_of_another_model_or_missing_fail_before_writing(tmp_path, tiny_config):
    Trainer(tiny_config(train__max_steps=1), tmp_path / "src", console=False).fit()
    source_dir = tmp_path / "src" / "checkpoints" / "ckpt-00000001"
    for overrides, expected in (
        ({"model__arch": "m4depth"}, "arch 'cosemdepth' (run: 'm4depth')"),
        ({"model__levels": 2}, "levels 3 (run: 2)"),
        ({"model__num_classes": 5}, "num_classes 7 (run: 5)"),
    ):
        with pytest.raises(CheckpointError, match=re.escape(expected)) as e:
            Trainer(tiny_config(train__init_weights=str(source_dir), **overrides), tmp_path / "bad", console=False)
        assert str(e.value).startswith("train.init_weights: ")
    with pytest.raises(CheckpointError, match="train.init_weights: .*missing"):
        Trainer(tiny_config(train__init_weights=str(tmp_path / "missing")), tmp_path / "bad", console=False)
    assert not (tmp_path / "bad").exists()


def test_init_weights_from_an_official_tensorflow_checkpoint(tmp_path, tiny_config, tfref_dir):
    """The authors' checkpoint of the fixture, converted on the fly, is the new run's starting point."""
    expected, _ = convert_checkpoint(tfref_dir / "ckpt")
    cfg = tiny_config(model__levels=5, data__size=32, train__max_steps=1, train__init_weights=str(tfref_dir / "ckpt"))
    Trainer(cfg, tmp_path / "ft", console=False).fit()
    got = read_model_state(tmp_path / "ft" / "checkpoints" / "ckpt-00000000")
    assert got.keys() == expected.keys()
    assert all(torch.equal(got[k], expected[k].float()) for k in got)


@pytest.mark.parametrize("retain", [True, False])
def test_cpu_trainer_retains_host_memory_unless_told_not_to(tmp_path, tiny_config, monkeypatch, retain):
    calls = []
    monkeypatch.setattr("cosemdepth.training.trainer.retain_freed_host_memory", lambda: calls.append(1) or True)
    Trainer(tiny_config(train__device="cpu", train__retain_host_memory=retain), tmp_path / "run", console=False)
    assert calls == ([1] if retain else [])


def test_every_model_folder_of_a_run_records_the_motion_of_its_training_windows(tmp_path, tiny_config, cli_env):
    """The operating point in config.json: data.size, the dataset's focal length there, and the statistics of the
    translations of rows 1..3 of every 4-row chunk of the training CSVs (computed here from a plain parse)."""
    import sys
    from pathlib import Path

    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
    from _writers import read_split_rows, write_midair

    from cosemdepth.checkpoints.model_io import load_model, operating_point_of
    from cosemdepth.data.midair.splits import generate_splits

    root, splits = tmp_path / "midair", tmp_path / "splits"
    write_midair(root, {("Kite_training", "sunny"): [0, 1, 2]}, frames=36, size=32)  # 8 CSV rows per trajectory
    generate_splits(root, splits, rule="train")
    norms = []
    for csv in sorted((splits / "train_data").rglob("*.csv")):
        rows = read_split_rows(csv)
        assert len(rows) == 8
        for chunk in (rows[0:4], rows[4:8]):
            norms += [math.sqrt(sum(float(r[c]) ** 2 for c in ("tx", "ty", "tz"))) for r in chunk[1:]]
    x = np.array(norms)
    expected = {
        "count": 18,
        "mean": x.mean(),
        "median": np.median(x),
        **{f"p{q:02d}": np.percentile(x, q) for q in (5, 25, 75, 95)},
    }

    src = {"name": "midair", "root": str(root), "split_dir": str(splits)}
    cfg = tiny_config(
        data__train=[src],
        data__val=src,
        data__val_split="train",
        data__seq_len=2,
        data__db_seq_len=4,
        data__val_seq_len=2,
        train__max_steps=2,
        train__validate_every_epochs=1,
        train__checkpoint_every=1,
    )
    Trainer(cfg, tmp_path / "run", console=False).fit()
    folders = [*sorted((tmp_path / "run" / "checkpoints").iterdir()), tmp_path / "run" / "best"]
    assert len(folders) >= 2
    for folder in folders:
        op = operating_point_of(folder)
        assert op.size == (16, 16) and op.focal_px == (8.0, 8.0), folder  # the 90-degree camera at 16 px
        assert op.step_translation.to_dict() == pytest.approx(expected, rel=1e-6), folder
    assert load_model(folders[-1]).operating_point == op
    # scripts/ship_weights.py carries it over to the shipped folder
    import subprocess

    script = Path(__file__).resolve().parents[2] / "scripts" / "ship_weights.py"
    subprocess.run(
        [sys.executable, str(script), str(tmp_path / "run"), str(tmp_path / "shipped")],
        env=cli_env,
        check=True,
        capture_output=True,
    )
    assert operating_point_of(tmp_path / "shipped") == op
