"""Write a SynthAir dataset in the Mid-Air layout (design 10.1-10.5) and its split CSVs.

Layout under the output folder ``DIR``::

    DIR/synthair.json                                  generation parameters (seed, size, version, ...)
    DIR/SynthAir/<climate>/sensor_records.hdf5         100 Hz ground truth + camera_data path lists
    DIR/SynthAir/<climate>/color_left/trajectory_XXXX/NNNNNN.JPEG
    DIR/SynthAir/<climate>/stereo_disparity/trajectory_XXXX/NNNNNN.PNG    float16 bits of 512/z-depth (any S)
    DIR/SynthAir/<climate>/segmentation/trajectory_XXXX/NNNNNN.PNG        8-bit Mid-Air label IDs
    DIR/splits/{train,val,test}_data/SynthAir/<climate>/traj_XXXX.csv      from generate_splits(DIR, DIR/splits)
    DIR/SynthAir/<climate>/flight_export/trajectory_XXXX/...               with ``export``: video and logs (.export)

Trajectory numbers are ``climate_number * 1000 + i`` with Mid-Air's climate numbers (sunny 0, sunset 1, foggy 2,
cloudy 3). By default only the frames that the split CSVs use are rendered (K, 2K, ..., R K with R CSV rows and
the frame step K, 4 by default as in Mid-Air); ``all_frames`` renders every 25 Hz frame. A motion profile
(``motion``, :mod:`.motion`) warps the timeline of every flight. A camera mount (``camera_mount``) puts the camera on
the flying body: the tree (frames, ground truth, CSVs) is then the mounted camera's, and the exports hold the body's
logs. Every file is written atomically; an interrupted run can be resumed by running the same command again (frames
already on disk are kept, and they are identical to what would be written).
"""

from __future__ import annotations

import io
import json
import multiprocessing
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import h5py
import numpy as np
import torch
from PIL import Image
from tqdm import tqdm

from ..camera.calibration import Calibration
from ..camera.distortion import invert_profile
from ..camera.writers import calibration_files
from ..data.midair import format as fmt
from ..data.midair.splits import generate_splits
from ..errors import ConfigError, DatasetError
from ..geometry.mount import CameraMount, parse_mount
from ..models.config import MIDAIR_IMAGE_SIZE
from ..output_safety.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from ..output_safety.outdir import check_output_dir
from ..workers import check_workers
from .climate import CLIMATES, get_climate
from .export import EXPORT_DIR, ExportPlan, camera_flight, export_trajectory, parse_export, parse_fps
from .motion import SAMPLES_PER_FRAME, MotionProfile, parse_motion, timeline, warp_flight
from .render import render_frames
from .trajectory import MODES, Flight, make_flight
from .world import get_world

#: How the disparity PNGs encode depth (recorded in synthair.json; a tree in another encoding is refused).
DEPTH_ENCODING = "stereo_disparity PNG: uint16 = float16 bits of 512 / z_depth (Mid-Air convention, any size)"

#: Environment name of the generated tree (its folder under the dataset root).
ENVIRONMENT = "SynthAir"
#: Version of the generator's output; bump whenever the same arguments would give different files.
VERSION = "1.0"
METADATA = "synthair.json"
SPLITS_DIR = "splits"
#: Mid-Air's climate numbering (trajectory numbers climate * 1000 + i).
CLIMATE_NUMBER = {"sunny": 0, "sunset": 1, "foggy": 2, "cloudy": 3}
MAX_SIZE = 4096
#: Colour rays per pixel per axis that the renderer supports (``--supersample``).
SUPERSAMPLES = (1, 3, 5)
#: Largest ``--frame-step`` (camera frames between two CSV rows: 25 / K Hz).
MAX_FRAME_STEP = 250
#: Most 25 Hz camera frames per trajectory (11 hours of flight).
MAX_FRAMES = 1_000_000
MIN_SIZE = 16
#: Camera frames per flight when neither ``frames`` nor a motion profile says otherwise.
DEFAULT_FRAMES = 200
#: ``--distortion`` lens models and their coefficient counts (radtan: k1, k2, p1, p2 and optionally k3..k6).
DISTORTIONS = {"radtan": (4, 8), "equidistant": (4, 4)}
#: Folder of the calibration files written beside a flight rendered through a lens.
CALIBRATION_DIR = "calibration"


def parse_distortion(spec: str) -> tuple[str, tuple[float, ...]]:
    """``"radtan:k1,k2,p1,p2[,k3[,k4,k5,k6]]"`` or ``"equidistant:k1,k2,k3,k4"`` -> ``(model, coefficients)``; a
    ConfigError naming ``--distortion`` otherwise."""
    model, _, rest = str(spec).partition(":")
    model = model.strip()
    if model not in DISTORTIONS:
        raise ConfigError(
            f"--distortion {spec!r}: unknown lens model {model!r}; expected radtan:k1,k2,p1,p2[,k3] or "
            "equidistant:k1,k2,k3,k4"
        )
    try:
        coeffs = tuple(float(v) for v in rest.split(",")) if rest.strip() else ()
    except ValueError:
        raise ConfigError(f"--distortion {spec!r}: the coefficients must be numbers separated by commas") from None
    lo, hi = DISTORTIONS[model]
    if not lo <= len(coeffs) <= hi or not all(np.isfinite(coeffs)):
        want = f"{lo}" if lo == hi else f"{lo} to {hi}"
        raise ConfigError(f"--distortion {spec!r}: {model} takes {want} finite coefficients, got {len(coeffs)}")
    return model, coeffs


@dataclass(frozen=True)
class SynthConfig:
    """What ``cosemdepth synth`` generates. ``trajectories`` is per climate; ``frames`` counts 25 Hz camera frames
    per trajectory (the ground truth has ``4 * frames`` samples at 100 Hz); ``None``: the sum of the motion
    profile's segments, or :data:`DEFAULT_FRAMES` without one (given with a profile, it must equal that sum).
    ``motion``: a motion profile (``--motion``, :mod:`.motion`; ``None``: the normal flight); ``frame_step``: the
    split CSVs use every ``frame_step``-th camera frame (Mid-Air's 4: 6.25 Hz)."""

    out: Path
    trajectories: int = 4
    frames: int | None = None
    size: int = MIDAIR_IMAGE_SIZE
    seed: int = 0
    climates: tuple[str, ...] = CLIMATES
    all_frames: bool = False
    supersample: int = 1
    jpeg_quality: int = 98
    motion: str | None = None
    frame_step: int = fmt.FRAME_SKIP
    distortion: str | None = None
    camera_mount: str = "forward"
    export: tuple[str, ...] = ()
    time_offset: float = 2.0
    fps: str = "25"
    workers: int = field(default=1, compare=False)

    def __post_init__(self) -> None:
        profile = self.motion_profile
        if self.frames is None:
            object.__setattr__(self, "frames", DEFAULT_FRAMES if profile is None else profile.frames)
        elif profile is not None and self.frames != profile.frames:
            raise ConfigError(
                f"--frames {self.frames!r} does not match --motion {self.motion!r}, whose segments "
                f"add up to {profile.frames} frames (give one of them, or make them agree)"
            )

    @cached_property
    def motion_profile(self) -> MotionProfile | None:
        return None if self.motion is None else parse_motion(self.motion)

    @cached_property
    def lens(self) -> Calibration | None:
        """The camera with ``distortion`` (``--distortion``): the 90-degree intrinsics at ``size`` and the lens
        model; None for the pinhole. A ConfigError when the lens folds over the image or sees 90 degrees or more
        off-axis at its corners (every SynthAir ray must have a z-depth)."""
        if self.distortion is None:
            return None
        model, coeffs = parse_distortion(self.distortion)
        s = self.size
        try:
            lens = Calibration(
                (s, s),
                s / 2,
                s / 2,
                s / 2,
                s / 2,
                model=model,
                coefficients=coeffs,
                source="--distortion",
                layout="synthair",
            ).check()
        except DatasetError as e:
            raise ConfigError(str(e)) from None
        if model == "equidistant":
            theta, _ = lens.limit()
            corner = torch.tensor(lens.corner_radius(), dtype=torch.float64)
            reach = float(invert_profile(model, corner, coeffs, theta))
            if not reach < np.radians(89.0):
                raise ConfigError(
                    f"--distortion {self.distortion!r}: the image corners look {np.degrees(reach):.1f} degrees "
                    "off-axis; SynthAir renders rays up to 89 degrees (z-depth in front of the camera)"
                )
        return lens

    @cached_property
    def mount(self) -> CameraMount:
        """The camera mount (``camera_mount``, :func:`cosemdepth.geometry.mount.parse_mount`)."""
        return parse_mount(self.camera_mount)

    @cached_property
    def export_plan(self) -> ExportPlan | None:
        """What ``export`` writes per trajectory (None: no export)."""
        if not self.export:
            return None
        return ExportPlan(parse_export(self.export), parse_fps(self.fps), float(self.time_offset), self.mount)

    def validate(self) -> None:
        if not isinstance(self.size, int) or not MIN_SIZE <= self.size <= MAX_SIZE:
            raise ConfigError(f"--size must be an integer in [{MIN_SIZE}, {MAX_SIZE}] pixels, got {self.size!r}")
        if not isinstance(self.trajectories, int) or not 1 <= self.trajectories <= 1000:
            raise ConfigError(f"--trajectories must be in [1, 1000] (per climate), got {self.trajectories!r}")
        if not isinstance(self.frame_step, int) or not 1 <= self.frame_step <= MAX_FRAME_STEP:
            raise ConfigError(
                f"--frame-step must be an integer in [1, {MAX_FRAME_STEP}] (25 Hz camera frames between "
                f"two CSV rows), got {self.frame_step!r}"
            )
        min_frames = 2 * self.frame_step
        if not isinstance(self.frames, int) or not min_frames <= self.frames <= MAX_FRAMES:
            raise ConfigError(
                f"--frames must be an integer in [{min_frames}, {MAX_FRAMES}] (25 Hz camera frames per trajectory; "
                f"the split CSVs need frames 0 and {self.frame_step} at least), got {self.frames!r}"
            )
        if not isinstance(self.seed, int) or not 0 <= self.seed < 2**63:
            raise ConfigError(f"--seed must be a non-negative integer, got {self.seed!r}")
        if not self.climates:
            raise ConfigError("--climates needs at least one climate")
        unknown = [c for c in self.climates if c not in CLIMATES]
        if unknown:
            raise ConfigError(f"--climates: unknown climate(s) {unknown}; choose from {', '.join(CLIMATES)}")
        if len(set(self.climates)) != len(self.climates):
            raise ConfigError(f"--climates lists a climate twice: {list(self.climates)}")
        if self.supersample not in SUPERSAMPLES:
            raise ConfigError(
                f"--supersample must be one of {', '.join(map(str, SUPERSAMPLES))}, got {self.supersample!r}"
            )
        if not 1 <= self.jpeg_quality <= 100:
            raise ConfigError(f"--jpeg-quality must be in [1, 100], got {self.jpeg_quality!r}")
        check_workers(self.workers, minimum=1)
        _ = self.lens  # checks --distortion
        parse_mount(self.camera_mount)  # a ConfigError naming --camera-mount
        if self.export:
            plan = self.export_plan
            if not (isinstance(self.time_offset, (int, float)) and 0 <= self.time_offset < 1e6):
                raise ConfigError(f"--time-offset must be a non-negative number of seconds, got {self.time_offset!r}")
            if "mp4" in plan.formats and self.size % 2:
                raise ConfigError(f"--export mp4 needs an even --size (H.264 in 4:2:0), got {self.size}")
            plan.frame_times((self.frames * SAMPLES_PER_FRAME - 1) / fmt.GROUNDTRUTH_RATE)

    def metadata(self) -> dict:
        """Everything that determines the output bytes (what ``synthair.json`` records). ``motion``,
        ``frame_step``, ``camera_mount`` and ``export`` appear only when they differ from the defaults (the normal
        flight, step 4, the forward camera, no export), so that the default output stays what it was."""
        meta = {
            "generator": "cosemdepth synth",
            "version": VERSION,
            "environment": ENVIRONMENT,
            "seed": self.seed,
            "size": self.size,
            "trajectories_per_climate": self.trajectories,
            "frames": self.frames,
            "climates": list(self.climates),
            "all_frames": self.all_frames,
            "supersample": self.supersample,
            "jpeg_quality": self.jpeg_quality,
            "splits": SPLITS_DIR,
            "camera": {
                "width": self.size,
                "height": self.size,
                "fx": self.size / 2,
                "fy": self.size / 2,
                "cx": self.size / 2,
                "cy": self.size / 2,
                "rate_hz": fmt.CAMERA_RATE,
            },
            "groundtruth_rate_hz": fmt.GROUNDTRUTH_RATE,
            "depth_encoding": DEPTH_ENCODING,
        }
        if self.lens is not None:
            meta["camera"]["distortion"] = {
                "model": self.lens.model,
                "coefficients": list(self.lens.coefficients),
                "calibration": {name: f"{CALIBRATION_DIR}/{name}" for name in calibration_files(self.lens)},
            }
        if self.motion_profile is not None:
            meta["motion"] = self.motion_profile.metadata()
        if self.frame_step != fmt.FRAME_SKIP:
            meta["frame_step"] = self.frame_step
        if not self.mount.is_identity:
            meta["camera_mount"] = self.mount.metadata()
        if self.export_plan is not None:
            plan = self.export_plan
            meta["export"] = {
                "formats": list(plan.formats),
                "fps": str(plan.fps),
                "time_offset_s": plan.time_offset,
                "camera_mount": self.mount.metadata(),
                "folder": EXPORT_DIR,
            }
        return meta


#: Keys of ``synthair.json`` that are absent at their defaults (compared when resuming all the same).
OPTIONAL_METADATA = ("motion", "frame_step", "camera_mount", "export")


def trajectory_number(climate: str, i: int) -> int:
    return CLIMATE_NUMBER[climate] * 1000 + i


def csv_rows(frames: int, frame_step: int = fmt.FRAME_SKIP) -> int:
    """Rows of a trajectory's split CSV for ``frames`` camera frames, one every ``frame_step`` (design 10.3)."""
    return max(frames // frame_step - 1, 0)


def rendered_frames(cfg: SynthConfig) -> list[int]:
    """Camera frames rendered: those the split CSVs use (``K, 2K, ...``), or every frame with ``all_frames``."""
    if cfg.all_frames:
        return list(range(cfg.frames))
    return [cfg.frame_step * (k + 1) for k in range(csv_rows(cfg.frames, cfg.frame_step))]


def check_output_folder(cfg: SynthConfig) -> bool:
    """Raise a ConfigError if ``cfg.out`` cannot receive this dataset. Returns True when resuming."""
    out = Path(cfg.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a folder")
    # the output policy (cosemdepth.output_safety.outdir): a file in the way, a non-empty folder that is not a SynthAir dataset
    check_output_dir(
        out, command="synth", mode="resume", what="--out folder", recognize=lambda p: (p / METADATA).is_file()
    )
    if not out.exists() or not any(out.iterdir()):
        return False
    meta_path = out / METADATA
    if not meta_path.is_file():
        raise ConfigError(
            f"--out {out}: folder is not empty and holds no {METADATA}; refusing to write a SynthAir dataset into "
            "it (choose a new or empty folder)"
        )
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError) as e:
        raise ConfigError(f"--out {out}: cannot read {meta_path.name} ({e})") from None
    expected = cfg.metadata()
    keys = [*expected, *(k for k in OPTIONAL_METADATA if k not in expected)]
    diff = sorted(k for k in keys if meta.get(k) != expected.get(k))
    if diff:
        raise ConfigError(
            f"--out {out}: holds another SynthAir dataset (different {', '.join(diff)}); choose a new or empty "
            "folder, or repeat the original arguments to resume it"
        )
    return True


# ----------------------------------------------------------------------------------------------------------------
# encoding


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    buf = io.BytesIO()
    img = Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8))
    img.save(buf, format="JPEG", quality=quality, subsampling=0, optimize=False)
    return buf.getvalue()


def encode_png(array: np.ndarray) -> bytes:
    """8-bit or 16-bit single-channel PNG."""
    buf = io.BytesIO()
    if array.dtype not in (np.uint8, np.uint16) or array.ndim != 2:
        raise TypeError(f"PNG arrays must be 2-D uint8 or uint16, got {array.dtype} {array.shape}")
    img = Image.fromarray(np.ascontiguousarray(array))  # mode L (uint8) or I;16 (uint16)
    img.save(buf, format="PNG", compress_level=6)
    return buf.getvalue()


def depth_to_png_disparity(depth: np.ndarray) -> np.ndarray:
    """z-depth [H, W] metres -> uint16 float16 bit patterns of ``512 / depth`` (Mid-Air's convention at any size)."""
    return fmt.encode_disparity(fmt.depth_to_disparity(depth))


# ----------------------------------------------------------------------------------------------------------------
# generation

_WORKER_STATE: dict = {}


@dataclass(frozen=True)
class _Task:
    """Consecutive rendered frames of one trajectory, rendered in one batch."""

    climate: str
    number: int
    frames: tuple[int, ...]
    attitudes: tuple[tuple[float, ...], ...]
    positions: tuple[tuple[float, ...], ...]
    sun_azimuth: float


def batch_size(size: int) -> int:
    """Frames rendered together: small images share the ray marcher's per-step overhead (results are identical)."""
    return int(np.clip(round(2 * 384**2 / size**2), 1, 16))


def _frame_paths(root: Path, climate: str, number: int, frame: int) -> tuple[Path, Path, Path]:
    base = root / ENVIRONMENT / climate
    traj = fmt.trajectory_dir(number)
    return (
        base / fmt.COLOR_DIR / traj / fmt.frame_name(frame, fmt.COLOR_EXT),
        base / fmt.DISPARITY_DIR / traj / fmt.frame_name(frame, fmt.DISPARITY_EXT),
        base / fmt.SEGMENTATION_DIR / traj / fmt.frame_name(frame, fmt.SEGMENTATION_EXT),
    )


def _init_worker(cfg: SynthConfig) -> None:
    if "world" not in _WORKER_STATE:
        _WORKER_STATE.update(cfg=cfg, world=get_world(cfg.seed))


def _render_task(task: _Task) -> int:
    cfg: SynthConfig = _WORKER_STATE["cfg"]
    world = _WORKER_STATE["world"]
    torch.set_num_threads(1)
    todo = []
    for i, k in enumerate(task.frames):
        paths = _frame_paths(Path(cfg.out), task.climate, task.number, k)
        if not all(p.is_file() for p in paths):
            todo.append((i, paths))
    if not todo:
        return 0
    climate = get_climate(task.climate).with_sun_azimuth(task.sun_azimuth)
    att = np.array([task.attitudes[i] for i, _ in todo])
    pos = np.array([task.positions[i] for i, _ in todo])
    frames = render_frames(world, climate, att, pos, cfg.size, cfg.size, supersample=cfg.supersample, lens=cfg.lens)
    for (_, paths), frame in zip(todo, frames):
        atomic_write_bytes(paths[0], encode_jpeg(frame.rgb, cfg.jpeg_quality))
        atomic_write_bytes(paths[1], encode_png(depth_to_png_disparity(frame.depth)))
        atomic_write_bytes(paths[2], encode_png(frame.labels))
    return len(todo)


def _write_sensor_records(path: Path, flights: dict[int, PlannedFlight], frames: list[int]) -> None:
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w", track_order=False) as h5:
            for number, planned in sorted(flights.items()):
                flight = planned.flight
                traj = fmt.trajectory_dir(number)
                g = h5.create_group(f"{traj}/groundtruth")
                for name in ("attitude", "position", "velocity", "acceleration", "angular_velocity"):
                    g.create_dataset(name, data=np.asarray(getattr(flight, name), dtype=np.float64), track_times=False)
                cam = h5.create_group(f"{traj}/camera_data")
                for folder, ext in (
                    (fmt.COLOR_DIR, fmt.COLOR_EXT),
                    (fmt.DISPARITY_DIR, fmt.DISPARITY_EXT),
                    (fmt.SEGMENTATION_DIR, fmt.SEGMENTATION_EXT),
                ):
                    names = [f"{folder}/{traj}/{fmt.frame_name(k, ext)}".encode() for k in frames]
                    cam.create_dataset(folder, data=np.array(names, dtype="S"), track_times=False)


@dataclass(frozen=True)
class PlannedFlight:
    flight: Flight
    sun_azimuth: float  # degrees; the climate's sun direction varies a little between trajectories


def plan_flights(cfg: SynthConfig, world) -> dict[str, dict[int, PlannedFlight]]:
    """The flights of every climate and trajectory number (deterministic for the seed).

    Trajectory ``i`` of climate number ``c`` flies mode ``MODES[(i + c) % 4]`` (road, village, lake, free), so
    that small sets still see roads, buildings and water. With a motion profile, each flight is its base flight
    (the plain flight of the same seed, long enough for the warped timeline) read along that timeline.
    """
    profile = cfg.motion_profile
    warp = None if profile is None else timeline(profile)
    out: dict[str, dict[int, PlannedFlight]] = {}
    for climate in cfg.climates:
        ci = CLIMATE_NUMBER[climate]
        flights = {}
        for i in range(cfg.trajectories):
            rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 0xF117, ci, i]))
            mode = MODES[(i + ci) % len(MODES)]
            if warp is None:
                flight = make_flight(world, rng, cfg.frames, mode)
            else:
                track = warp.ground_track if warp.turns else None
                flight = warp_flight(make_flight(world, rng, warp.base_frames, mode, ground_track=track), warp)
            azimuth = get_climate(climate).sun_azimuth + float(rng.uniform(-50.0, 50.0))
            flights[trajectory_number(climate, i)] = PlannedFlight(flight, azimuth)
        out[climate] = flights
    return out


def _export(cfg: SynthConfig, world, flights: dict[str, dict[int, PlannedFlight]], frames: list[int]) -> None:
    """The video and logs of every flight (:mod:`.export`): the body's flight, the camera mounted on it."""
    torch.set_num_threads(1)
    for climate, fl in flights.items():
        for number, planned in sorted(fl.items()):
            look = get_climate(climate).with_sun_azimuth(planned.sun_azimuth)

            def render_rgb(q_camera, p_camera, look=look):
                bs = batch_size(cfg.size)
                for c in range(0, len(q_camera), bs):
                    batch = render_frames(
                        world,
                        look,
                        q_camera[c : c + bs],
                        p_camera[c : c + bs],
                        cfg.size,
                        cfg.size,
                        cfg.supersample,
                        lens=cfg.lens,
                    )
                    yield from (f.rgb for f in batch)

            folder = Path(cfg.out) / ENVIRONMENT / climate / EXPORT_DIR / fmt.trajectory_dir(number)
            export_trajectory(folder, planned.flight, cfg.export_plan, cfg.seed, number, render_rgb, frames)


def generate(cfg: SynthConfig, progress: bool = True) -> dict:
    """Generate the dataset described by ``cfg``; returns a summary (counts and paths)."""
    cfg.validate()
    resuming = check_output_folder(cfg)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = cfg.metadata()
    meta["complete"] = False
    if not resuming:
        atomic_write_text(out / METADATA, json.dumps(meta, indent=2) + "\n")
    if cfg.lens is not None:  # the calibration of the lens, in the layouts users have, beside the flights
        for name, text in calibration_files(cfg.lens).items():
            atomic_write_text(out / CALIBRATION_DIR / name, text)

    world = get_world(cfg.seed)
    flights = plan_flights(cfg, world)
    frames = rendered_frames(cfg)
    tasks = []
    cameras = {
        c: {n: PlannedFlight(camera_flight(p.flight, cfg.mount), p.sun_azimuth) for n, p in fl.items()}
        for c, fl in flights.items()
    }
    for climate, fl in cameras.items():
        _write_sensor_records(out / ENVIRONMENT / climate / fmt.SENSOR_RECORDS, fl, frames)
        bs = batch_size(cfg.size)
        for number, planned in sorted(fl.items()):
            f = planned.flight
            for c in range(0, len(frames), bs):
                ks = tuple(frames[c : c + bs])
                tasks.append(
                    _Task(
                        climate,
                        number,
                        ks,
                        tuple(tuple(f.attitude[SAMPLES_PER_FRAME * k]) for k in ks),
                        tuple(tuple(f.position[SAMPLES_PER_FRAME * k]) for k in ks),
                        planned.sun_azimuth,
                    )
                )

    _WORKER_STATE.update(cfg=cfg, world=world)
    written = 0
    total = sum(len(t.frames) for t in tasks)
    bar = tqdm(total=total, desc="synthair", unit="frame", disable=not progress)
    threads = torch.get_num_threads()
    try:
        if cfg.workers > 1 and len(tasks) > 1:
            # fork shares the world with the workers; elsewhere each worker builds it (deterministic)
            ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else None)
            with ctx.Pool(cfg.workers, initializer=_init_worker, initargs=(cfg,)) as pool:
                for task, n in zip(tasks, pool.imap(_render_task, tasks, chunksize=1)):
                    written += n
                    bar.update(len(task.frames))
        else:
            for task in tasks:
                written += _render_task(task)
                bar.update(len(task.frames))
        if cfg.export_plan is not None:
            _export(cfg, world, flights, frames)
    finally:
        bar.close()
        _WORKER_STATE.clear()
        torch.set_num_threads(threads)

    splits = generate_splits(out, out / SPLITS_DIR, rule="generic", frame_step=cfg.frame_step)
    meta["complete"] = True
    atomic_write_text(out / METADATA, json.dumps(meta, indent=2) + "\n")
    return {
        "root": str(out),
        "frames_rendered": written,
        "frames_total": total,
        "splits": {k: [str(p) for p in v] for k, v in splits.items()},
        "resumed": resuming,
    }
