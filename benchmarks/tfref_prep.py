"""Prepare a Mid-Air-format tree (e.g. SynthAir) for the original's loader so that it reads the same depths as ours.

Used by the side-by-side benchmarks (``pipeline_vs_original.py``, ``convergence_vs_original.py``); also a script:

    TFREF_PY=... COSEM_AUTHORS=... PYTHONPATH=src python benchmarks/tfref_prep.py --data TREE --split-dir SPLITS --prep PREP

Runs the tfref harness' ``prepare`` stage (``train_reference.py --stages prepare --splits SPLITS``: the authors' CSV
layout, 384x384 mapped labels, symlinks to the colour and disparity folders), then fixes the depth scale. The
original's loader computes ``depth = 512 / disparity`` whatever the image size (Mid-Air's 1024 px focal); the
stored disparity of a tree of width ``W`` is ``(W / 2) / z`` (Mid-Air and SynthAir alike; ours reads
``(W / 2) / disparity``). Measured on a 128 px SynthAir tree without this step, the original's training depths were
8.0x ours (per-sequence medians 160.8 m vs 20.2 m, 43 % vs 21 % of pixels at the loss clip of 200 m). So every
``stereo_disparity`` symlink whose PNGs are not 1024 px wide is replaced here by a folder of copies with
``disparity * 1024 / W`` (float16 bits, exact for power-of-two ratios), after which ``512 / disparity'`` is the
same z-depth ours reads. Nothing is written into the source tree.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
TFREF_TOOLS = Path(os.environ.get("TFREF_TOOLS", HERE.parents[2] / "shared" / "tools" / "tfref"))
MARK = "disparity_rescaled.json"


def rescale_disparity_dir(src: Path, dst: Path) -> dict:
    sys.path.insert(0, str(HERE.parents[1] / "src"))
    from cosemdepth.data.decode import read_uint16_png
    from cosemdepth.data.midair.format import decode_disparity, encode_disparity
    from cosemdepth.data.synthair.writer import encode_png
    from cosemdepth.io.atomic import atomic_write_bytes

    n, widths = 0, set()
    for f in sorted(src.rglob("*.PNG")):
        raw = read_uint16_png(f)
        w = raw.shape[1]
        widths.add(w)
        disp = decode_disparity(raw).astype(np.float64) * (1024.0 / w)
        out = dst / f.relative_to(src)
        out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(out, encode_png(encode_disparity(disp)))
        n += 1
    return {"files": n, "widths": sorted(widths)}


def prepare_for_original(tfpy: str, authors: str, data: str, split_dir: str, prep: str) -> dict:
    """The tfref prepare stage into ``prep`` (when not done yet) plus the disparity rescaling; returns its record."""
    prep_p = Path(prep)
    mark = prep_p / MARK
    if mark.exists():
        return json.loads(mark.read_text())
    if not (prep_p / "prepare.json").exists():
        sets = sorted(p.name for p in (Path(split_dir) / "train_data").iterdir() if p.is_dir())
        subprocess.run([tfpy, str(TFREF_TOOLS / "train_reference.py"), authors, "--data", data, "--prep", prep,
                        "--stages", "prepare", "--sets", *sets, "--splits", split_dir], check=True)
    info = json.loads((prep_p / "prepare.json").read_text())
    done = []
    for d in sorted(Path(info["db_path"]).glob("*/*/stereo_disparity")):
        if not d.is_symlink():
            continue
        target = Path(os.readlink(d))
        tmp = d.with_name("stereo_disparity.rescaling")
        rec = rescale_disparity_dir(target, tmp)
        if rec["widths"] == [1024]:
            import shutil

            shutil.rmtree(tmp)
            continue
        d.unlink()
        tmp.rename(d)
        done.append({"folder": str(d), "source": str(target), **rec})
    rec = {"rescaled": done, "rule": "disparity * 1024 / W, so that the original's 512 / disparity is the z-depth"}
    mark.write_text(json.dumps(rec, indent=1))
    return rec


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True)
    ap.add_argument("--split-dir", required=True)
    ap.add_argument("--prep", required=True)
    a = ap.parse_args()
    tfpy, authors = os.environ.get("TFREF_PY"), os.environ.get("COSEM_AUTHORS")
    if not (tfpy and authors):
        print("TFREF_PY and COSEM_AUTHORS must be set (see ../shared/tools/tfref/README.md)")
        return 2
    print(json.dumps(prepare_for_original(tfpy, authors, a.data, a.split_dir, a.prep), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
