"""Speed of a training step and of the checkpoint machinery (write, validate, load), on this machine.

    PYTHONPATH=src python benchmarks/train_speed.py [--size 128] [--levels 5] [--batch 3] [--threads 1]
        [--device cpu] [--steps 5] [--out result.json]

Prints a JSON object (seconds; best of the timed steps after one warm-up) and writes it to ``--out`` if given.
The step is the whole training step of the trainer: Co-SemDepth forward over 4 frames, the loss of design 8, backward,
the non-finite check and Adam. The checkpoint figures are for the model of ``--levels`` levels (5: the paper's).
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import torch

from cosemdepth.bench.report import print_json
from cosemdepth.config import RunConfig
from cosemdepth.models import build_model
from cosemdepth.training.checkpoint import CheckpointManager, get_rng_state, load_checkpoint, validate_checkpoint
from cosemdepth.training.data import collate, to_device
from cosemdepth.training.toy import ToyDataset
from cosemdepth.training.trainer import bf16_autocast, compute_loss, forward_batch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("--batch", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--bf16", action="store_true")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    device = torch.device(a.device)
    cfg = RunConfig.from_dict({"model": {"levels": a.levels}, "data": {"train": [{"name": "toy"}]}})
    model = build_model(cfg.model).to(device).train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4, eps=1e-7)
    batch = to_device(collate([ToyDataset(length=a.batch, size=(a.size, a.size))[i] for i in range(a.batch)]), device)

    def step() -> None:
        with bf16_autocast(device, a.bf16):
            out = forward_batch(model, batch)
        loss = compute_loss(out, batch, cfg).total
        opt.zero_grad(set_to_none=True)
        loss.backward()
        norm = torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(p.grad) for p in model.parameters()
                                                     if p.grad is not None]))
        if bool(torch.isfinite(loss)) and bool(torch.isfinite(norm)):
            opt.step()
        if device.type == "cuda":
            torch.cuda.synchronize()

    step()  # warm-up
    times = []
    for _ in range(a.steps):
        t = time.perf_counter()
        step()
        times.append(time.perf_counter() - t)

    with tempfile.TemporaryDirectory() as tmp:
        mgr = CheckpointManager(Path(tmp) / "ck", keep_last=2)
        t = time.perf_counter()
        path = mgr.save(model_state=model.state_dict(), model_config=cfg.model, optimizer_state=opt.state_dict(),
                        trainer_state={"step": 1, "epoch": 0}, rng_state=get_rng_state())
        t_save = time.perf_counter() - t
        size = sum(p.stat().st_size for p in path.iterdir())
        t = time.perf_counter()
        validate_checkpoint(path)
        t_validate = time.perf_counter() - t
        t = time.perf_counter()
        load_checkpoint(path, validate=False)
        t_load = time.perf_counter() - t

    result = {
        "machine": platform.platform(), "processor": platform.processor() or platform.machine(),
        "torch": torch.__version__, "device": str(device), "threads": a.threads, "size": a.size,
        "levels": a.levels, "batch": a.batch, "seq_len": 4, "bf16": a.bf16,
        "num_parameters": model.num_parameters(),
        "train_step_s_best": min(times), "train_step_s_median": sorted(times)[len(times) // 2],
        "checkpoint_bytes": size, "checkpoint_save_s": t_save, "checkpoint_validate_s": t_validate,
        "checkpoint_load_s": t_load,
    }
    print_json(result, a.out)


if __name__ == "__main__":
    main()
