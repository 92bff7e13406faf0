"""Per-frame fidelity figures of a converted official checkpoint against the authors' TensorFlow outputs.

    python benchmarks/fidelity.py [--fixture DIR] [--out FILE | --update]

The fixture: ``../shared/fixtures/tfref-s128`` when it is there (the figures of the README), else the repository's
``tests/fixtures/tfref-64x96`` (its compact form is rebuilt in a temporary folder first).
Prints, for both cost-volume precisions, the per-frame figures; with ``--out FILE`` writes the JSON (median / 99th
percentile / max relative error of depth and parallax per frame and level, max absolute error of the semantic
probabilities and encoder features) to FILE; ``--update`` writes it to the tracked
``benchmarks/results/fidelity.json``. By default nothing is written, so a run leaves ``git status`` clean.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from cosemdepth.bench.harness import make_report, write_report
from cosemdepth.checkpoints.model_io import load_model
from cosemdepth.evaluation.fidelity import compare_with_reference

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the test fixtures' builder (tests/tfref_fixture.py)
from tfref_fixture import open_fixture  # noqa: E402

TRACKED = ROOT / "benchmarks" / "results" / "fidelity.json"
SHARED_FIXTURE = ROOT.parent / "shared" / "fixtures" / "tfref-s128"
IN_REPO_FIXTURE = ROOT / "tests" / "fixtures" / "tfref-64x96"


def default_fixture() -> Path:
    """The shared fixture when it is beside the repository, else the repository's own."""
    return SHARED_FIXTURE if (SHARED_FIXTURE / "reference.npz").is_file() else IN_REPO_FIXTURE


def output_path(args: argparse.Namespace) -> Path | None:
    """Where the JSON goes: ``--out``, the tracked result file with ``--update``, else nowhere."""
    return args.out if args.out is not None else (TRACKED if args.update else None)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--fixture", type=Path, default=None, help=f"default: {SHARED_FIXTURE} if present, else {IN_REPO_FIXTURE}"
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument("--out", type=Path, default=None, help="write the JSON here")
    where.add_argument(
        "--update", action="store_true", help="write the JSON to the tracked benchmarks/results/fidelity.json"
    )
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    fixture = args.fixture if args.fixture is not None else default_fixture()
    print(f"fixture: {fixture}")
    with tempfile.TemporaryDirectory(prefix="cosemdepth-fidelity.") as scratch:
        run(args, fixture, open_fixture(fixture, scratch))


def run(args: argparse.Namespace, fixture: Path, folder: Path) -> None:
    """Compare on ``folder`` (the fixture ``fixture``, rebuilt if it is in compact form)."""
    model = load_model(folder / "ckpt", mode="reference")  # the modules: what the fidelity bar is about
    result = {}
    for dtype in ("float16", "float32"):
        model.set_numerics(pscv_half=dtype == "float16")
        result[f"pscv_{dtype}"] = compare_with_reference(model, folder)
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
        write_report(out, make_report("fidelity", {"fixture": str(fixture)}, result))
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
