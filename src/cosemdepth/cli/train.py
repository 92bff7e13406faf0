"""``cosemdepth train``: train Co-SemDepth, M4Depth or M4Semantic (docs/training.md).

Examples::

    cosemdepth train --config midair --data-root data/midair --split-dir data/midair/splits --out runs/midair
    cosemdepth train --config synthair-small --data-root data/synthair --out runs/small --set train.lr=3e-4
    torchrun --nproc_per_node=4 -m cosemdepth train --config midair ... --out runs/midair-4gpu

Running the same command again resumes the run from its newest valid checkpoint.
"""

from __future__ import annotations

import argparse
import json

from ..data.registry import DATASETS
from ..models.config import ARCHITECTURES
from ..training.config import RunConfig, dump_config, resolve_config
from ..training.trainer import Trainer

#: The defaults the shortcuts show (the paper's recipe; a --config file may change them).
DEFAULTS = RunConfig()


def configure(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = (
        "Defaults are the paper's Mid-Air recipe (design 9.1). Precedence: defaults < --config file < the "
        "explicit flags < --set overrides (in order). Config keys: see docs/training.md."
    )
    p.add_argument(
        "--config", "-c", metavar="YAML", help="config file, or the name of a shipped config (midair, synthair-small)"
    )
    p.add_argument(
        "--out", "-o", required=True, metavar="RUN_DIR", help="run folder: created if new, resumed if it holds a run"
    )
    p.add_argument(
        "--set",
        "-s",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="overrides",
        help="override a config key, e.g. train.lr=3e-4 or data.train.1.weight=0.5 (repeatable)",
    )
    g = p.add_argument_group("shortcuts for common keys (defaults: the paper's recipe, unless --config sets them)")
    m, d, t = DEFAULTS.model, DEFAULTS.data, DEFAULTS.train
    g.add_argument("--model", choices=tuple(ARCHITECTURES), help=f"model.arch (default {m.arch})")
    g.add_argument(
        "--dataset", metavar="NAME", help=f"data.train.0.name: {', '.join(DATASETS)} (default {d.train[0].name})"
    )
    g.add_argument("--data-root", metavar="DIR", help="data.train.0.root")
    g.add_argument("--split-dir", metavar="DIR", help="data.train.0.split_dir")
    g.add_argument("--epochs", type=int, help=f"train.epochs (default {t.epochs})")
    g.add_argument("--max-steps", type=int, metavar="N", help=f"train.max_steps (default {t.max_steps}: no limit)")
    g.add_argument("--batch-size", type=int, metavar="B", help=f"train.batch_size (default {t.batch_size})")
    g.add_argument("--lr", type=float, help=f"train.lr (default {t.lr:g})")
    g.add_argument("--seed", type=int, help=f"train.seed (default {t.seed})")
    g.add_argument("--device", help=f"train.device: auto, cpu, cuda, cuda:N (default {t.device})")
    g.add_argument(
        "--bf16",
        action="store_true",
        default=None,
        help="train.bf16: bfloat16 autocast of the forward (CPU and CUDA); fp32 weights and loss",
    )
    g.add_argument(
        "--init-weights",
        metavar="PATH",
        help="train.init_weights: start from these weights (a model folder, a run's best/ or checkpoint "
        "folder, an official TF checkpoint) instead of a random initialisation: fine-tuning",
    )
    g.add_argument(
        "--init-from",
        metavar="MODEL_DIR",
        help="train.init_from: start from the weights of a model of another config (another arch, "
        "semantic_sncv or semantic_time): matching tensors copied, new input channels zero, so the "
        "run starts with that model's outputs",
    )
    g.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--print-config", action="store_true", help="print the resolved config and exit")


_FLAGS = {
    "model": "model.arch",
    "dataset": "data.train.0.name",
    "data_root": "data.train.0.root",
    "split_dir": "data.train.0.split_dir",
    "epochs": "train.epochs",
    "max_steps": "train.max_steps",
    "batch_size": "train.batch_size",
    "lr": "train.lr",
    "seed": "train.seed",
    "device": "train.device",
    "bf16": "train.bf16",
    "init_weights": "train.init_weights",
    "init_from": "train.init_from",
}


def run(args: argparse.Namespace) -> int:
    values = {key: getattr(args, attr) for attr, key in _FLAGS.items() if getattr(args, attr) is not None}
    if args.no_progress:
        values["train.progress"] = False
    cfg = resolve_config(args.config, args.overrides, values)
    if args.print_config:
        print(dump_config(cfg), end="")
        return 0

    trainer = Trainer(cfg, args.out)
    summary = trainer.fit()
    if trainer.dist.is_main:
        best = summary.get("best")
        print(
            json.dumps(
                {
                    "run_dir": summary["run_dir"],
                    "step": summary["step"],
                    "epoch": summary["epoch"],
                    "best_step": None if best is None else best.get("step"),
                    "checkpoint": summary["checkpoint"],
                }
            )
        )
    return 0
