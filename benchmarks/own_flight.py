"""Your own drone, end to end: the same SynthAir flight as images + poses and as a video + the flight controller's
log (PX4 ULog, ArduPilot DataFlash, MAVLink tlog, DJI SRT), clocks that disagree, cameras on other mounts.

    python benchmarks/own_flight.py [--model weights/synthair-cosemdepth] [--seed 1021] [--cache runs/own_flight]
        [--flights forward pitch30 down] [--threads N] [--out benchmarks/results/own_flight]

Flights (:data:`FLIGHTS`): one sunny trajectory of world ``--seed`` (held out: the shipped weights were trained on
worlds 11-17), 128x128 px, :data:`FRAMES` frames, exported by ``cosemdepth synth --export ...
--time-offset 12.37``: the video starts 12.37 s into the flight and its logs (a quarter of a frame off the 25 Hz
grid), with the camera looking forward, pitched down 30 degrees (``--camera-mount 0,-30,0``) or straight down
(``down``). Generated into ``<cache>/<flight>`` and kept.

Ground truth: the video's frames are not frames of the Mid-Air layout (they sit 0.01 s after them), so the depth of
every video frame is rendered here by SynthAir's renderer at the camera pose ``truth.csv`` records for it (the pose
the video frame was rendered from; depth comes from the pixel-centre ray whatever the supersampling).

Routes, each a ``cosemdepth predict`` run (baseline policy, the model's defaults, batch 1, float32 fast path):

* ``images``: the video's frames as the video reader decodes them, written to PNG, with the optical frame's poses
  from ``truth.csv`` (TUM, ``--convention opencv``, ``--match order``): the reference, on the very same pixels;
* ``<log>``: ``--images video.mp4 --log flight.<ext> --time-offset auto`` (and ``--camera-mount`` for the mounted
  cameras); ``ulog+0.04`` etc.: the ULog with the true offset plus 0.04 s, 0.2 s, 1 s (the cost of a wrong clock);
* ``srt``: the DJI subtitles (positions from latitude/longitude printed to 6 decimals, 0.11 m; the camera's attitude
  from the gimbal angles); ``srt-1e-5``: the same file with latitude/longitude rounded to 5 decimals (1.1 m, the
  resolution of older models' once-a-second lines, about a GPS receiver's noise).

Metrics (:mod:`cosemdepth.measures.metrics`, the test protocol): AbsRel and delta1 over the pixels with ground truth
(up to 80 m), whatever the mask, of the frames that are resets neither in the route nor in the images route
(``paired``: the route's and the images route's figures on the same decoded frames), and over the pixels the route
marks valid (``valid_abs_rel``, ``coverage``). ``acceptance``: the estimated offsets within one frame of the truth;
AbsRel of the video routes with the clock found (``--time-offset auto``) within 3 % (relative) of the images route;
for the subtitles, no frame (estimated or held) whose baseline from its reference is below the positions' resolution
has a valid pixel. Writes ``OUT.json`` and ``OUT.md``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from cosemdepth.bench.harness import command_line, make_report, run_meta, write_report
from cosemdepth.data.video import open_video
from cosemdepth.measures.metrics import DepthMetrics, ValidDepthMetrics
from cosemdepth.output_safety.atomic import atomic_path, atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
SIZE, SUPERSAMPLE, CLIMATE = 128, 1, "sunny"
FRAMES = 560  # 22.4 s of flight: the video covers its last 10 s
TIME_OFFSET = 12.37
HFOV = 90.0
#: Flight -> (camera mount, exported formats).
FLIGHTS = {
    "forward": ("forward", "mp4,ulog,dataflash,tlog,srt"),
    "pitch30": ("0,-30,0", "mp4,ulog"),
    "down": ("down", "mp4,ulog"),
}
#: Log routes: name -> file of the export folder.
LOGS = {"ulog": "flight.ulg", "dataflash": "flight.bin", "tlog": "flight.tlog", "srt": "video.SRT"}
#: The subtitles again, latitude/longitude rounded to this many decimals (route ``srt-1e-5``).
COARSE_SRT_DECIMALS = 5
#: Offsets off the truth (seconds) run with the ULog.
OFFSET_ERRORS = (0.04, 0.2, 1.0)
#: Acceptance: relative AbsRel difference to the images route at most this.
MAX_RELATIVE = 0.03


def sh(cmd: list[str], log: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run a command, its output to ``log``; stop with its last lines on failure."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    log.write_text(f"$ {' '.join(cmd)}\n{done.stdout}{done.stderr}[{time.perf_counter() - t0:.1f} s]\n")
    if done.returncode != 0:
        sys.exit(f"failed ({done.returncode}): {' '.join(cmd)}\n{(done.stdout + done.stderr)[-3000:]}")
    return done


def export_folder(root: Path) -> Path:
    found = sorted(root.glob(f"SynthAir/{CLIMATE}/flight_export/trajectory_*"))
    if not found:
        sys.exit(f"{root}: no flight export")
    return found[0]


def generate(cache: Path, name: str, seed: int, env: dict) -> Path:
    mount, formats = FLIGHTS[name]
    root = cache / name
    cmd = [sys.executable, "-m", "cosemdepth", "synth", "--out", str(root), "--trajectories", "1"]
    cmd += ["--climates", CLIMATE, "--frames", str(FRAMES), "--size", str(SIZE), "--supersample", str(SUPERSAMPLE)]
    cmd += ["--seed", str(seed), "--camera-mount", mount, "--export", formats, "--time-offset", str(TIME_OFFSET)]
    exported = sorted(root.glob(f"SynthAir/{CLIMATE}/flight_export/trajectory_*/truth.csv"))
    if not ((root / "synthair.json").is_file() and exported):
        print(f"generating {name} ...", flush=True)
        cache.mkdir(parents=True, exist_ok=True)
        sh([*cmd, "--no-progress"], cache / f"{name}.synth.log", env)
    return export_folder(root)


def read_truth(folder: Path) -> list[dict]:
    with open(folder / "truth.csv", newline="") as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def render_ground_truth(folder: Path, truth: list[dict], seed: int) -> np.ndarray:
    """``[N, H, W]`` float32 z-depth of every video frame (cached in ``gt_depth.npy``)."""
    path = folder / "gt_depth.npy"
    if path.is_file():
        return np.load(path)
    from cosemdepth.geometry.mount import optical_to_camera_frd
    from cosemdepth.synthair.climate import get_climate
    from cosemdepth.synthair.render import SKY_DEPTH, render_frames
    from cosemdepth.synthair.world import get_world

    world = get_world(seed)
    q = np.array([[r["camera_qw"], r["camera_qx"], r["camera_qy"], r["camera_qz"]] for r in truth])
    p = np.array([[r["camera_x"], r["camera_y"], r["camera_z"]] for r in truth])
    att = optical_to_camera_frd(q)
    out = []
    for c in range(0, len(truth), 16):
        frames = render_frames(world, get_climate(CLIMATE), att[c : c + 16], p[c : c + 16], SIZE, SIZE, 1)
        out += [f.depth for f in frames]
    depth = np.stack(out).astype(np.float32)
    depth[depth >= SKY_DEPTH] = 0.0  # the sky: no ground truth (beyond the metrics' 80 m anyway)
    with atomic_path(path) as tmp:
        np.save(tmp, depth)
    return depth


def images_route(folder: Path, truth: list[dict]) -> tuple[Path, Path]:
    """The video's decoded frames as PNGs (``frames/000042.png``) and the optical frame's poses (TUM)."""
    images = folder / "frames"
    poses = folder / "poses_optical.txt"
    if not poses.is_file():
        images.mkdir(exist_ok=True)
        for index, _, rgb in open_video(folder / "video.mp4").frames():
            Image.fromarray(rgb).save(images / f"{index:06d}.png")
        lines = ["# video time, optical frame position (NED) and quaternion (x, y, z, w): camera-to-world"]
        for r in truth:
            lines.append(
                f"{r['video_time_s']:.6f} {r['camera_x']:.9f} {r['camera_y']:.9f} {r['camera_z']:.9f} "
                f"{r['camera_qx']:.12f} {r['camera_qy']:.12f} {r['camera_qz']:.12f} {r['camera_qw']:.12f}"
            )
        atomic_write_text(poses, "\n".join(lines) + "\n")
    return images, poses


def coarse_srt(folder: Path, decimals: int = COARSE_SRT_DECIMALS) -> Path:
    """``video.SRT`` with its latitudes and longitudes rounded to ``decimals`` decimals (``video_1e-5.SRT``)."""
    path = folder / f"video_1e-{decimals}.SRT"
    if not path.is_file():
        text = (folder / LOGS["srt"]).read_text(encoding="utf-8")
        text = re.sub(
            r"\[(latitude|longitude|longtitude)\s*:\s*([-+0-9.]+)\]",
            lambda m: f"[{m.group(1)}: {float(m.group(2)):.{decimals}f}]",
            text,
        )
        atomic_write_text(path, text)
    return path


def predict(model: Path, out: Path, source: list[str], threads: int, env: dict) -> tuple[dict, str]:
    cmd = [sys.executable, "-m", "cosemdepth", "predict", "--model", str(model), "--flight", *source]
    cmd += ["--hfov", str(HFOV), "--out", str(out), "--video", "none", "--threads", str(threads), "--no-progress"]
    done = sh(cmd, out.parent / f"{out.name}.log", env)
    return json.loads((out / "predictions.json").read_text()), done.stdout.strip()


def stem(record: dict) -> int:
    return int(Path(record["files"]["depth"]).stem)


def route_metrics(out: Path, manifest: dict, gt: np.ndarray, include: set[int]) -> dict:
    depth, valid = DepthMetrics(), ValidDepthMetrics()
    for rec in manifest["frames"]:
        k = stem(rec)
        if k not in include:
            continue
        pred = torch.from_numpy(np.load(out / rec["files"]["depth"]).astype(np.float32))[None, None]
        ok = torch.from_numpy(np.array(Image.open(out / rec["files"]["depth_valid"])) > 0)[None, None]
        g = torch.from_numpy(gt[k])[None, None]
        depth.update(g, pred)
        valid.update(g, pred, ok)
    d, v = depth.compute(), valid.compute()
    return {
        "abs_rel": d["abs_rel"],
        "delta1": d["delta1"],
        "frames": d["depth_frames"],
        "valid_abs_rel": v["valid_abs_rel"],
        "coverage": v["coverage"],
    }


def statuses(manifest: dict) -> dict[int, str]:
    return {stem(r): r.get("status", "estimated") for r in manifest["frames"]}


def run_flight(name: str, args, env: dict) -> dict:
    folder = generate(args.cache, name, args.seed, env)
    truth = read_truth(folder)
    true_offset = truth[0]["log_time_s"]
    gt = render_ground_truth(folder, truth, args.seed)
    images, poses = images_route(folder, truth)
    mount = FLIGHTS[name][0]
    routes: dict[str, list[str]] = {
        "images": ["--images", str(images), "--poses", str(poses), "--convention", "opencv", "--match", "order"]
    }
    video = ["--images", str(folder / "video.mp4")]
    mount_args = [] if mount == "forward" else ["--camera-mount", mount]
    for log, file in LOGS.items():
        if (folder / file).is_file():
            routes[log] = [*video, "--log", str(folder / file), "--time-offset", "auto", *mount_args]
    if name == "forward":
        routes[f"srt-1e-{COARSE_SRT_DECIMALS}"] = [*video, "--log", str(coarse_srt(folder)), "--time-offset", "auto"]
        for err in OFFSET_ERRORS:
            given = ["--time-offset", f"{true_offset + err:.6f}"]
            routes[f"ulog+{err:g}"] = [*video, "--log", str(folder / LOGS["ulog"]), *given]
    runs: dict[str, dict] = {}
    outs = args.cache / f"{name}-predict"
    outs.mkdir(parents=True, exist_ok=True)
    for route, source in routes.items():
        print(f"{name}: {route} ...", flush=True)
        t0 = time.perf_counter()
        manifest, printed = predict(args.model, outs / route, [*source], args.threads, env)
        runs[route] = {"manifest": manifest, "printed": printed, "seconds": round(time.perf_counter() - t0, 1)}
    kept = {route: {k for k, s in statuses(r["manifest"]).items() if s != "reset"} for route, r in runs.items()}
    result: dict = {
        "export": str(folder.relative_to(args.cache)),
        "camera_mount": mount,
        "video_frames": len(truth),
        "true_offset_s": true_offset,
        "routes": {},
    }
    frame_s = float(truth[1]["video_time_s"] - truth[0]["video_time_s"])
    for route, r in runs.items():
        m = r["manifest"]
        st = statuses(m)
        paired = kept["images"] & kept[route]
        entry = {
            "paired": route_metrics(outs / route, m, gt, paired),
            "images_paired": route_metrics(outs / "images", runs["images"]["manifest"], gt, paired),
            "own": route_metrics(outs / route, m, gt, kept[route]),
            "frames_by_status": {s: sum(1 for v in st.values() if v == s) for s in ("estimated", "held", "reset")},
            "printed": r["printed"].splitlines(),
            "seconds": r["seconds"],
        }
        run = m.get("run", {})
        if route != "images":
            offset = run.get("time_offset_s")
            # the subtitles are on the video's clock: their true offset is the first frame's video time
            truth_s = truth[0]["video_time_s"] if route.startswith("srt") else true_offset
            entry.update(
                time_offset_s=offset,
                offset_error_s=None if offset is None else offset - truth_s,
                offset_error_frames=None if offset is None else (offset - truth_s) / frame_s,
                time_offset_confidence=run.get("time_offset_confidence"),
                time_offset=(m.get("dataset") or {}).get("time_offset"),
            )
        if route.startswith("srt"):
            entry["srt_validity"] = srt_validity(m)
        entry["abs_rel_relative_to_images"] = entry["paired"]["abs_rel"] / entry["images_paired"]["abs_rel"] - 1.0
        result["routes"][route] = entry
    return result


def srt_validity(manifest: dict) -> dict:
    """The frames against the positions' resolution (``dataset.log.position_resolution_m``): how many have a
    baseline from their reference below it, and how many of those have a valid pixel (none may)."""
    res = float(((manifest.get("dataset") or {}).get("log") or {}).get("position_resolution_m") or 0.0)
    frames = [r for r in manifest["frames"] if r.get("status") != "reset"]
    short = [r for r in frames if r.get("baseline_m", 0.0) < res]
    estimated = [r for r in frames if r.get("status") == "estimated"]
    return {
        "position_resolution_m": res,
        "min_baseline_m": (manifest.get("policy") or {}).get("min_baseline_m"),
        "frames_below_resolution": {s: sum(1 for r in short if r["status"] == s) for s in ("estimated", "held")},
        "frames_below_resolution_with_valid_pixels": sum(1 for r in short if r.get("valid_fraction", 0) > 0),
        "min_estimated_baseline_m": min((r["baseline_m"] for r in estimated), default=None),
        "frames_with_valid_pixels": sum(1 for r in frames if r.get("valid_fraction", 0) > 0),
    }


def acceptance(results: dict) -> dict:
    """Per flight and route: the clock within one frame and AbsRel within :data:`MAX_RELATIVE` of the images route
    (the logs with ``--time-offset auto``); the subtitles: no frame below the positions' resolution valid."""
    out: dict = {}
    for name, flight in results.items():
        checks = {}
        for route, e in flight["routes"].items():
            if route == "images" or "+" in route:
                continue
            c: dict = {}
            if route.startswith("srt"):
                c["srt_ok"] = e["srt_validity"]["frames_below_resolution_with_valid_pixels"] == 0
            else:
                c["abs_rel_relative_to_images"] = e["abs_rel_relative_to_images"]
                c["abs_rel_ok"] = abs(e["abs_rel_relative_to_images"]) <= MAX_RELATIVE
                c["offset_error_frames"] = e["offset_error_frames"]
                c["offset_ok"] = e["offset_error_frames"] is not None and abs(e["offset_error_frames"]) <= 1.0
            checks[route] = c
        out[name] = checks
    out["all_ok"] = all(v for f in out.values() for c in f.values() for k, v in c.items() if k.endswith("_ok"))
    return out


def markdown(results: dict, meta: dict, params: dict) -> str:
    load = meta.get("loadavg")
    lines = [
        "# Own flights: images + poses against video + log (benchmarks/own_flight.py)",
        "",
        f"`{meta.get('command')}`: {meta.get('cpu_model')} ({meta.get('cpu_count')} cores"
        + (f", load average {load[0]:.1f}" if load else "")
        + f"), {params['threads']} threads, {meta.get('date_utc')}; model {params['model']}; SynthAir world "
        f"{params['seed']}, {params['size']}x{params['size']} px, batch 1, float32, baseline policy; the video starts "
        f"{params['time_offset_s']} s into the flight.",
        "",
        "AbsRel over the frames that are resets neither in the route nor in the images route (the same decoded "
        "frames), every pixel with ground truth; valid AbsRel and coverage over the pixels the route marks valid.",
        "",
        "| flight | route | offset used - truth | confidence | frames | AbsRel | AbsRel images | vs images | "
        "valid AbsRel | coverage | estimated / held / reset |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for name, flight in results.items():
        for route, e in flight["routes"].items():
            err, err_f = e.get("offset_error_s"), e.get("offset_error_frames")
            conf = e.get("time_offset_confidence")
            fs = e["frames_by_status"]
            lines.append(
                f"| {name} | {route} | {'' if err is None else f'{1000 * err:+.1f} ms ({err_f:+.2f} frames)'} | "
                f"{'' if conf is None else f'{conf:.2f}'} | {e['paired']['frames']} | {e['paired']['abs_rel']:.4f} | "
                f"{e['images_paired']['abs_rel']:.4f} | {100 * e['abs_rel_relative_to_images']:+.2f} % | "
                f"{e['paired']['valid_abs_rel']:.4f} | {100 * e['paired']['coverage']:.1f} % | "
                f"{fs['estimated']} / {fs['held']} / {fs['reset']} |"
            )
    lines += [
        "",
        "DJI subtitles: frames (not resets) whose baseline from their reference frame is below the positions' "
        "resolution, and those of them with a valid pixel (none may).",
        "",
        "| route | resolution | min baseline (policy) | below resolution: estimated / held | of them valid | "
        "shortest estimated baseline | frames with valid pixels |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, flight in results.items():
        for route, e in flight["routes"].items():
            v = e.get("srt_validity")
            if v:
                below = v["frames_below_resolution"]
                lines.append(
                    f"| {route} | {v['position_resolution_m']:.3f} m | {v['min_baseline_m']:.3f} m | "
                    f"{below['estimated']} / {below['held']} | {v['frames_below_resolution_with_valid_pixels']} | "
                    f"{v['min_estimated_baseline_m']:.3f} m | {v['frames_with_valid_pixels']} |"
                )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", type=Path, default=ROOT / "weights" / "synthair-cosemdepth")
    ap.add_argument("--seed", type=int, default=1021)
    ap.add_argument("--cache", type=Path, default=ROOT / "runs" / "own_flight")
    ap.add_argument("--flights", nargs="+", choices=tuple(FLIGHTS), default=list(FLIGHTS))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "own_flight")
    args = ap.parse_args(argv)
    args.cache = args.cache.resolve()
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads)}
    meta = run_meta(command=command_line())
    results = {name: run_flight(name, args, env) for name in args.flights}
    params = {
        "model": str(args.model.relative_to(ROOT)) if args.model.is_relative_to(ROOT) else str(args.model),
        "seed": args.seed,
        "flights": {n: {"camera_mount": FLIGHTS[n][0], "export": FLIGHTS[n][1]} for n in args.flights},
        "frames": FRAMES,
        "time_offset_s": TIME_OFFSET,
        "size": SIZE,
        "supersample": SUPERSAMPLE,
        "climate": CLIMATE,
        "hfov": HFOV,
        "offset_errors_s": list(OFFSET_ERRORS),
        "coarse_srt_decimals": COARSE_SRT_DECIMALS,
        "threads": args.threads,
    }
    report = make_report("own_flight", params, results, meta=meta, acceptance=acceptance(results))
    write_report(args.out.with_suffix(".json"), report)
    atomic_write_text(args.out.with_suffix(".md"), markdown(results, meta, params))
    print(json.dumps(report["acceptance"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
