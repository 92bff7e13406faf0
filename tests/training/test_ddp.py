"""Two-process DistributedDataParallel on CPU (gloo, started by torchrun) gives the weights of one process with the
doubled batch; only rank 0 writes."""

from __future__ import annotations

import subprocess

import torch

from cosemdepth.training.checkpoint import load_checkpoint
from cosemdepth.training.events import read_events
from cosemdepth.training.trainer import Trainer

STEPS = 3


def test_two_process_ddp_matches_one_process_with_double_batch(tmp_path, python, cli_env, tiny_cli, tiny_config):
    run = tmp_path / "ddp"
    # Adam's eps is raised from 1e-7 to 1e-3 here: the bias of the first convolution feeds DINL, which subtracts the
    # per-channel mean, so its true gradient is zero and what is left is float rounding noise (~1e-9) that depends
    # on how the batch is split. With eps = 1e-7 Adam turns that noise into full +-lr steps; with 1e-3 it stays
    # noise, while every real gradient still gets an Adam step. The weights then agree to ~3e-8 (moves ~3e-4).
    settings = dict(
        data__augment=False,
        train__max_steps=STEPS,
        train__checkpoint_every=100,
        train__eps=1e-3,
        train__validate_every_epochs=1,
    )
    cmd = [
        python,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nnodes=1",
        "--nproc_per_node=2",
        "-m",
        "cosemdepth",
        "train",
        "--out",
        str(run),
        *tiny_cli(train__batch_size=1, **settings),
    ]
    r = subprocess.run(cmd, env=cli_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-4000:]

    ref = Trainer(tiny_config(train__batch_size=2, **settings), tmp_path / "single", console=False)
    ref.fit()

    ddp = load_checkpoint(run / "checkpoints" / f"ckpt-{STEPS:08d}")
    single = ref.model.state_dict()
    init = load_checkpoint(tmp_path / "single" / "checkpoints" / "ckpt-00000000").model
    moved = 0.0
    for k, v in single.items():
        torch.testing.assert_close(ddp.model[k], v, rtol=1e-5, atol=1e-6, msg=lambda m, k=k: f"{k}: {m}")
        moved = max(moved, float((v - init[k]).abs().max()))
    assert moved > 1e-4  # the weights did change: the comparison is not between two initialisations

    events = read_events(run / "events.jsonl")
    start = next(e for e in events if e["kind"] == "start")
    assert start["world_size"] == 2 and start["steps_per_epoch"] == 4  # 8 items / 2 ranks / batch 1
    # rank 0 alone writes: one event per step, one checkpoint per save, one TensorBoard file
    assert [e["step"] for e in events if e["kind"] == "train"] == list(range(1, STEPS + 1))
    assert [e["step"] for e in events if e["kind"] == "checkpoint"] == [0, STEPS]
    assert len(list((run / "tensorboard").iterdir())) == 1
    # the logged losses are the average over the ranks: the loss of the doubled batch
    ref_first = next(e for e in read_events(tmp_path / "single" / "events.jsonl") if e["kind"] == "train")
    ddp_first = next(e for e in events if e["kind"] == "train")
    assert abs(ddp_first["loss_total"] - ref_first["loss_total"]) < 1e-5 * abs(ref_first["loss_total"])
    # the final validation ran (every rank computes it, rank 0's result is used) and wrote the best model once
    val = [e for e in events if e["kind"] == "validation"]
    assert len(val) == 1 and val[0]["step"] == STEPS and val[0]["metrics"]["frames"] == 8
    assert abs(val[0]["metrics"]["abs_rel"] - ref.state.last_validation["abs_rel"]) < 1e-4
    assert [e["step"] for e in events if e["kind"] == "best"] == [STEPS] and (run / "best" / "config.json").is_file()
