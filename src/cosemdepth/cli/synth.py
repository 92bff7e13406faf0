"""``cosemdepth synth``: generate a SynthAir dataset (procedural aerial flights written in the Mid-Air format).

The dataset goes to ``--out DIR`` (see :mod:`cosemdepth.data.synthair.writer` for the layout); its split CSVs go
to ``DIR/splits/{train,val,test}_data/SynthAir/<climate>/traj_XXXX.csv``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..data.synthair.climate import CLIMATES


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output folder (new or empty; or an interrupted "
                        "SynthAir run with the same arguments, which is resumed)")
    parser.add_argument("--trajectories", type=int, default=4, metavar="N", help="trajectories per climate "
                        "(default 4; numbered climate*1000 + i as in Mid-Air: sunny 0, sunset 1, foggy 2, cloudy 3)")
    parser.add_argument("--frames", type=int, default=200, metavar="F", help="25 Hz camera frames per trajectory "
                        "(default 200 = 8 s; the ground truth has 4F samples at 100 Hz and the split CSVs "
                        "floor(F/4) - 1 rows)")
    parser.add_argument("--size", type=int, default=384, metavar="S", help="image width = height in pixels "
                        "(default 384; focal S/2, 90 degree FOV)")
    parser.add_argument("--seed", type=int, default=0, metavar="K", help="world and flight seed (default 0)")
    parser.add_argument("--climates", nargs="+", default=list(CLIMATES), metavar="CLIMATE",
                        help=f"climates to render (default all: {' '.join(CLIMATES)})")
    parser.add_argument("--all-frames", action="store_true", help="render every 25 Hz frame (default: only the "
                        "frames the split CSVs use, 4, 8, 12, ...)")
    parser.add_argument("--supersample", type=int, default=1, choices=(1, 3, 5), help="colour rays per pixel "
                        "per axis (antialiasing; depth and labels always come from the pixel centre)")
    parser.add_argument("--jpeg-quality", type=int, default=98,
                        help="JPEG quality (default 98, 4:4:4 chroma; photo-consistency suffers below about 95)")
    parser.add_argument("--workers", type=int, default=1, help="render processes (default 1)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from ..data.synthair.writer import SynthConfig, generate

    cfg = SynthConfig(
        out=args.out,
        trajectories=args.trajectories,
        frames=args.frames,
        size=args.size,
        seed=args.seed,
        climates=tuple(args.climates),
        all_frames=args.all_frames,
        supersample=args.supersample,
        jpeg_quality=args.jpeg_quality,
        workers=args.workers,
    )
    summary = generate(cfg, progress=not args.no_progress)
    print(json.dumps({k: summary[k] for k in ("root", "frames_rendered", "frames_total", "resumed")}))
    print(f"split CSVs: {Path(args.out) / 'splits'}")
    return 0
