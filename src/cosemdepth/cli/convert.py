"""``cosemdepth convert TF_CHECKPOINT OUT_DIR``: official TensorFlow checkpoint -> our model folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..checkpoints.convert import MIDAIR_OPERATING_POINT, import_checkpoint
from ..checkpoints.model_io import CONFIG_FILE, WEIGHTS_FILE, save_weights
from ..errors import CheckpointError
from ..models.config import ARCHITECTURES, ORIGINAL_PSCV_DTYPE, PSCV_DTYPES
from ..output_safety.outdir import check_output_dir, model_inputs, write_marker


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "checkpoint",
        metavar="TF_CHECKPOINT",
        help="TensorFlow checkpoint: a prefix (.../cp-0059.ckpt), its .index file, or a folder with a "
        "'checkpoint' file (such as the authors' train/ or best/ folder)",
    )
    parser.add_argument(
        "out_dir",
        metavar="OUT_DIR",
        help="output folder; gets config.json and model.safetensors "
        "(existing ones are replaced only if cosemdepth wrote them)",
    )
    parser.add_argument(
        "--arch",
        choices=ARCHITECTURES,
        default=None,
        help="load only this part of the checkpoint, e.g. m4depth = encoder + depth decoder of a joint checkpoint "
        "(default: the architecture the checkpoint holds)",
    )
    parser.add_argument(
        "--no-feature-normalization",
        dest="feature_normalization",
        action="store_false",
        help="the checkpoint was trained with --no_feature_normalization (the only ablation that leaves no trace "
        "in the weights, so it cannot be inferred)",
    )
    parser.add_argument(
        "--pscv-dtype",
        choices=PSCV_DTYPES,
        default=ORIGINAL_PSCV_DTYPE,
        help="precision of the parallax cost-volume products in the converted model: float16 as the original "
        "computes them, so that the original's numbers are reproduced (default), or float32",
    )


def run(args: argparse.Namespace) -> int:
    out = Path(args.out_dir)
    if out.exists() and not out.is_dir():
        raise CheckpointError(f"{out}: OUT_DIR exists and is not a folder")
    files = (CONFIG_FILE, WEIGHTS_FILE)
    check_output_dir(
        out,
        command="convert",
        mode="into",
        what="OUT_DIR",
        files=files,
        inputs=model_inputs(args.checkpoint, "TF_CHECKPOINT"),
    )
    conv = import_checkpoint(
        args.checkpoint,
        arch=args.arch,
        feature_normalization=args.feature_normalization,
        pscv_dtype=args.pscv_dtype,
    )
    save_weights(conv.state_dict, conv.config, out, source=conv.source, operating_point=MIDAIR_OPERATING_POINT)
    write_marker(out, "convert", files)
    cfg = conv.config
    yes = {True: "on", False: "off"}
    parts = ", ".join(f"{p.replace('_', ' ')} {n:,}" for p, n in conv.parameters_by_part().items())
    lines = [
        f"source:     {conv.source['checkpoint']} ({conv.source['entries']} entries)",
        f"arch:       {cfg.arch}",
        f"levels:     {cfg.levels}",
    ]
    lines.append(f"classes:    {cfg.num_classes}" if cfg.has_semantic else "classes:    - (no semantic decoder)")
    lines.append(f"parameters: {conv.num_parameters:,} ({parts})")
    switches = [f"DINL {yes[cfg.dinl]}"]
    if cfg.has_depth:
        switches += [
            f"SNCV {yes[cfg.sncv]}",
            f"time recurrence {yes[cfg.time_recurrence]}",
            f"level memory {yes[cfg.level_memory]}",
            f"feature subdivision {yes[cfg.feature_subdivision]}",
        ]
    switches.append(f"feature normalization {yes[cfg.feature_normalization]} (not stored in checkpoints)")
    if cfg.has_depth:
        switches.append(f"cost volume {cfg.pscv_dtype}")
    lines.append(f"switches:   {', '.join(switches)}")
    dropped = f"{len(conv.dropped_keys)} dropped (--arch {cfg.arch}), " if conv.dropped_keys else ""
    lines.append(
        f"tensors:    {len(conv.converted_keys)} converted, {dropped}"
        f"{conv.source['ignored_tensors']} ignored (optimizer, metrics, counters, state, object graph)"
    )
    op = MIDAIR_OPERATING_POINT
    lines.append(
        f"operating:  {op.size[0]}x{op.size[1]} px, focal length {op.focal:g} px ({op.hfov_deg:g} degrees), "
        f"median step {op.step_translation.median:.2f} m (Mid-Air's; commands run the model at this focal "
        "length)"
    )
    lines.append(f"wrote:      {out / CONFIG_FILE}, {out / WEIGHTS_FILE}")
    print("\n".join(lines))
    return 0
