"""Class weights for the semantic loss from a run config's training data (median-frequency balancing).

    python scripts/class_weights.py --config NAME_OR_YAML [--set KEY=VALUE ...] [--power 0.5] [--out FILE.json]

Opens every ``data.train`` dataset of the config as training opens it (same split, windows and size, without
augmentation), counts the labels of the frames the loss supervises (every window's frames from the second on) and
prints the per-class pixel shares and ``train.semantic_class_weights`` = ``(median share / share) ** power``
(:func:`cosemdepth.measures.losses.median_frequency_weights`), ready to paste into the config.
"""

from __future__ import annotations

import argparse
import json
import sys

import torch

from cosemdepth.errors import ConfigError, CosemdepthError
from cosemdepth.measures.losses import FIRST_SUPERVISED_FRAME, median_frequency_weights
from cosemdepth.output_safety.atomic import atomic_write_text
from cosemdepth.training.config import resolve_config
from cosemdepth.training.data import open_source


def count_labels(cfg) -> torch.Tensor:
    """Pixel count per class over the supervised frames of every training window of ``cfg``'s ``data.train``."""
    n = cfg.model.num_classes
    counts = torch.zeros(n, dtype=torch.int64)
    d = cfg.data
    for i, src in enumerate(d.train):
        ds = open_source(
            src,
            f"data.train[{i}]",
            split=d.train_split,
            seq_len=d.seq_len,
            size=d.size,
            augment=False,
            mode="train",
            db_seq_len=d.db_seq_len,
            seed=cfg.train.seed,
            num_classes=n,
        )
        for j in range(len(ds)):
            labels = torch.as_tensor(ds[j]["semantic"])[FIRST_SUPERVISED_FRAME:]
            counts += torch.bincount(labels.flatten().long(), minlength=n)[:n]
    return counts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", required=True, help="built-in config name or YAML file (as cosemdepth train)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    ap.add_argument("--power", type=float, default=0.5, help="1: median-frequency balancing; 0.5 (default): its root")
    ap.add_argument("--out", help="also write the counts, shares and weights to this JSON file")
    args = ap.parse_args(argv)
    try:
        cfg = resolve_config(args.config, args.set)
        if not cfg.model.has_semantic:
            raise ConfigError(f"--config: the {cfg.model.arch} model has no semantic decoder")
        counts = count_labels(cfg)
        weights = median_frequency_weights(counts.tolist(), args.power)
    except (CosemdepthError, ValueError, OSError) as e:
        print(f"class_weights.py: error: {e}", file=sys.stderr)
        return 2
    total = int(counts.sum())
    report = {
        "config": str(args.config),
        "overrides": args.set,
        "power": args.power,
        "counts": counts.tolist(),
        "shares": [c / total for c in counts.tolist()],
        "semantic_class_weights": [round(w, 3) for w in weights],
    }
    for c, (k, s, w) in enumerate(zip(report["counts"], report["shares"], report["semantic_class_weights"])):
        print(f"class {c}: {k:>12,d} px  {100 * s:6.2f} %  weight {w}")
    print(f"train:\n  semantic_class_weights: {report['semantic_class_weights']}")
    if args.out:
        atomic_write_text(args.out, json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
