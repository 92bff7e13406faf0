"""Per-frame fidelity figures of a converted official checkpoint against the authors' TensorFlow outputs.

    python benchmarks/fidelity.py [--fixture ../shared/fixtures/tfref-s128] [--out FILE | --update]

Prints, for both cost-volume precisions, the per-frame figures; with ``--out FILE`` writes the JSON (median / 99th
percentile / max relative error of depth and parallax per frame and level, max absolute error of the semantic
probabilities and encoder features) to FILE; ``--update`` writes it to the tracked
``benchmarks/results/fidelity.json``. By default nothing is written, so a run leaves ``git status`` clean.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
from pathlib import Path

import torch

from cosemdepth.evaluation.fidelity import compare_with_reference
from cosemdepth.io.atomic import atomic_write_text
from cosemdepth.io.model_io import load_model

ROOT = Path(__file__).resolve().parents[1]
TRACKED = ROOT / "benchmarks" / "results" / "fidelity.json"


def output_path(args: argparse.Namespace) -> Path | None:
    """Where the JSON goes: ``--out``, the tracked result file with ``--update``, else nowhere."""
    return args.out if args.out is not None else (TRACKED if args.update else None)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fixture", type=Path, default=ROOT.parent / "shared" / "fixtures" / "tfref-s128")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--out", type=Path, default=None, help="write the JSON here")
    where.add_argument("--update", action="store_true", help="write the JSON to the tracked benchmarks/results/fidelity.json")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    model = load_model(args.fixture / "ckpt", mode="reference")  # the modules: what the fidelity bar is about
    result = {
        "fixture": str(args.fixture),
        "date": datetime.date.today().isoformat(),
        "torch": torch.__version__,
        "machine": platform.processor() or platform.machine(),
    }
    for dtype in ("float16", "float32"):
        model.set_numerics(pscv_half=dtype == "float16")
        result[f"pscv_{dtype}"] = compare_with_reference(model, args.fixture)
        print(f"cost volume products in {dtype}:")
        for t, frame in enumerate(result[f"pscv_{dtype}"]["streaming"]):
            d = frame.get("depth", {})
            sem = max(v["max_abs"] for k, v in frame.items() if "semantic" in k and "max_abs" in v)
            worst = max((v["p99"], k) for k, v in frame.items() if "p99" in v)
            print(
                f"  frame {t}: depth median {d.get('median', 0):.2e} p99 {d.get('p99', 0):.2e} max {d.get('max', 0):.2e}"
                f" | worst level p99 {worst[0]:.2e} ({worst[1]}) | semantic max abs {sem:.2e}"
            )
    out = output_path(args)
    if out is not None:
        atomic_write_text(out, json.dumps(result, indent=1))
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
