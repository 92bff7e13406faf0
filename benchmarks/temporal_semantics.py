"""The semantic decoder's temporal variants side by side: Co-SemDepth, +SNCV, +S^{t-1} warped with the ground-truth
depth, and Co-SemDepth-T (S^{t-1} warped with the model's own depth), each trained with the same recipe and budget
for several seeds on SynthAir and evaluated on held-out flights (other world seeds).

    python benchmarks/temporal_semantics.py [--work DIR] [--init MODEL_DIR] [--lr LR] [--supersample 1|3|5]
        [--test-frames 100] [--seeds 0 1 2] [--steps 60] [--test-worlds 21 22] [--variants cosemdepth sncv s_prev_gt cosemdepth_t] [--threads 1] [--rounds 3]
        [--out benchmarks/results/temporal_semantics] [--strip docs/images/temporal_strip.png]

Data (generated with ``cosemdepth synth`` into ``--work`` and reused by a later run): training world 5, trajectories
0 and 1 of the sunny and cloudy climates (128 px, 200 frames at the default frame step: 48 training windows), every
trajectory in training; the held-out flights are one sunny trajectory of each ``--test-worlds`` seed (100 frames, 25
rows). Training: ``cosemdepth train --config synthair-small`` (4 levels, batch 2, lr 3e-4, augmentation) for
``--steps`` steps with ``train.num_threads`` ``--threads``; the model evaluated is the one of the last step (one
validation at the end writes it to ``best/``). A run folder that already holds ``best/`` is not trained again.

Fine-tuning (``--init MODEL_DIR``): every variant starts from the same trained weights (``train.init_from``: the
matching tensors copied, the new input channels of the semantic refiners zero), so at step 0 every variant computes
exactly that model's outputs, which are evaluated once as the reference row. The recipe then takes the source's
levels, and the bf16 autocast and semantic class weights its ``config.json`` records, with lr ``--lr`` (default
:data:`FINETUNE_LR`); the data is supersampled 3x by default as the shipped weights' was. Runs go to a folder named
after the recipe, so a from-scratch study and a fine-tuning one do not reuse each other's runs.

Evaluation: ``evaluate`` (fast engine, float32, the default every-frame policy, reset frames left out) on each
held-out flight with ``--threads`` threads; per run the mean over the flights of ``miou`` and of the labels' temporal
consistency (``flicker``, ``change_recall``, ``gt_change``: docs/evaluation.md). Per variant: the mean and the
sample standard deviation (and min, max) over the seeds. Time per frame: the seed-0 models of every variant streamed
over the first held-out flight in ``--rounds`` interleaved rounds (variant order rotated each round), the median of
the rounds' ``ms_per_frame``. Writes ``OUT.json``, ``OUT.md`` and ``OUT.png`` (mIoU and flicker per seed, ms per
frame) and the picture strip (labels over consecutive frames of the first held-out flight, seed-0 models).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

from cosemdepth.bench.harness import make_report, run_meta, write_report
from cosemdepth.output_safety.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]

#: Variant -> (label, ``cosemdepth train`` overrides). Everything else is the synthair-small recipe.
VARIANTS = {
    "cosemdepth": ("Co-SemDepth", ["model.arch=cosemdepth"]),
    "sncv": ("+SNCV", ["model.arch=cosemdepth", "model.semantic_sncv=true"]),
    "s_prev_gt": ("+S^{t-1} (GT depth)", ["model.arch=cosemdepth", "model.semantic_time=gt"]),
    "cosemdepth_t": ("Co-SemDepth-T", ["model.arch=cosemdepth-t"]),
    "cosemdepth_t_avg": ("Co-SemDepth-T, output averaged (a 0.5)", ["model.arch=cosemdepth-t"]),
}
#: Variants with no training of their own: another variant's trained weights under model-config changes that add no
#: parameter (variant -> (source variant, model-config changes)).
DERIVED = {"cosemdepth_t_avg": ("cosemdepth_t", {"semantic_fusion": 0.5})}
TRAIN_WORLD = 5
TRAIN_CLIMATES = ("sunny", "cloudy")
SIZE = 128
#: Issue targets for Co-SemDepth-T against Co-SemDepth (mean over seeds).
TARGETS = {"miou_gain_points": 2.0, "flicker_reduction": 0.30, "time_increase_max": 0.10}
STRIP_FRAMES = 6
#: Learning rate of the fine-tuning (``--init``): the shipped weights' stage 2 started at 6e-5 with batch 3.
FINETUNE_LR = 3e-5
#: A killed training run is resumed this many times in all, after a pause.
TRAIN_ATTEMPTS, RETRY_WAIT_S = 4, 60


def cli(*args: str, log: Path | None = None, threads: int = 1) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    cmd = [sys.executable, "-m", "cosemdepth", *args]
    with open(log, "a") if log else open(os.devnull, "w") as f:
        f.write(" ".join(cmd) + "\n")
        f.flush()
        subprocess.run(cmd, check=True, env=env, stdout=f, stderr=subprocess.STDOUT)


def make_data(
    work: Path, test_worlds: list[int], log: Path, supersample: int = 1, test_frames: int = 100
) -> tuple[Path, Path, dict[int, tuple[Path, Path]]]:
    """Generate (or reuse) the training world and the held-out flights; returns the training root and split folder
    and, per test world, its root and split folder."""
    ss = ["--supersample", str(supersample)]
    tag = "" if supersample == 1 else f"-ss{supersample}"
    train = work / f"train-s{TRAIN_WORLD}{tag}"
    if not (train / "synthair.json").exists():
        cli(
            "synth",
            "--out",
            str(train),
            "--trajectories",
            "2",
            "--frames",
            "200",
            "--size",
            str(SIZE),
            "--seed",
            str(TRAIN_WORLD),
            "--climates",
            *TRAIN_CLIMATES,
            *ss,
            "--no-progress",
            log=log,
        )
    splits = work / f"splits-train-s{TRAIN_WORLD}{tag}"
    if not (splits / "train_data").exists():
        cli("splits", "synthair", str(train), str(splits), "--rule", "train", log=log)
        # the trainer validates once, at the end, to write the last step's model to best/: a training flight will do
        val = splits / "val_data" / "SynthAir" / "sunny"
        val.mkdir(parents=True, exist_ok=True)
        shutil.copy(splits / "train_data" / "SynthAir" / "sunny" / "traj_0000.csv", val / "traj_0000.csv")
    tests = {}
    test_tag = ("" if test_frames == 100 else f"-f{test_frames}") + tag
    for w in test_worlds:
        root, sp = work / f"test-s{w}{test_tag}", work / f"splits-test-s{w}{test_tag}"
        if not (root / "synthair.json").exists():
            cli(
                "synth",
                "--out",
                str(root),
                "--trajectories",
                "1",
                "--frames",
                str(test_frames),
                "--size",
                str(SIZE),
                "--seed",
                str(w),
                "--climates",
                "sunny",
                *ss,
                "--no-progress",
                log=log,
            )
        if not (sp / "test_data").exists():
            cli("splits", "synthair", str(root), str(sp), "--rule", "test", log=log)
        tests[w] = (root, sp)
    return train, splits, tests


def recipe_sets(init: Path | None, lr: float | None) -> list[str]:
    """The ``--set`` overrides of the recipe common to every variant, on top of ``--config synthair-small``.

    From scratch: synthair-small as it is (``lr`` replaces its 3e-4). Fine-tuning (``init``): the source model's
    levels, and its training's precision (bf16 autocast) and per-class weights of the semantic loss when its
    config.json records them (the shipped weights' stage 2), ``lr`` (default :data:`FINETUNE_LR`)."""
    sets = [] if lr is None and init is None else [f"train.lr={lr if lr is not None else FINETUNE_LR}"]
    if init is not None:
        meta = json.loads((init / "config.json").read_text(encoding="utf-8"))
        sets.append(f"model.levels={meta['model']['levels']}")
        train_cfg = meta.get("source", {}).get("run_config", {}).get("train", {})
        if train_cfg.get("bf16"):
            sets.append("train.bf16=true")
        if train_cfg.get("semantic_class_weights"):
            sets.append(f"train.semantic_class_weights={json.dumps(train_cfg['semantic_class_weights'])}")
    return sets


def train_run(
    run: Path,
    variant: str,
    seed: int,
    steps: int,
    train: Path,
    splits: Path,
    threads: int,
    log: Path,
    init: Path | None = None,
    recipe: list[str] = (),
) -> float:
    """Train one run (unless its ``best/`` exists); returns the training wall time in seconds (NaN when reused)."""
    if (run / "best" / "model.safetensors").exists():
        return math.nan
    # epochs high enough that --steps alone ends the run
    sets = [
        *VARIANTS[variant][1],
        *recipe,
        f"train.num_threads={threads}",
        "train.epochs=1000",
        "train.validate_every_epochs=0",
        f"train.validate_every_steps={steps}",
        "train.val_max_batches=1",
    ]
    if init is not None:
        sets.append(f"train.init_from={init}")
    t0 = time.perf_counter()
    for attempt in range(TRAIN_ATTEMPTS):
        try:
            cli(
                "train",
                "--config",
                "synthair-small",
                "--data-root",
                str(train),
                "--split-dir",
                str(splits),
                "--max-steps",
                str(steps),
                "--seed",
                str(seed),
                "--no-progress",
                "--out",
                str(run),
                *sum((["--set", s] for s in sets), []),
                log=log,
                threads=threads,
            )
            break
        except subprocess.CalledProcessError:
            # killed (e.g. out of memory on a shared machine): the run folder resumes from its last checkpoint,
            # with the weights an uninterrupted run has at that step
            if attempt == TRAIN_ATTEMPTS - 1:
                raise
            time.sleep(RETRY_WAIT_S)
    return time.perf_counter() - t0


def derive_run(source: Path, run: Path, changes: dict) -> None:
    """``run/best``: the weights of ``source/best`` in a model whose config has ``changes`` (unless it exists)."""
    from cosemdepth.checkpoints.model_io import load_model, save_model
    from cosemdepth.models import build_model

    if (run / "best" / "model.safetensors").exists():
        return
    src = load_model(source / "best", mode="reference")
    model = build_model(src.config, **changes)
    model.load_state_dict(src.state_dict())
    save_model(model, run / "best", source={"type": "derived", "from": str(source / "best"), "changes": changes})


def evaluate_run(model_dir: Path, tests: dict, sinks_for=None) -> dict:
    from cosemdepth.checkpoints.model_io import load_model
    from cosemdepth.data import open_dataset
    from cosemdepth.evaluation.evaluator import evaluate

    model = load_model(model_dir, mode="fast")
    per_flight = {}
    for w, (root, sp) in tests.items():
        ds = open_dataset("synthair", root, split_dir=sp, split="test", seq_len=1, size=SIZE)
        res = evaluate(model, ds, warmup=2, sinks=sinks_for(w) if sinks_for else [])
        m = res.metrics
        per_flight[w] = {
            k: _num(m.get(k))
            for k in (
                "miou",
                "flicker",
                "flicker_median",
                "flicker_max",
                "change_recall",
                "gt_change",
                "flicker_pairs",
                "abs_rel",
            )
        }
        per_flight[w]["ms_per_frame"] = res.ms_per_frame
    mean = {
        k: _mean([f[k] for f in per_flight.values()])
        for k in ("miou", "flicker", "change_recall", "gt_change", "abs_rel")
    }
    return {
        "per_flight": {str(k): v for k, v in per_flight.items()},
        **mean,
        "params": sum(p.numel() for p in model.parameters()),
    }


def time_variants(models: dict[str, Path], tests: dict, rounds: int) -> dict[str, dict]:
    """Interleaved rounds on the first held-out flight: per variant every round's ms per frame and their median."""
    from cosemdepth.checkpoints.model_io import load_model
    from cosemdepth.data import open_dataset
    from cosemdepth.evaluation.evaluator import evaluate

    w = next(iter(tests))
    root, sp = tests[w]
    ds = open_dataset("synthair", root, split_dir=sp, split="test", seq_len=1, size=SIZE)
    loaded = {v: load_model(p, mode="fast") for v, p in models.items()}
    names = list(loaded)
    times = {v: [] for v in names}
    for r in range(rounds):
        order = names[r % len(names) :] + names[: r % len(names)]
        for v in order:
            times[v].append(evaluate(loaded[v], ds, warmup=2).ms_per_frame)
    return {v: {"rounds": t, "median": statistics.median(t)} for v, t in times.items()}


def _tag(recipe: list[str]) -> str:
    """A short name for a fine-tuning recipe's run folders (another recipe trains into other folders)."""
    return hashlib.sha256("\n".join(recipe).encode()).hexdigest()[:8]


def _num(x):
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else x


def _mean(xs):
    xs = [x for x in xs if x is not None]
    return sum(xs) / len(xs) if xs else None


def summarize(values: list) -> dict:
    xs = [x for x in values if x is not None]
    if not xs:
        return {"mean": None, "std": None, "min": None, "max": None, "n": 0}
    return {
        "mean": statistics.fmean(xs),
        "std": statistics.stdev(xs) if len(xs) > 1 else 0.0,
        "min": min(xs),
        "max": max(xs),
        "n": len(xs),
    }


def acceptance(summary: dict, variant: str = "cosemdepth_t") -> dict:
    """The targets for Co-SemDepth-T (or ``variant``) against Co-SemDepth, with what was measured."""
    base, t = summary.get("cosemdepth"), summary.get(variant)
    if not base or not t:
        return {}
    gain = 100 * (t["miou"]["mean"] - base["miou"]["mean"])
    red = 1 - t["flicker"]["mean"] / base["flicker"]["mean"] if base["flicker"]["mean"] else None
    inc = t["ms_per_frame"] / base["ms_per_frame"] - 1
    out = {
        "miou_gain_points": {
            "target": f">= +{TARGETS['miou_gain_points']}",
            "measured": gain,
            "met": gain >= TARGETS["miou_gain_points"],
        },
        "flicker_reduction": {
            "target": f">= {TARGETS['flicker_reduction']:.0%}",
            "measured": red,
            "met": red is not None and red >= TARGETS["flicker_reduction"],
        },
        "time_increase": {
            "target": f"<= {TARGETS['time_increase_max']:.0%}",
            "measured": inc,
            "met": inc <= TARGETS["time_increase_max"],
        },
    }
    gt = summary.get("s_prev_gt") if variant == "cosemdepth_t" else None
    if gt:
        out["s_prev_gt_miou_gain_points"] = {
            "paper": 1.56,
            "measured": 100 * (gt["miou"]["mean"] - base["miou"]["mean"]),
        }
    return out


def markdown(report: dict) -> str:
    s = report["summary"]
    lines = [
        "# The semantic decoder's temporal variants (SynthAir)",
        "",
        f"`{report['command']}` on {report['machine']['cpu']} ({report['machine']['threads']} thread), "
        f"{report['date']}. Recipe: {report['recipe']}. Held-out flights: worlds {report['test_worlds']} "
        f"(sunny, {report['test_frames'] // 4 - 1} rows each, supersample {report['supersample']}). "
        f"Seeds {report['seeds']}.",
        "",
        "| variant | mIoU % (mean ± sd, min-max) | flicker % (mean ± sd) | change recall % | ms/frame | params |",
        "|---|---|---|---|---|---|",
    ]
    ref = report.get("reference")
    if ref:
        lines.append(
            f"| step 0: `{report['init']}` (every variant) | {100 * ref['miou']:.2f} | "
            f"{100 * ref['flicker']:.2f} | {100 * ref['change_recall']:.1f} | | {ref['params']:,} |"
        )
    for v, row in s.items():
        mi, fl, cr = row["miou"], row["flicker"], row["change_recall"]
        lines.append(
            f"| {VARIANTS[v][0]} | {100 * mi['mean']:.2f} ± {100 * mi['std']:.2f} ({100 * mi['min']:.2f}-"
            f"{100 * mi['max']:.2f}) | {100 * fl['mean']:.2f} ± {100 * fl['std']:.2f} | {100 * cr['mean']:.1f} | "
            f"{row['ms_per_frame']:.1f} | {row['params']:,} |"
        )
    gt_change = [r["gt_change"] for r in report["runs"] if r.get("gt_change") is not None]
    if gt_change:
        lines += [
            "",
            f"The ground truth itself changes (warped with the true depth and motion) on "
            f"{100 * statistics.fmean(gt_change):.1f} % of the compared pixels.",
        ]
    for key, who in (("acceptance", "Co-SemDepth-T"), ("acceptance_averaged", VARIANTS["cosemdepth_t_avg"][0])):
        acc = report.get(key) or {}
        if not acc:
            continue
        lines += ["", f"Acceptance ({who} against Co-SemDepth, means over the seeds):", ""]
        for k, a in acc.items():
            meas = a["measured"]
            txt = "n/a" if meas is None else (f"{meas:+.2f} points" if "points" in k else f"{100 * meas:+.1f} %")
            target = a.get("target", f"paper +{a.get('paper')} points")
            met = "" if "met" not in a else (" (met)" if a["met"] else " (missed)")
            lines.append(f"* {k}: target {target}, measured {txt}{met}")
    lines += [
        "",
        "Per run (mean over the held-out flights):",
        "",
        "| variant | seed | mIoU % | flicker % | train s |",
        "|---|---|---|---|---|",
    ]
    for r in report["runs"]:
        ts = "reused" if r["train_seconds"] is None else f"{r['train_seconds']:.0f}"
        lines.append(
            f"| {VARIANTS[r['variant']][0]} | {r['seed']} | {100 * r['miou']:.2f} | {100 * r['flicker']:.2f} | {ts} |"
        )
    return "\n".join(lines) + "\n"


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for k, v in enumerate(report["summary"]):
        runs = [r for r in report["runs"] if r["variant"] == v]
        a.scatter(
            [100 * r["flicker"] for r in runs], [100 * r["miou"] for r in runs], label=VARIANTS[v][0], color=f"C{k}"
        )
        b.bar(k, report["summary"][v]["ms_per_frame"], color=f"C{k}")
    a.set_xlabel("flicker % (lower is better)")
    a.set_ylabel("mIoU %")
    a.legend(fontsize=8)
    a.set_title("per seed, held-out flights")
    b.set_xticks(range(len(report["summary"])), [VARIANTS[v][0] for v in report["summary"]], rotation=20, fontsize=8)
    b.set_ylabel("ms per frame (CPU, 1 thread)")
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    os.replace(tmp, path)


class StripCollector:
    """A sink of the evaluation keeping the RGB, ground-truth and predicted labels of frames ``first..first+n-1``."""

    def __init__(self, first: int, n: int):
        self.first, self.n = first, n
        self.rgb, self.gt, self.pred = {}, {}, {}

    def open(self, folder) -> None:
        pass

    def close(self) -> dict:
        return {}

    def abort(self) -> None:
        pass

    def __call__(self, batch) -> None:
        for b, fr in enumerate(batch.frame.tolist()):
            if self.first <= fr < self.first + self.n:
                self.rgb[fr] = batch.rgb[b].float().cpu().numpy()
                self.gt[fr] = batch.gt_labels[b].cpu().numpy()
                self.pred[fr] = batch.labels[b].cpu().numpy()


def _label(v: str) -> str:
    return "step 0 (--init)" if v == "init" else VARIANTS[v][0]


def write_strip(collectors: dict[str, StripCollector], path: Path, num_classes: int) -> None:
    from PIL import Image, ImageDraw

    from cosemdepth.measures.classes import class_info
    from cosemdepth.render.visualize import colorize_labels, rgb_to_uint8

    _, palette = class_info(num_classes, "synthair")
    any_c = next(iter(collectors.values()))
    frames = sorted(any_c.pred)
    rows = [
        ("RGB", [rgb_to_uint8(any_c.rgb[f]) for f in frames]),
        ("ground truth", [colorize_labels(any_c.gt[f], palette) for f in frames]),
    ]
    rows += [(_label(v), [colorize_labels(c.pred[f], palette) for f in frames]) for v, c in collectors.items()]
    h, w = rows[0][1][0].shape[:2]
    measure = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    label_w, gap = max(150, 12 + max(int(measure.textlength(name)) for name, _ in rows)), 2
    canvas = Image.new("RGB", (label_w + len(frames) * (w + gap), len(rows) * (h + gap) + 16), "white")
    draw = ImageDraw.Draw(canvas)
    for j, f in enumerate(frames):
        draw.text((label_w + j * (w + gap) + 4, 2), f"frame {f}", fill="black")
    for i, (name, tiles) in enumerate(rows):
        y = 16 + i * (h + gap)
        draw.text((4, y + h // 2 - 6), name, fill="black")
        for j, tile in enumerate(tiles):
            canvas.paste(Image.fromarray(tile), (label_w + j * (w + gap), y))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.png")
    canvas.save(tmp)
    os.replace(tmp, path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=Path("runs/temporal_semantics"))
    ap.add_argument(
        "--init",
        type=Path,
        metavar="MODEL_DIR",
        help="fine-tune every variant from these weights (train.init_from) instead of training from scratch",
    )
    ap.add_argument(
        "--lr",
        type=float,
        help=f"learning rate (default: synthair-small's 3e-4 from scratch, {FINETUNE_LR:g} with --init)",
    )
    ap.add_argument(
        "--supersample",
        type=int,
        choices=(1, 3, 5),
        help="SynthAir colour supersampling of the data (default 1; 3 with --init, as the shipped "
        "weights' training data)",
    )
    ap.add_argument("--test-frames", type=int, default=100, help="25 Hz frames of each held-out flight (default 100)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--test-worlds", type=int, nargs="+", default=[21, 22])
    ap.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "temporal_semantics")
    ap.add_argument("--strip", type=Path, default=ROOT / "docs" / "images" / "temporal_strip.png")
    a = ap.parse_args()
    if a.init is not None and not (a.init / "config.json").is_file():
        print(f"--init {a.init}: not a model folder (no config.json)", file=sys.stderr)
        return 2
    supersample = a.supersample or (3 if a.init is not None else 1)
    torch.set_num_threads(a.threads)
    a.work.mkdir(parents=True, exist_ok=True)
    log = a.work / "log.txt"
    train, splits, tests = make_data(a.work, a.test_worlds, log, supersample, a.test_frames)
    recipe = recipe_sets(a.init, a.lr)
    runs_dir = a.work / ("runs" if a.init is None else f"runs-ft-{_tag([str(a.init), *recipe])}")
    first_world = a.test_worlds[0]
    collectors: dict[str, StripCollector] = {}
    reference = None
    if a.init is not None:  # every variant's step 0: the source model's outputs exactly
        collectors["init"] = StripCollector(1, STRIP_FRAMES)
        reference = evaluate_run(a.init, tests, lambda w, c=collectors["init"]: [c] if w == first_world else [])
        print(f"init ({a.init}): miou {reference['miou']:.4f} flicker {reference['flicker']:.4f}", flush=True)
    runs = []
    for seed in a.seeds:  # seed-major: every variant has some seeds done if the study is cut short
        for v in a.variants:
            run = runs_dir / f"{v}-s{seed}"
            if v in DERIVED:
                src_v, changes = DERIVED[v]
                src = runs_dir / f"{src_v}-s{seed}"
                train_run(src, src_v, seed, a.steps, train, splits, a.threads, log, a.init, recipe)
                derive_run(src, run, changes)
                secs = math.nan
            else:
                secs = train_run(run, v, seed, a.steps, train, splits, a.threads, log, a.init, recipe)
            cb = None
            if seed == a.seeds[0]:
                collectors[v] = StripCollector(1, STRIP_FRAMES)
                cb = lambda w, c=collectors[v]: [c] if w == first_world else []  # noqa: E731
            res = evaluate_run(run / "best", tests, cb)
            runs.append({"variant": v, "seed": seed, "train_seconds": None if math.isnan(secs) else secs, **res})
            print(
                f"{v} seed {seed}: miou {res['miou']:.4f} flicker {res['flicker']:.4f} ({secs:.0f} s training)",
                flush=True,
            )
    timing = time_variants({v: runs_dir / f"{v}-s{a.seeds[0]}" / "best" for v in a.variants}, tests, a.rounds)
    summary = {}
    for v in a.variants:
        rs = [r for r in runs if r["variant"] == v]
        summary[v] = {
            "label": VARIANTS[v][0],
            "overrides": VARIANTS[v][1],
            **{k: summarize([r[k] for r in rs]) for k in ("miou", "flicker", "change_recall", "abs_rel")},
            "ms_per_frame": timing[v]["median"],
            "ms_per_frame_rounds": timing[v]["rounds"],
            "params": rs[0]["params"],
        }
    meta = run_meta()
    start = "from scratch" if a.init is None else f"fine-tuned from {a.init} (train.init_from)"
    report = {
        "command": meta["command"],
        "date": meta["date_utc"],
        "machine": {"cpu": meta["cpu_model"], "threads": a.threads, "torch": torch.__version__},
        "recipe": f"cosemdepth train --config synthair-small {' '.join('--set ' + x for x in recipe)} (128 px, "
        f"batch 2), {start}, {a.steps} steps, training world {TRAIN_WORLD} "
        f"({' + '.join(TRAIN_CLIMATES)}, 2 trajectories each, supersample {supersample})",
        "init": None if a.init is None else str(a.init),
        "steps": a.steps,
        "seeds": a.seeds,
        "test_worlds": a.test_worlds,
        "test_frames": a.test_frames,
        "supersample": supersample,
        "policy": "every-frame",
        "reference": reference,
        "summary": summary,
        "acceptance": None,
        "runs": runs,
    }
    report["acceptance"] = acceptance(summary)
    report["acceptance_averaged"] = acceptance(summary, "cosemdepth_t_avg")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    params = {
        k: report[k]
        for k in ("recipe", "init", "steps", "seeds", "test_worlds", "test_frames", "supersample", "policy")
    }
    params.update(variants=a.variants, threads=a.threads, rounds=a.rounds, lr=a.lr)
    write_report(
        a.out.with_suffix(".json"),
        make_report(
            "temporal_semantics",
            params,
            {k: report[k] for k in ("reference", "summary", "acceptance", "acceptance_averaged", "runs")},
            meta=meta,
        ),
    )
    atomic_write_text(a.out.with_suffix(".md"), markdown(report))
    plot(report, a.out.with_suffix(".png"))
    if collectors and all(c.pred for c in collectors.values()):
        write_strip(collectors, a.strip, 7)
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
