"""Folders that commands read as input, each written by the code that writes such folders (the project's writers,
the rosbags writer, the Mid-Air / TopAir / Aeroscapes layouts of the test writers), for the output-policy tests.

``make_input_folders(root)`` returns ``{kind name: folder}`` (the names of :data:`cosemdepth.output_safety.input_kinds
.INPUT_KINDS`); a SynthAir dataset is checked where ``cosemdepth synth`` writes one
(``tests/synthair/test_synthair_writer.py``) and through the CLI (``tests/cli/test_output_policy.py``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _bags import camera_info_msg, image_msg, typestore, write_bag  # noqa: E402
from _writers import write_midair, write_png_gray  # noqa: E402


def _model_and_checkpoint(root: Path) -> tuple[Path, Path]:
    import torch

    from cosemdepth import build_model, save_model
    from cosemdepth.training.checkpoint import CheckpointManager, get_rng_state

    torch.manual_seed(0)
    model = build_model(arch="m4semantic", levels=1, num_classes=3)
    save_model(model, root / "model")
    from cosemdepth.training.config import RunConfig
    from cosemdepth.training.rundir import create_run_dir

    create_run_dir(root / "run", RunConfig())
    ckpt = CheckpointManager(root / "run" / "checkpoints").save(
        model_state=model.state_dict(),
        model_config=model.config,
        optimizer_state=torch.optim.Adam(model.parameters()).state_dict(),
        trainer_state={"step": 1, "epoch": 0},
        rng_state=get_rng_state(),
    )
    return root / "model", ckpt


def make_input_folders(root: Path) -> dict[str, Path]:
    from cosemdepth.data.midair.splits import generate_splits

    root.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    write_midair(root / "midair", {("Kite_training", "sunny"): [0, 1]}, frames=16, size=16, images=False)
    generate_splits(root / "midair", root / "midair" / "splits", rule=lambda t: "test")
    out["a Mid-Air-format dataset"] = root / "midair"
    out["part of a Mid-Air-format dataset"] = root / "midair" / "Kite_training" / "sunny"
    out["a split folder"] = root / "midair" / "splits"
    model, ckpt = _model_and_checkpoint(root)
    out["a model folder"] = model
    out["a training checkpoint"] = ckpt
    out["a folder of training checkpoints"] = ckpt.parent
    out["a training run folder"] = ckpt.parent.parent
    # TopAir: <root>/<env>/images, depth, seg_id (data.topair)
    env = root / "topair" / "OakForest_3"
    for sub in ("images", "depth", "seg_id"):
        write_png_gray(env / sub / "000000.png", np.zeros((8, 8), np.uint8))
    out["a TopAir dataset"] = root / "topair"
    out["a TopAir environment folder"] = env
    # Aeroscapes: JPEGImages/ + SegmentationClass/ + ImageSets/ (data.aeroscapes)
    aero = root / "aeroscapes"
    (aero / "JPEGImages").mkdir(parents=True)
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(aero / "JPEGImages" / "a.jpg")
    write_png_gray(aero / "SegmentationClass" / "a.png", np.zeros((8, 8), np.uint8))
    out["an Aeroscapes dataset"] = aero
    # the authors' TensorFlow checkpoint folder: the "checkpoint" state file, P.index and P.data shards
    tf = root / "tf" / "train"
    tf.mkdir(parents=True)
    for name in ("checkpoint", "cp-0001.ckpt.index", "cp-0001.ckpt.data-00000-of-00001"):
        (tf / name).write_bytes(b"\0")
    out["a TensorFlow checkpoint folder"] = tf
    # your own flight: images + a TUM pose file (data.flight)
    flight = root / "flight"
    flight.mkdir()
    for i in range(2):
        Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(flight / f"{i:06d}.PNG")
    (flight / "poses.txt").write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n")
    out["a flight (images and a pose file)"] = flight
    ts = typestore(False)
    bag = write_bag(
        root / "bag",
        [
            ("/cam/image", image_msg(ts, 1, np.zeros((4, 4, 3), np.uint8)), 1),
            ("/cam/info", camera_info_msg(ts, 1, 4, 4, (2, 2, 2, 2)), 1),
        ],
    )
    out["a ROS 2 bag"] = bag
    return out


__all__ = ["make_input_folders"]
