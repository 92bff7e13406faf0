"""Real lenses: depth from SynthAir flights rendered through distorting lenses and undistorted on the fly, against the
same flights rendered as a pinhole; and the per-frame remap's speed and accuracy against OpenCV and grid_sample.

    python benchmarks/undistortion.py [--model weights/synthair-cosemdepth] [--seed 1000] [--cache DIR]
        [--radtan=-0.3,0.1,0.001,-0.0005,0] [--equidistant 0.02,-0.005,0.001,0] [--threads 1]
        [--out benchmarks/results/undistortion]

Flights: ``cosemdepth synth --seed SEED --trajectories 1 --frames 80 --size 128`` (one trajectory per climate, a
world held out from the training worlds), three times: as the pinhole, ``--distortion radtan:...`` (a strong barrel
lens, as a GoPro's: the image corners move 20 % towards the centre) and ``--distortion equidistant:...`` (a fisheye:
the distorted image's corners are 80 degrees off-axis). Every lens flight has the pinhole's intrinsics, poses and
scenes, so the undistorted flight at the model's focal length is the pinhole flight's view. Kept in ``--cache``.

Depth (``results.depth``): the shipped model on the test split of each flight, the paper's protocol (every-frame,
reset frames left out), streamed at the model's focal length (64 px: 128x128):

* ``pinhole``; ``<lens>``: undistorted with the calibration file ``synth`` wrote (canvas ``same``: the pinhole of the
  calibration's focal length); ``<lens>_ignored``: the distorted images read as if they were the pinhole's;
* ``radtan_full_edge`` / ``radtan_full_black``: the undistorted canvas widened to the whole source image
  (``canvas="full"``), where the pixels without a source are fed edge-replicated or black (the choice of
  ``Undistorter``'s default fill); ``centre_128_abs_rel``: AbsRel inside its central 128x128 pixels, the view of
  the default canvas (the periphery's share of the difference);
* per entry: ``abs_rel``, ``rmse``, ``delta1`` over the pixels with ground truth (0 where no source pixel exists),
  ``valid_abs_rel`` and ``coverage`` over the pixels marked valid, ``target_valid_fraction`` (target pixels with a
  source) and ``source_coverage`` (share of the distorted image the target shows: 1 - the coverage lost at the
  border), and ``abs_rel_vs_pinhole`` (relative difference to the pinhole's AbsRel; the acceptance is 5 %).

Remap (``results.remap``): one 1920x1080 GoPro-like frame (radtan, fx 880) undistorted to the 384 px model's focal
length (192 px: 419x236) and to the full size, per frame, one thread: this package's ``Undistorter`` (``grid_sample`` at
source positions computed in float64), ``torch.nn.functional.grid_sample`` on the float image (what kornia's
``remap`` runs) with a grid built in float32, a gather of the 4 taps from the uint8 image (the first implementation),
``cv2.remap`` with float maps and with 16-bit fixed-point maps; each against a float64 reference
(float64 source positions, float64 bilinear): max and mean absolute error in 8-bit levels.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from cosemdepth.bench.harness import make_report, run_meta, summarize, time_calls, write_report

ROOT = Path(__file__).resolve().parents[1]
FLIGHT = ["--trajectories", "1", "--frames", "80", "--size", "128"]


def synth(out: Path, seed: int, distortion: str | None) -> Path:
    if (out / "synthair.json").is_file() and '"complete": true' in (out / "synthair.json").read_text():
        return out
    cmd = [sys.executable, "-m", "cosemdepth", "synth", "--out", str(out), "--seed", str(seed), *FLIGHT]
    cmd += ["--no-progress"] + (["--distortion", distortion] if distortion else [])
    subprocess.run(cmd, check=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    return out


def depth_entry(model, root: Path, *, calibration=None, canvas: str = "same", fill: str = "edge") -> dict:
    from cosemdepth.camera import UndistortedFrames, Undistorter, load_calibration
    from cosemdepth.data import open_dataset
    from cosemdepth.data.frames import FocalSize
    from cosemdepth.evaluation.evaluator import evaluate

    focal = FocalSize(float(model.operating_point.focal))
    kw = {} if calibration is None else {"calibration": calibration}
    ds = open_dataset("synthair", root, split="test", seq_len=1, size=focal, **kw)
    info = getattr(ds, "calibration", None)
    if calibration and (canvas != "same" or fill != "edge"):
        und = Undistorter(load_calibration(calibration), focal_px=focal.focal_px, canvas=canvas, fill=fill)
        ds.load_frame = UndistortedFrames(ds.load_frame.inner, und)
        ds.intrinsics = und.intrinsics
        info = und.info()
    callbacks, centre = [], None
    if canvas == "full":  # the same canvas's view inside the full one: separates the periphery from the rest
        from cosemdepth.measures.metrics import DepthMetrics

        centre = DepthMetrics()
        (h, w), (ch, cw) = ds.load_frame.size, (128, 128)
        top, left = (h - ch) // 2, (w - cw) // 2
        crop = (slice(None), slice(None), slice(top, top + ch), slice(left, left + cw))
        callbacks.append(lambda b, inc: centre.update(b.gt_depth[crop], b.depth[crop], inc))
    t0 = time.perf_counter()
    m = evaluate(model, ds, progress=False, callbacks=callbacks).metrics
    out = {k: m.get(k) for k in ("abs_rel", "rmse", "delta1", "valid_abs_rel", "coverage", "depth_frames")}
    if centre is not None:
        out["centre_128_abs_rel"] = centre.compute()["abs_rel"]
    out["seconds"] = round(time.perf_counter() - t0, 1)
    out["size"] = list(ds.load_frame.size) if hasattr(ds.load_frame, "size") else None
    out["target_valid_fraction"] = None if info is None else info["valid_fraction"]
    out["source_coverage"] = None if info is None else info["source_coverage"]
    return out


def remap_comparison(iters: int) -> dict:
    import cv2

    from cosemdepth.camera import Calibration, Undistorter

    cal = Calibration((1080, 1920), 880.0, 880.0, 962.5, 541.0, model="radtan", coefficients=(-0.26, 0.07, 0, 0, 0.0))
    img = np.random.default_rng(0).integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    # a smooth image too: random pixels are the worst case for the interpolation weights' precision
    yy, xx = np.mgrid[0:1080, 0:1920]
    smooth = (127.5 + 120 * np.sin(xx / 37.0) * np.cos(yy / 23.0))[..., None].repeat(3, 2).astype(np.uint8)
    out = {}
    for name, kw in (("to_192px_focal", {"focal_px": 192.0}), ("full_size", {})):
        und = Undistorter(cal, **kw)
        ho, wo = und.size
        fx, fy, cx, cy = und.k
        rows = (torch.arange(ho, dtype=torch.float64) + 0.5 - cy) / fy
        cols = (torch.arange(wo, dtype=torch.float64) + 0.5 - cx) / fx
        from cosemdepth.camera.distortion import distort

        xy = torch.stack(torch.meshgrid(cols, rows, indexing="xy"), -1)
        uv = cal.project(distort(cal.model, xy, cal.coefficients))
        mx, my = (uv[..., 0] - 0.5).numpy(), (uv[..., 1] - 0.5).numpy()  # float64 source index coordinates

        def reference(image):
            a, b = np.clip(mx, 0, 1919), np.clip(my, 0, 1079)
            x0, y0 = np.floor(a).astype(int), np.floor(b).astype(int)
            x1, y1 = np.minimum(x0 + 1, 1919), np.minimum(y0 + 1, 1079)
            wx, wy = (a - x0)[..., None], (b - y0)[..., None]
            f = image.astype(np.float64)
            return (f[y0, x0] * (1 - wx) + f[y0, x1] * wx) * (1 - wy) + (f[y1, x0] * (1 - wx) + f[y1, x1] * wx) * wy

        m1, m2 = mx.astype(np.float32), my.astype(np.float32)
        f1, f2 = cv2.convertMaps(m1, m2, cv2.CV_16SC2)
        grid = torch.from_numpy(np.stack([(mx + 0.5) / 1920 * 2 - 1, (my + 0.5) / 1080 * 2 - 1], -1)).float()[None]
        # the alternative the package measured and left: gather the 4 taps from the uint8 image (float64-built taps)
        a, b = np.clip(mx, 0, 1919), np.clip(my, 0, 1079)
        x0, y0 = np.floor(a).astype(np.int64), np.floor(b).astype(np.int64)
        wx = torch.from_numpy((a - x0).reshape(-1, 1)).float()
        wy = torch.from_numpy((b - y0).reshape(-1, 1)).float()
        i00 = torch.from_numpy((y0 * 1920 + x0).reshape(-1))
        dx = torch.from_numpy((np.minimum(x0 + 1, 1919) - x0).reshape(-1))
        dy = torch.from_numpy(((np.minimum(y0 + 1, 1079) - y0) * 1920).reshape(-1))
        taps = torch.cat([i00, i00 + dx, i00 + dy, i00 + dy + dx])

        def gather(im):
            t = torch.from_numpy(im).reshape(-1, 3).index_select(0, taps).float()
            n = i00.numel()
            top = t[:n] + (t[n : 2 * n] - t[:n]) * wx
            bottom = t[2 * n : 3 * n] + (t[3 * n :] - t[2 * n : 3 * n]) * wx
            return (top + (bottom - top) * wy).reshape(ho, wo, 3).numpy()

        methods = {
            "cosemdepth_undistorter": lambda im: und(im)[0].permute(1, 2, 0).numpy() * 255,
            "uint8_gather": gather,
            "torch_grid_sample": lambda im: (
                torch.nn.functional.grid_sample(
                    torch.from_numpy(im).permute(2, 0, 1)[None].float(),
                    grid,
                    align_corners=False,
                    padding_mode="border",
                )[0]
                .permute(1, 2, 0)
                .numpy()
            ),
            "cv2_remap_float_maps_u8": lambda im: cv2.remap(
                im, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            ).astype(np.float64),
            "cv2_remap_fixed_point_maps_u8": lambda im: cv2.remap(
                im, f1, f2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            ).astype(np.float64),
            "cv2_remap_float_image": lambda im: cv2.remap(
                im.astype(np.float32), m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            ).astype(np.float64),
        }
        entry = {"source": [1080, 1920], "target": [ho, wo]}
        for key, fn in methods.items():
            errs = {}
            for label, image in (("random", img), ("smooth", smooth)):
                e = np.abs(fn(image) - reference(image))
                errs[label] = {"max_levels": round(float(e.max()), 4), "mean_levels": round(float(e.mean()), 5)}
            times = time_calls(lambda: fn(img), warmup=1, iters=iters)
            entry[key] = {"ms": summarize(times, 1e3, 2), "error": errs}
        build = time_calls(lambda: Undistorter(cal, **kw), warmup=0, iters=1)
        entry["undistorter_build_ms"] = round(build[0] * 1e3, 1)
        out[name] = entry
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=ROOT / "weights" / "synthair-cosemdepth")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--cache", type=Path, default=ROOT / "data" / "undistortion")
    ap.add_argument("--radtan", default="-0.3,0.1,0.001,-0.0005,0")
    ap.add_argument("--equidistant", default="0.02,-0.005,0.001,0")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--skip-depth", action="store_true", help="only the remap comparison")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "undistortion")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    meta = run_meta()
    results: dict = {"remap": remap_comparison(args.iters)}
    if not args.skip_depth:
        from cosemdepth import load_model

        model = load_model(args.model)
        flights = {
            "pinhole": synth(args.cache / f"s{args.seed}-pinhole", args.seed, None),
            "radtan": synth(args.cache / f"s{args.seed}-radtan", args.seed, f"radtan:{args.radtan}"),
            "equidistant": synth(
                args.cache / f"s{args.seed}-equidistant", args.seed, f"equidistant:{args.equidistant}"
            ),
        }
        depth = {"pinhole": depth_entry(model, flights["pinhole"])}
        for lens in ("radtan", "equidistant"):
            cal = flights[lens] / "calibration" / "camera_info.yaml"
            depth[lens] = depth_entry(model, flights[lens], calibration=cal)
            depth[f"{lens}_ignored"] = depth_entry(model, flights[lens], calibration=False)
        cal = flights["radtan"] / "calibration" / "camera_info.yaml"
        for fill in ("edge", "black"):
            depth[f"radtan_full_{fill}"] = depth_entry(
                model, flights["radtan"], calibration=cal, canvas="full", fill=fill
            )
        base = depth["pinhole"]["abs_rel"]
        for v in depth.values():
            v["abs_rel_vs_pinhole"] = None if base is None else round(v["abs_rel"] / base - 1, 4)
        results["depth"] = depth
        results["acceptance"] = {
            lens: bool(abs(depth[lens]["abs_rel_vs_pinhole"]) <= 0.05) for lens in ("radtan", "equidistant")
        }
    params = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    params["flight"] = " ".join(FLIGHT)
    report = make_report("undistortion", params, results, meta=meta)
    write_report(args.out.with_suffix(".json"), report)
    print(f"wrote {args.out.with_suffix('.json')}")
    if "depth" in results:
        for k, v in results["depth"].items():
            print(f"{k:>20}: AbsRel {v['abs_rel']:.4f} ({100 * v['abs_rel_vs_pinhole']:+.1f} %), valid AbsRel "
                  f"{v['valid_abs_rel']:.4f}, coverage {v['coverage']:.3f}, source shown {v['source_coverage']}")  # fmt: skip
    return 0 if all(results.get("acceptance", {}).values()) else 1


if __name__ == "__main__":
    sys.exit(main())
