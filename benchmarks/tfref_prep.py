"""Prepare a Mid-Air-format tree (e.g. SynthAir) for the original's loader so that it reads the same depths as ours.

Used by the side-by-side benchmarks (``pipeline_vs_original.py``, ``convergence_vs_original.py``); also a script:

    TFREF_PY=... COSEM_AUTHORS=... PYTHONPATH=src python benchmarks/tfref_prep.py --data TREE --split-dir SPLITS --prep PREP

Runs the tfref harness' ``prepare`` stage (``train_reference.py --stages prepare --splits SPLITS``: the authors' CSV
layout, 384x384 mapped labels, symlinks to the colour and disparity folders). Both loaders compute
``depth = 512 / disparity`` whatever the PNG size (Mid-Air's convention, which SynthAir follows at every size), so the
disparities are used as they are. It checks that: a tree whose ``synthair.json`` records another depth encoding (a
SynthAir tree written before that convention, ``(W / 2) / z``, which the original reads ``1024 / W`` times too far:
8.0x at 128 px, measured) is refused. Nothing is written into the source tree.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve()
TFREF_TOOLS = Path(os.environ.get("TFREF_TOOLS", HERE.parents[2] / "shared" / "tools" / "tfref"))


def check_depth_encoding(data: str) -> None:
    """Refuse a SynthAir tree whose disparities are not ``512 / z`` (see the module docstring)."""
    sys.path.insert(0, str(HERE.parents[1] / "src"))
    from cosemdepth.data.synthair.writer import DEPTH_ENCODING

    meta = Path(data) / "synthair.json"
    if meta.exists():
        enc = json.loads(meta.read_text()).get("depth_encoding")
        if enc != DEPTH_ENCODING:
            raise SystemExit(f"{meta}: depth_encoding {enc!r}, expected {DEPTH_ENCODING!r}: regenerate the tree "
                             "(cosemdepth synth) so that the original reads the same depths")


def prepare_for_original(tfpy: str, authors: str, data: str, split_dir: str, prep: str) -> dict:
    """The tfref prepare stage into ``prep`` (when not done yet); returns its record."""
    check_depth_encoding(data)
    prep_p = Path(prep)
    if not (prep_p / "prepare.json").exists():
        sets = sorted(p.name for p in (Path(split_dir) / "train_data").iterdir() if p.is_dir())
        subprocess.run([tfpy, str(TFREF_TOOLS / "train_reference.py"), authors, "--data", data, "--prep", prep,
                        "--stages", "prepare", "--sets", *sets, "--splits", split_dir], check=True)
    return json.loads((prep_p / "prepare.json").read_text())


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
