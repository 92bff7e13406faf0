"""Test writers of tiny datasets in the Mid-Air, TopAir and Aeroscapes formats (independent of the readers).

Mid-Air layout written here (design 10.1): ``<root>/<env>/<climate>/color_left/trajectory_XXXX/NNNNNN.JPEG``,
``stereo_disparity/.../NNNNNN.PNG`` (uint16 holding float16 bits), ``segmentation/.../NNNNNN.PNG`` (8-bit gray IDs)
and ``sensor_records.hdf5`` with ``trajectory_XXXX/groundtruth/{attitude,position}`` at 100 Hz (NED body,
quaternions w-first, body-to-world) and ``trajectory_XXXX/camera_data/<sensor>`` lists of relative image paths.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
from PIL import Image


def quat_from_euler_zyx(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Body-to-world quaternion (w, x, y, z) of yaw about z, then pitch about y, then roll about x (NED)."""
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def rot_from_quat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def flight_groundtruth(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Smooth 100 Hz NED body poses: ``(attitude [n, 4], position [n, 3])``."""
    t = np.arange(n) / 100.0
    ph = seed * 0.7
    yaw = 0.3 * np.sin(0.5 * t + ph) + 0.1 * seed
    pitch = 0.1 * np.sin(0.7 * t + 1 + ph)
    roll = 0.15 * np.cos(0.4 * t + ph)
    att = quat_from_euler_zyx(yaw, pitch, roll)
    pos = np.stack([6.0 * t + seed, 2.0 * np.sin(0.3 * t + ph), -20 + np.cos(0.5 * t)], axis=-1)
    return att, pos


@dataclass
class MidAirTruth:
    """What was written, for exact comparisons."""

    root: Path
    size: int
    rgb: dict[str, np.ndarray] = field(default_factory=dict)  # relative path -> uint8 array written to the JPEG
    disparity_bits: dict[str, np.ndarray] = field(default_factory=dict)  # relative path -> uint16
    labels: dict[str, np.ndarray] = field(default_factory=dict)  # relative path -> uint8 IDs
    groundtruth: dict[tuple[str, str, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


def write_midair(
    root: Path,
    layout: dict[tuple[str, str], list[int]],
    frames: int = 20,
    size: int = 32,
    seed: int = 0,
    label_ids: int = 14,
    images: bool = True,
) -> MidAirTruth:
    """Write a tiny Mid-Air-format dataset: ``layout`` maps ``(env, climate)`` to trajectory numbers."""
    rng = np.random.default_rng(seed)
    truth = MidAirTruth(root=root, size=size)
    for (env, climate), numbers in layout.items():
        base = root / env / climate
        base.mkdir(parents=True, exist_ok=True)
        with h5py.File(base / "sensor_records.hdf5", "w") as h5:
            for number in numbers:
                traj = f"trajectory_{number:04d}"
                att, pos = flight_groundtruth(4 * frames, seed=number)
                truth.groundtruth[(env, climate, number)] = (att, pos)
                g = h5.create_group(traj)
                g.create_dataset("groundtruth/attitude", data=att)
                g.create_dataset("groundtruth/position", data=pos)
                for sensor, ext in (("color_left", "JPEG"), ("stereo_disparity", "PNG"), ("segmentation", "PNG")):
                    names = [f"{sensor}/{traj}/{i:06d}.{ext}".encode() for i in range(frames)]
                    g.create_dataset(f"camera_data/{sensor}", data=np.array(names))
                for sensor in ("color_left", "stereo_disparity", "segmentation"):
                    (base / sensor / traj).mkdir(parents=True, exist_ok=True)
                if not images:
                    continue
                for i in range(frames):
                    rel = f"{env}/{climate}"
                    yy, xx = np.mgrid[0:size, 0:size]
                    rgb = np.stack(
                        [
                            (128 + 100 * np.sin(xx / 3.0 + i + number)),
                            (128 + 100 * np.cos(yy / 4.0 - i)),
                            (128 + 90 * np.sin((xx + yy) / 5.0 + 0.5 * i)),
                        ],
                        axis=-1,
                    ).astype(np.uint8)
                    p = f"{rel}/color_left/{traj}/{i:06d}.JPEG"
                    Image.fromarray(rgb).save(root / p, format="JPEG", quality=95, subsampling=0)
                    truth.rgb[p] = rgb
                    disp = rng.uniform(0.05, 40.0, (size, size)).astype(np.float16)
                    bits = disp.view(np.uint16)
                    p = f"{rel}/stereo_disparity/{traj}/{i:06d}.PNG"
                    Image.fromarray(bits).save(root / p, format="PNG")
                    truth.disparity_bits[p] = bits
                    ids = rng.integers(0, label_ids, (size, size)).astype(np.uint8)
                    p = f"{rel}/segmentation/{traj}/{i:06d}.PNG"
                    Image.fromarray(ids).save(root / p, format="PNG")
                    truth.labels[p] = ids
    return truth


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    """relative path -> (size, mtime_ns) of every file and folder under ``folder``."""
    out = {}
    for p in sorted(folder.rglob("*")):
        st = p.stat()
        out[p.relative_to(folder).as_posix()] = (st.st_size if p.is_file() else -1, st.st_mtime_ns)
    return out


def read_split_rows(csv_path: Path) -> list[dict[str, str]]:
    """Independent plain parse of a tab-separated split CSV."""
    lines = csv_path.read_text().splitlines()
    header = lines[0].split("\t")
    return [dict(zip(header, ln.split("\t"))) for ln in lines[1:] if ln]


def write_png_gray(path: Path, arr: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr).save(path, format="PNG")


def deg(x: float) -> float:
    return math.radians(x)
