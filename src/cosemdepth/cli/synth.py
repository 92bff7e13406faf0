"""``cosemdepth synth``: generate a SynthAir dataset (procedural aerial flights written in the Mid-Air format).

The dataset goes to ``--out DIR`` (see :mod:`cosemdepth.synthair.writer` for the layout); its split CSVs go
to ``DIR/splits/{train,val,test}_data/SynthAir/<climate>/traj_XXXX.csv``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..errors import ConfigError
from ..synthair.export import parse_export
from ..synthair.motion import DEFAULT_YAW, GRAMMAR
from ..synthair.writer import SUPERSAMPLES, SynthConfig, generate

#: The generator's defaults (the flags read them: one home for defaults).
DEFAULTS = SynthConfig(out=Path("."))


class _Given(argparse.Action):
    """Store the value and note that the flag was given (``--frames`` must then agree with ``--motion``)."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        setattr(namespace, f"{self.dest}_given", True)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        required=True,
        type=Path,
        help="output folder (new or empty; or an interrupted SynthAir run with the same arguments, which is resumed)",
    )
    d = DEFAULTS
    parser.add_argument(
        "--trajectories",
        type=int,
        default=d.trajectories,
        metavar="N",
        help="trajectories per "
        f"climate (default {d.trajectories}; numbered climate*1000 + i as in Mid-Air: sunny 0, sunset 1, foggy 2, cloudy 3)",
    )
    parser.add_argument(
        "--frames",
        type=int,
        default=d.frames,
        action=_Given,
        metavar="F",
        help="25 Hz camera "
        f"frames per trajectory (default {d.frames} = {d.frames / 25:g} s, or with --motion the sum of "
        "its segments; the ground truth has 4F samples at 100 Hz and the split CSVs floor(F/K) - 1 "
        "rows, K the --frame-step)",
    )
    parser.add_argument(
        "--motion",
        default=d.motion,
        metavar="SPEC",
        help="motion profile: comma-separated "
        f"segments over the 25 Hz frames, in order: {GRAMMAR}; e.g. 'fly:40,hover:10,yaw:10@90,"
        f"fly*0.25:40'. hover holds the pose exactly, yaw turns in place (default {DEFAULT_YAW:g} "
        "degrees, positive to the right) and the flight goes on in the new direction; the segments "
        "must add up to --frames if it is given (default: the normal flight; see docs/synthair.md)",
    )
    parser.add_argument(
        "--frame-step",
        type=int,
        default=d.frame_step,
        metavar="K",
        help="the split CSVs (and "
        f"the frames rendered) use every K-th 25 Hz frame (default {d.frame_step}, Mid-Air's: "
        "6.25 Hz; K=2: 12.5 Hz, K=8: 3.125 Hz); each row holds the motion between frames K apart",
    )
    parser.add_argument(
        "--size",
        type=int,
        default=d.size,
        metavar="S",
        help=f"image width = height in pixels (default {d.size}; focal S/2, 90 degree FOV)",
    )
    parser.add_argument(
        "--seed", type=int, default=d.seed, metavar="SEED", help=f"world and flight seed (default {d.seed})"
    )
    parser.add_argument(
        "--climates",
        nargs="+",
        default=list(d.climates),
        metavar="CLIMATE",
        help=f"climates to render (default: {' '.join(d.climates)})",
    )
    parser.add_argument(
        "--all-frames",
        action="store_true",
        help="render every 25 Hz frame (default: only the frames the split CSVs use, K, 2K, 3K, ...)",
    )
    parser.add_argument(
        "--supersample",
        type=int,
        default=d.supersample,
        choices=SUPERSAMPLES,
        help="colour rays per "
        f"pixel per axis (default {d.supersample}; antialiasing; depth and labels always come from the "
        "pixel centre)",
    )
    parser.add_argument(
        "--jpeg-quality",
        type=int,
        default=d.jpeg_quality,
        help=f"JPEG quality (default {d.jpeg_quality}, 4:4:4 chroma; photo-consistency suffers below about 95)",
    )
    parser.add_argument(
        "--distortion",
        default=d.distortion,
        metavar="LENS",
        help="render through a distorting lens with the same intrinsics: radtan:k1,k2,p1,p2[,k3] (OpenCV/ROS "
        "plumb_bob) or equidistant:k1,k2,k3,k4 (fisheye); every pixel's ray exactly, ground truth in the distorted "
        "pixels; the calibration files go to DIR/calibration/ (default: the pinhole)",
    )
    parser.add_argument(
        "--camera-mount",
        default=d.camera_mount,
        metavar="SPEC",
        help="the camera's mount on the flying body: forward, down, R,P,Y (degrees of the camera's FRD frame "
        "relative to the body's, e.g. 0,-30,0 pitched down 30), or a Kalibr camchain YAML (cam0.T_cam_imu), with an "
        f"optional lever arm @X,Y,Z (metres, body FRD); the frames are rendered from it (default {d.camera_mount}; "
        "see docs/own-flight.md)",
    )
    parser.add_argument(
        "--export",
        default=None,
        metavar="FORMATS",
        help="also write each flight as a drone team has it, comma-separated: mp4 (H.264 video), ulog (PX4), "
        "dataflash (ArduPilot .bin), tlog (MAVLink), srt (DJI subtitles), with exact ground truth (truth.csv); "
        "see docs/synthair.md",
    )
    parser.add_argument(
        "--time-offset",
        type=float,
        default=d.time_offset,
        action=_Given,
        metavar="S",
        help=f"with --export: the video starts S seconds into the flight and its logs (default {d.time_offset:g})",
    )
    parser.add_argument(
        "--fps",
        default=d.fps,
        action=_Given,
        metavar="F",
        help=f"with --export: the video's frame rate, e.g. 25, 29.97 or 30000/1001 (default {d.fps})",
    )
    parser.add_argument("--workers", type=int, default=d.workers, help=f"render processes (default {d.workers})")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if args.export is None:
        given = [
            flag
            for flag, dest in (("--time-offset", "time_offset"), ("--fps", "fps"))
            if getattr(args, f"{dest}_given", False)
        ]
        if given:
            raise ConfigError(f"{given[0]} applies only with --export")
    cfg = SynthConfig(
        out=args.out,
        trajectories=args.trajectories,
        frames=args.frames if getattr(args, "frames_given", False) or args.motion is None else None,
        size=args.size,
        seed=args.seed,
        climates=tuple(args.climates),
        all_frames=args.all_frames,
        supersample=args.supersample,
        jpeg_quality=args.jpeg_quality,
        motion=args.motion,
        frame_step=args.frame_step,
        distortion=args.distortion,
        camera_mount=args.camera_mount,
        export=() if args.export is None else parse_export(args.export),
        time_offset=args.time_offset,
        fps=args.fps,
        workers=args.workers,
    )
    summary = generate(cfg, progress=not args.no_progress)
    print(json.dumps({k: summary[k] for k in ("root", "frames_rendered", "frames_total", "resumed")}))
    print(f"split CSVs: {Path(args.out) / 'splits'}")
    return 0
