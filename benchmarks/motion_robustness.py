"""Depth under unusual camera motion: hover, yaw in place, slow and fast flight, other frame rates; both streaming
policies, with the shipped weights on held-out SynthAir worlds.

    python benchmarks/motion_robustness.py [--model weights/synthair-cosemdepth] [--seeds 21 77]
        [--data DIR | --cache DIR] [--demo DIR] [--regimes normal hover ...] [--policies every-frame baseline]
        [--min-baseline M] [--max-conditioning C] [--max-log-ratio R] [--min-overlap F] [--threads N]
        [--out benchmarks/results/motion_robustness]

Flights: one sunny trajectory per seed and regime, 128x128 px, 3x supersampled, rendered by ``cosemdepth synth
--motion SPEC --frame-step K`` (:data:`REGIMES`) into ``<cache>/s<seed>-<regime>`` (kept: a later run reuses them);
``--data DIR`` reads already generated ones from ``DIR/s<seed>-<regime>`` instead. The demo flight (``cosemdepth
demo``'s: world 1001, 150 rows) is ``--demo DIR``, by default ``<cache>/s1001-demo`` (generated in cache mode, skipped
when ``--data`` has none).

Every flight is streamed frame by frame (batch 1, the fast engine in float32, reset frames in no metric) under each
policy of :mod:`cosemdepth.inference.policy`; per regime and policy, pooled over the seeds' frames:

* ``abs_rel``, ``delta1``: the paper's metrics over every pixel with ground truth (per-frame means);
* ``valid_abs_rel``, ``valid_delta1``, ``coverage``: over the pixels the output marks valid
  (:class:`~cosemdepth.measures.metrics.ValidDepthMetrics`; coverage = valid fraction of the GT pixels of the
  non-reset frames);
* ``frames_by_status`` (estimated / held / reset), ``valid_nonpositive_pixels`` (valid pixels whose depth is <= 0);
* ``too_near_pixels``: GT pixels predicted nearer than :data:`TOO_NEAR` x the ground truth, and ``too_near_removed``,
  the fraction of them the validity mask removes.

For the hover and yaw regimes the same figures restricted to the rows inside the hover / yaw segment and to the rows
inside the fly segments of the same flights (``synthair.json`` records the segments; a row joining frames ``K k`` and
``K (k + 1)`` belongs to a segment ``[n0, n0 + N)`` when ``n0 <= K k`` and ``K (k + 1) <= n0 + N``; rows straddling two
segments are in neither). ``acceptance`` checks the calibration targets of docs/motion.md. Writes ``OUT.json``,
``OUT.md`` and ``OUT.png`` (AbsRel per regime and policy).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Callable

import torch

from cosemdepth.bench.harness import command_line, make_report, run_meta, write_report
from cosemdepth.measures.metrics import EPS, EVAL_MAX_DEPTH, DepthMetrics, ValidDepthMetrics
from cosemdepth.output_safety.atomic import atomic_write_bytes, atomic_write_text

ROOT = Path(__file__).resolve().parents[1]

#: Regime -> (``cosemdepth synth --motion`` spec, ``--frame-step``). Every regime flies the normal flight's path (200
#: rendered frames at the normal speed), so that the regimes compare on the same scenes.
REGIMES = {
    "normal": ("fly:200", 4),
    "hover": ("fly:80,hover:40,fly:80", 4),
    "yaw": ("fly:80,yaw:40@90,fly:80", 4),
    "speed0.25": ("fly*0.25:800", 4),
    "speed0.5": ("fly*0.5:400", 4),
    "speed2": ("fly*2:100", 4),
    "rate2": ("fly:200", 2),
    "rate0.5": ("fly:200", 8),
}
#: Regimes with a segment of their own inside fly segments: the segment kind reported separately.
SEGMENT_REGIMES = {"hover": "hover", "yaw": "yaw"}
SIZE = 128
SUPERSAMPLE = 3
CLIMATE = "sunny"
DEFAULT_SEEDS = (21, 77)
POLICY_NAMES = ("every-frame", "baseline")
#: A prediction nearer than this fraction of the ground truth is "too near" (the dangerous error for a drone).
TOO_NEAR = 0.35
DEMO_NAME = "demo"

# Calibration targets (docs/motion.md).
#: (a) hover / yaw rows, baseline policy: valid AbsRel at most this multiple of the fly rows' of the same flights.
STILL_RATIO = 1.5
#: (b) slow flight and doubled frame rate, baseline policy: valid AbsRel at most this multiple of the normal flights'.
SLOW_RATIO = 1.3
SLOW_REGIMES = ("speed0.25", "speed0.5", "rate2")
FAST_REGIMES = ("speed2", "rate0.5")
#: (c) normal flights: relative AbsRel change baseline vs every-frame below this, coverage at least MIN_COVERAGE.
NORMAL_ABSREL_CHANGE = 0.01
MIN_COVERAGE = 0.97
#: (d) demo flight, baseline policy: at least this fraction of the too-near pixels is not valid.
MIN_TOO_NEAR_REMOVED = 0.5
#: (e) the fly rows of the hover and yaw flights (normal flight before and after the still segment): the baseline
#: policy's AbsRel at most this multiple of the every-frame policy's (it must not make normal flight worse).
MAX_FLY_RATIO = 1.01


def segment_kind(segment: str) -> str:
    """``"fly*0.25:200"`` -> ``"fly"``, ``"yaw:40@90"`` -> ``"yaw"``."""
    return segment.split(":", 1)[0].split("*", 1)[0]


def row_kinds(meta: dict) -> Callable[[int], str | None]:
    """The segment kind of each split row ``k`` of a SynthAir set from its ``synthair.json`` (None: straddles)."""
    step = int(meta.get("frame_step", 4))
    segments = (meta.get("motion") or {}).get("segments") or [{"segment": "fly", "frames": [0, meta["frames"]]}]
    spans = [(segment_kind(s["segment"]), int(s["frames"][0]), int(s["frames"][1])) for s in segments]

    def kind(k: int) -> str | None:
        a, b = step * k, step * (k + 1)
        for name, n0, n1 in spans:
            if n0 <= a and b <= n1:
                return name
        return None

    return kind


class Tally:
    """Every figure of one (regime, policy, subset): frames added one step at a time."""

    def __init__(self) -> None:
        self.depth = DepthMetrics()
        self.valid = ValidDepthMetrics()
        self.status: Counter = Counter()
        self.nonpositive_valid = 0
        self.too_near = 0
        self.too_near_removed = 0

    def update(
        self, gt: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor, status: list[str], include: torch.Tensor
    ) -> None:
        """Frames ``[B, 1, H, W]`` (GT, predicted depth, validity), their statuses, ``include [B]`` bool."""
        inc = include.to(torch.bool).cpu()
        for st, i in zip(status, inc.tolist()):
            self.status[st] += int(i)
        if not bool(inc.any()):
            return
        gt, depth, valid = gt[inc].float().cpu(), depth[inc].float().cpu(), valid[inc].cpu()
        self.depth.update(gt, depth)
        self.valid.update(gt, depth, valid)
        self.nonpositive_valid += int((valid & ~(depth > 0)).sum())
        g = gt.clamp(0.0, EVAL_MAX_DEPTH)
        near = (g > EPS) & ~(depth >= TOO_NEAR * g)
        self.too_near += int(near.sum())
        self.too_near_removed += int((near & ~valid).sum())

    def result(self) -> dict:
        d = self.depth.compute()
        v = self.valid.compute()
        return {
            "abs_rel": d["abs_rel"],
            "delta1": d["delta1"],
            "depth_frames": d["depth_frames"],
            "valid_abs_rel": v["valid_abs_rel"],
            "valid_delta1": v["valid_delta1"],
            "coverage": v["coverage"],
            "valid_frames": v["valid_frames"],
            "frames_by_status": {k: int(self.status.get(k, 0)) for k in ("estimated", "held", "reset")},
            "valid_nonpositive_pixels": self.nonpositive_valid,
            "too_near_pixels": self.too_near,
            "too_near_removed": self.too_near_removed / self.too_near if self.too_near else math.nan,
        }


class TallySink:
    """A sink of the evaluation feeding a flight's tallies with the frames the protocol counts (``include``) that have
    depth (a frame of status reset is in no depth figure)."""

    def __init__(self, tallies, include):
        self.tallies, self.include = tallies, include

    def open(self, folder) -> None:
        pass

    def __call__(self, batch) -> None:
        include = self.include(batch)
        include = include & torch.tensor([st != "reset" for st in batch.status], device=include.device)
        self.tallies.update(batch.frame, batch.gt_depth, batch.depth, batch.valid, batch.status, include)

    def close(self) -> dict:
        return {}

    def abort(self) -> None:
        pass


class FlightTallies:
    """Routes the frames of one flight to the tallies of its regime: ``all`` and, for segment regimes, the segment
    kind and ``fly``."""

    def __init__(self, tallies: dict, regime: str, policy: str, kind: Callable[[int], str | None]) -> None:
        self.kind = kind
        self.targets = {"all": tallies.setdefault((regime, policy, "all"), Tally())}
        seg = SEGMENT_REGIMES.get(regime)
        if seg is not None:
            for sub in (seg, "fly"):
                self.targets[sub] = tallies.setdefault((regime, policy, sub), Tally())

    def update(self, frames: torch.Tensor, gt, depth, valid, status, include) -> None:
        self.targets["all"].update(gt, depth, valid, status, include)
        kinds = [self.kind(int(k)) for k in frames.tolist()]
        for sub, tally in self.targets.items():
            if sub == "all":
                continue
            sel = torch.tensor([k == sub for k in kinds])
            if bool(sel.any()):
                idx = sel.nonzero().flatten()
                tally.update(gt[idx], depth[idx], valid[idx], [status[i] for i in idx.tolist()], include.cpu()[idx])


def _ratio(a, b) -> float:
    return a / b if (b and math.isfinite(b) and b > 0 and a is not None and math.isfinite(a)) else math.nan


def acceptance(results: dict) -> dict:
    """The calibration targets (a)-(e) of docs/motion.md from ``results[regime][policy][subset]``."""
    out: dict = {}
    base, every = "baseline", "every-frame"

    def get(regime, policy, subset="all"):
        return results.get(regime, {}).get(policy, {}).get(subset)

    still = {}
    for regime, seg in SEGMENT_REGIMES.items():
        r = {}
        for pol in (base, every):
            s, f = get(regime, pol, seg), get(regime, pol, "fly")
            if s is None or f is None:
                continue
            r[pol] = {
                "segment_valid_abs_rel": s["valid_abs_rel"],
                "fly_valid_abs_rel": f["valid_abs_rel"],
                "ratio": _ratio(s["valid_abs_rel"], f["valid_abs_rel"]),
                "segment_abs_rel": s["abs_rel"],
                "fly_abs_rel": f["abs_rel"],
                "all_pixel_ratio": _ratio(s["abs_rel"], f["abs_rel"]),
                "segment_coverage": s["coverage"],
                "valid_nonpositive_pixels": s["valid_nonpositive_pixels"],
            }
        if base in r:
            r["ok"] = bool(r[base]["valid_nonpositive_pixels"] == 0 and r[base]["ratio"] <= STILL_RATIO)
        if r:
            still[regime] = r
    if still:
        out["a_still"] = {"max_ratio": STILL_RATIO, **still}
    normal = {pol: get("normal", pol) for pol in (base, every)}
    slow = {}
    for regime in SLOW_REGIMES + FAST_REGIMES:
        r = {}
        for pol in (base, every):
            x, n = get(regime, pol), normal[pol]
            if x is None or n is None:
                continue
            r[pol] = {
                "valid_abs_rel": x["valid_abs_rel"],
                "abs_rel": x["abs_rel"],
                "coverage": x["coverage"],
                "valid_ratio": _ratio(x["valid_abs_rel"], n["valid_abs_rel"]),
                "all_pixel_ratio": _ratio(x["abs_rel"], n["abs_rel"]),
            }
        if base in r and regime in SLOW_REGIMES:
            r["ok"] = bool(r[base]["valid_ratio"] <= SLOW_RATIO)
        if r:
            slow[regime] = r
    if slow:
        out["b_speed"] = {
            "max_ratio": SLOW_RATIO,
            "measure": "valid AbsRel, baseline policy, against the normal flights' under the same policy",
            **slow,
        }
    if normal[base] is not None and normal[every] is not None:
        b, e = normal[base], normal[every]
        change = abs(b["abs_rel"] - e["abs_rel"]) / e["abs_rel"]
        out["c_normal"] = {
            "abs_rel_every_frame": e["abs_rel"],
            "abs_rel_baseline": b["abs_rel"],
            "abs_rel_relative_change": change,
            "valid_abs_rel_baseline": b["valid_abs_rel"],
            "coverage_baseline": b["coverage"],
            "coverage_every_frame": e["coverage"],
            "max_change": NORMAL_ABSREL_CHANGE,
            "min_coverage": MIN_COVERAGE,
            "ok": bool(change < NORMAL_ABSREL_CHANGE and b["coverage"] >= MIN_COVERAGE),
        }
    demo = {pol: get(DEMO_NAME, pol) for pol in (base, every)}
    if demo[base] is not None:
        d = {
            pol: {
                "too_near_pixels": x["too_near_pixels"],
                "too_near_removed": x["too_near_removed"],
                "coverage": x["coverage"],
                "abs_rel": x["abs_rel"],
                "valid_abs_rel": x["valid_abs_rel"],
            }
            for pol, x in demo.items()
            if x is not None
        }
        out["d_demo"] = {
            "too_near": TOO_NEAR,
            "min_removed": MIN_TOO_NEAR_REMOVED,
            **d,
            "ok": bool(demo[base]["too_near_removed"] >= MIN_TOO_NEAR_REMOVED),
        }
    fly = {}
    for regime in SEGMENT_REGIMES:
        b, e = get(regime, base, "fly"), get(regime, every, "fly")
        if b is None or e is None:
            continue
        ratio = _ratio(b["abs_rel"], e["abs_rel"])
        fly[regime] = {
            "abs_rel_baseline": b["abs_rel"],
            "abs_rel_every_frame": e["abs_rel"],
            "ratio": ratio,
            "valid_abs_rel_baseline": b["valid_abs_rel"],
            "valid_abs_rel_every_frame": e["valid_abs_rel"],
            "ok": bool(ratio <= MAX_FLY_RATIO),
        }
    if fly:
        out["e_fly"] = {"max_ratio": MAX_FLY_RATIO, **fly}
    for key in ("a_still", "b_speed", "e_fly"):
        if key in out:
            out[key]["ok"] = all(x["ok"] for x in out[key].values() if isinstance(x, dict) and "ok" in x)
    out["all_ok"] = all(v["ok"] for v in out.values())
    return out


# ---------------------------------------------------------------------------------------------------------------
# Flights
# ---------------------------------------------------------------------------------------------------------------


def _complete(folder: Path) -> bool:
    try:
        return bool(json.loads((folder / "synthair.json").read_text()).get("complete"))
    except (OSError, ValueError):
        return False


def synth_argv(out: Path, seed: int, spec: str | None, step: int, frames: int | None = None) -> list[str]:
    argv = [
        "synth",
        "--out",
        str(out),
        "--trajectories",
        "1",
        "--size",
        str(SIZE),
        "--seed",
        str(seed),
        "--climates",
        CLIMATE,
        "--supersample",
        str(SUPERSAMPLE),
        "--frame-step",
        str(step),
        "--no-progress",
    ]
    if spec is not None:
        argv += ["--motion", spec]
    if frames is not None:
        argv += ["--frames", str(frames)]
    return argv


def generate(out: Path, argv: list[str]) -> float:
    """Run ``cosemdepth <argv>`` in a subprocess (the package this interpreter imports); returns its wall seconds."""
    env = dict(os.environ)
    t0 = time.perf_counter()
    print("generating", out, flush=True)
    subprocess.run([sys.executable, "-m", "cosemdepth", *argv], env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def flights(a) -> list[tuple[str, int, Path]]:
    """``(regime, seed, folder)`` of every flight to stream, generating missing ones in cache mode."""
    from cosemdepth.demo import DEFAULT_FRAMES, DEFAULT_SEED

    root = Path(a.data or a.cache)
    todo = [(regime, seed, root / f"s{seed}-{regime}") for regime in a.regimes for seed in a.seeds]
    for regime, seed, folder in todo:
        if not _complete(folder):
            if a.data:
                raise SystemExit(f"motion_robustness: --data {a.data}: {folder} is not a complete SynthAir set")
            spec, step = REGIMES[regime]
            generate(folder, synth_argv(folder, seed, spec, step))
    demo = Path(a.demo) if a.demo else root / f"s{DEFAULT_SEED}-{DEMO_NAME}"
    if not a.no_demo:
        if not _complete(demo) and not a.data and not a.demo:
            generate(demo, synth_argv(demo, DEFAULT_SEED, None, 4, frames=4 * (DEFAULT_FRAMES + 1)))
        if _complete(demo):
            todo.append((DEMO_NAME, DEFAULT_SEED, demo))
        elif a.demo:
            raise SystemExit(f"motion_robustness: --demo {a.demo}: not a complete SynthAir set")
        else:
            print(f"no demo flight in {root}: (d) not measured", flush=True)
    return todo


# ---------------------------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------------------------


def _f(v, spec=".4f") -> str:
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def markdown(report: dict) -> str:
    res = report["results"]
    s = report["settings"]
    m = report["meta"]
    lines = [
        "# Depth under unusual camera motion (both streaming policies)",
        "",
        f"Model {s['model']}, SynthAir seeds {', '.join(map(str, s['seeds']))} ({s['resolution']}x{s['resolution']} "
        f"px, batch {s['batch']}, {s['precision']}), policies: "
        + "; ".join(f"{k}: {json.dumps(v)}" for k, v in s["policies"].items())
        + ".",
        "",
        f"{m['cpu_model']}, {m['threads']} torch threads, torch {m['torch']}, {m['date_utc']}; "
        f"{report['wall_seconds']:.0f} s of streaming. Command: `{m['command']}`.",
        "",
        "| regime | rows | policy | AbsRel | δ1 | valid AbsRel | valid δ1 | coverage | estimated / held / reset "
        "| valid depth <= 0 | too near removed |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for regime, by_pol in res.items():
        subsets = list(next(iter(by_pol.values())).keys())
        for sub in subsets:
            for pol, by_sub in by_pol.items():
                r = by_sub[sub]
                st = r["frames_by_status"]
                lines.append(
                    f"| {regime} | {sub} | {pol} | {_f(r['abs_rel'])} | {_f(r['delta1'], '.3f')} | "
                    f"{_f(r['valid_abs_rel'])} | {_f(r['valid_delta1'], '.3f')} | {_f(r['coverage'], '.3f')} | "
                    f"{st['estimated']} / {st['held']} / {st['reset']} | {r['valid_nonpositive_pixels']} | "
                    f"{_f(r['too_near_removed'], '.3f')} ({r['too_near_pixels']}) |"
                )
    acc = report["acceptance"]
    lines += ["", "Acceptance (docs/motion.md):", ""]
    for key, v in acc.items():
        if isinstance(v, dict):
            lines.append(f"- {key}: {'pass' if v['ok'] else 'FAIL'} — {_acceptance_line(key, v)}")
    lines.append(f"- all: {'pass' if acc.get('all_ok') else 'FAIL'}")
    lines += [
        "",
        "AbsRel and δ1 over every pixel with ground truth (the paper's metrics); valid AbsRel / δ1 over the "
        "pixels marked valid; coverage = valid fraction of the GT pixels of the non-reset frames; too near = "
        f"predicted depth < {TOO_NEAR} x GT (in brackets: how many pixels), removed = the fraction not valid. "
        "Rows: `all` every row of the flights, `hover` / `yaw` the rows inside that segment, `fly` the rows "
        "inside the fly segments of the same flights.",
    ]
    return "\n".join(lines) + "\n"


def _acceptance_line(key: str, v: dict) -> str:
    if key == "a_still":
        return "; ".join(
            f"{r}: valid AbsRel {_f(x['baseline']['segment_valid_abs_rel'])} vs fly {_f(x['baseline']['fly_valid_abs_rel'])}"
            f" = {_f(x['baseline']['ratio'], '.2f')}x (<= {v['max_ratio']}), valid depth <= 0: "
            f"{x['baseline']['valid_nonpositive_pixels']}"
            for r, x in v.items()
            if isinstance(x, dict) and "baseline" in x
        )
    if key == "b_speed":
        return (
            "; ".join(
                f"{r}: {_f(x['baseline']['valid_ratio'], '.2f')}x (all pixels {_f(x['baseline']['all_pixel_ratio'], '.2f')}x;"
                f" every-frame {_f(x.get('every-frame', {}).get('valid_ratio'), '.2f')}x / "
                f"{_f(x.get('every-frame', {}).get('all_pixel_ratio'), '.2f')}x)"
                for r, x in v.items()
                if isinstance(x, dict) and "baseline" in x
            )
            + f" (<= {v['max_ratio']} for "
            f"{', '.join(SLOW_REGIMES)})"
        )
    if key == "c_normal":
        return (
            f"AbsRel change {100 * v['abs_rel_relative_change']:.2f} % (< {100 * v['max_change']:.0f} %), "
            f"coverage {_f(v['coverage_baseline'], '.4f')} (>= {v['min_coverage']})"
        )
    if key == "d_demo":
        return (
            "; ".join(
                f"{p}: {_f(x['too_near_removed'], '.3f')} of {x['too_near_pixels']} too-near pixels removed"
                for p, x in v.items()
                if isinstance(x, dict)
            )
            + f" (>= {v['min_removed']}, baseline)"
        )
    if key == "e_fly":
        return (
            "; ".join(
                f"{r}: fly rows AbsRel {_f(x['abs_rel_baseline'])} (baseline) vs {_f(x['abs_rel_every_frame'])} "
                f"(every-frame) = {_f(x['ratio'], '.3f')}x"
                for r, x in v.items()
                if isinstance(x, dict)
            )
            + f" (<= {v['max_ratio']})"
        )
    return ""


def plot(report: dict, path: Path) -> None:
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = report["results"]
    cols = []
    for regime, by_pol in res.items():
        for sub in next(iter(by_pol.values())):
            if sub == "all" or sub != "fly":
                cols.append((regime, sub))
    labels = [r if s == "all" else f"{r}\n({s} rows)" for r, s in cols]
    pols = list(next(iter(res.values())).keys())
    fig, axes = plt.subplots(2, 1, figsize=(max(8, 0.9 * len(cols) + 2), 7), sharex=True)
    width = 0.8 / max(len(pols), 1)
    for ax, key, title in (
        (axes[0], "abs_rel", "AbsRel, every pixel with ground truth"),
        (axes[1], "valid_abs_rel", "AbsRel over the valid pixels (coverage above the bars)"),
    ):
        for j, pol in enumerate(pols):
            xs = [i + (j - (len(pols) - 1) / 2) * width for i in range(len(cols))]
            vals = [res[r][pol][s][key] for r, s in cols]
            vals = [v if v is not None and math.isfinite(v) else 0.0 for v in vals]
            ax.bar(xs, vals, width, label=pol)
            if key == "valid_abs_rel":
                for x, (r, s), v in zip(xs, cols, vals):
                    ax.text(x, v, f"{100 * res[r][pol][s]['coverage']:.0f}%", ha="center", va="bottom", fontsize=7)
        ax.set_title(title, fontsize=10)
        ax.set_ylabel("AbsRel")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend()
    axes[1].set_xticks(range(len(cols)))
    axes[1].set_xticklabels(labels, fontsize=8)
    s = report["settings"]
    fig.suptitle(f"{s['model']} on SynthAir seeds {', '.join(map(str, s['seeds']))}, {s['resolution']} px", fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


# ---------------------------------------------------------------------------------------------------------------


def to_report(report: dict) -> dict:
    """The JSON written (the benchmark report shape) from the run's ``report`` (what the Markdown reads)."""
    results = {
        "regimes": report["results"],
        "acceptance": report["acceptance"],
        "per_flight": report["per_flight"],
        "flights": report["flights"],
        "wall_seconds": report["wall_seconds"],
    }
    return make_report("motion_robustness", report["settings"], results, meta=report["meta"])


def main(argv=None) -> int:
    from cosemdepth.geometry.validity import MAX_CONDITIONING
    from cosemdepth.inference.policy import MAX_LOG_RATIO, MIN_OVERLAP, POLICIES, StreamPolicy

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(ROOT / "weights" / "synthair-cosemdepth"), help="model folder")
    p.add_argument("--seeds", type=int, nargs="+", default=list(DEFAULT_SEEDS), help="held-out world seeds")
    p.add_argument("--regimes", nargs="+", choices=list(REGIMES), default=list(REGIMES))
    p.add_argument("--data", help="folder of already generated flights s<seed>-<regime> (nothing is generated)")
    p.add_argument(
        "--cache",
        default=str(ROOT / "runs" / "motion_robustness"),
        help="where flights are generated and kept (default runs/motion_robustness)",
    )
    p.add_argument("--demo", help="the demo flight (a SynthAir set; default <data or cache>/s1001-demo)")
    p.add_argument("--no-demo", action="store_true", help="skip the demo flight (criterion d)")
    p.add_argument("--policies", nargs="+", choices=list(POLICIES), default=list(POLICY_NAMES))
    p.add_argument("--min-baseline", type=float, help="metres (default: the model's operating point)")
    p.add_argument("--max-conditioning", type=float, default=MAX_CONDITIONING)
    p.add_argument("--max-log-ratio", type=float, default=MAX_LOG_RATIO)
    p.add_argument("--min-overlap", type=float, default=MIN_OVERLAP)
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument(
        "--out",
        default=str(ROOT / "benchmarks" / "results" / "motion_robustness"),
        help="output path without extension: OUT.json, OUT.md, OUT.png",
    )
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)

    from cosemdepth.checkpoints.model_io import load_model
    from cosemdepth.data import open_dataset
    from cosemdepth.evaluation.evaluator import Evaluator
    from cosemdepth.inference.policy import Streamer, policy_info

    todo = flights(a)
    model = load_model(a.model, mode="fast")
    policies = {
        name: StreamPolicy(
            mode=name,
            min_baseline=a.min_baseline if name == "baseline" else None,
            max_conditioning=a.max_conditioning,
            max_log_ratio=a.max_log_ratio,
            min_overlap=a.min_overlap,
        )
        for name in a.policies
    }
    tallies: dict = {}
    per_flight: dict = {}
    wall = 0.0
    for regime, seed, folder in todo:
        meta = json.loads((folder / "synthair.json").read_text())
        kind = row_kinds(meta)
        ds = open_dataset("synthair", folder, split_dir=folder / "splits", split="test", seq_len=1, size=SIZE)
        for name, policy in policies.items():
            ft = FlightTallies(tallies, regime, name, kind)

            t0 = time.perf_counter()
            ev = Evaluator(model, ds, policy=policy)
            ev.sinks.append(TallySink(ft, ev.include))
            r = ev.run()
            sec = time.perf_counter() - t0
            wall += sec
            m = r.metrics
            per_flight.setdefault(folder.name, {})[name] = {
                **{k: m[k] for k in ("abs_rel", "delta1", "valid_abs_rel", "valid_delta1", "coverage")},
                "frames_by_status": r.info["protocol"]["frames_by_status"],
                "seconds": round(sec, 1),
                "ms_per_frame": r.ms_per_frame,
            }
            print(
                f"{folder.name} {name}: AbsRel {m['abs_rel']:.4f} valid {m['valid_abs_rel']:.4f} coverage "
                f"{m['coverage']:.3f} {r.info['protocol']['frames_by_status']} ({sec:.0f} s)",
                flush=True,
            )
    results: dict = {}
    for (regime, pol, sub), t in tallies.items():
        results.setdefault(regime, {}).setdefault(pol, {})[sub] = t.result()
    report = {
        "benchmark": "motion_robustness",
        "meta": run_meta(
            command=command_line(["benchmarks/motion_robustness.py", *(argv if argv is not None else sys.argv[1:])])
        ),
        "settings": {
            "model": os.path.relpath(a.model, ROOT) if Path(a.model).is_relative_to(ROOT) else a.model,
            "seeds": a.seeds,
            "regimes": {r: {"motion": REGIMES[r][0], "frame_step": REGIMES[r][1]} for r in a.regimes},
            "resolution": SIZE,
            "batch": 1,
            "precision": "float32 (fast engine)",
            "climate": CLIMATE,
            "supersample": SUPERSAMPLE,
            "policies": {n: policy_info(Streamer(model, pol)) for n, pol in policies.items()},
            "operating_point_step_translation_m": (
                model.operating_point.step_translation.to_dict()
                if model.operating_point and model.operating_point.step_translation
                else None
            ),
        },
        "flights": {f.name: str(f) for _, _, f in todo},
        "wall_seconds": round(wall, 1),
        "results": results,
        "per_flight": per_flight,
    }
    report["acceptance"] = acceptance(results)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_report(Path(f"{out}.json"), to_report(report))
    atomic_write_text(Path(f"{out}.md"), markdown(report))
    plot(report, Path(f"{out}.png"))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
