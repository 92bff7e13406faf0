"""``train_ab.py`` with switches that put back the cost volumes or DINL of an older commit, for before/after A/B.

    PYTHONPATH=src python benchmarks/train_ab_before.py bf16,cl,oldsncv,oldpscv,olddinl bf16,cl [--before COMMIT]
        [train_ab.py options: --threads 1 --repeats 8 --out results/NAME.json]

Switches besides ``train_ab.py``'s: ``oldsncv`` / ``oldpscv``: the spatial / parallax-sweep cost volume of
``ops/cost_volume.py`` at ``--before`` (default 3ed54b1, before issue 11's third round), loaded from git into a
temporary module and swapped into the training forward's level operations (``models.pyramid.REFERENCE_OPS``) for
that variant's steps only; ``olddinl``: DINL through its plain ops (the path ``export --check`` takes), as before;
``unfused``: every convolution + LeakyReLU as two plain ops (``ops.conv`` without its fused oneDNN form), as before;
``oldl2``: the decoders' grouped L2 normalisation through autograd of its plain ops, as before; ``oldcat``: the
refiner inputs by ``torch.cat`` (then cast and re-laid out by the convolution), as before.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "src"))

import train_ab  # noqa: E402

import cosemdepth.models.pyramid as pyramid  # noqa: E402
import cosemdepth.ops.conv as conv_ops  # noqa: E402
import cosemdepth.ops.normalize as normalize  # noqa: E402


def load_old_cost_volume(commit: str):
    """``ops/cost_volume.py`` at ``commit`` as a module (its relative imports made absolute)."""
    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:src/cosemdepth/ops/cost_volume.py"],
                          check=True, capture_output=True, text=True).stdout
    text = text.replace("from ..", "from cosemdepth.")
    path = Path(tempfile.mkdtemp()) / "old_cost_volume.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("old_cost_volume", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def plain_grouped_l2(x, groups, guard=True):
    """The grouped L2 normalisation as plain ops (autograd's backward), as before issue 11's fourth round."""
    b, c, h, w = x.shape
    g = x.reshape(b, groups, c // groups, h, w)
    sq = (g * g).sum(dim=2, keepdim=True)
    if guard:
        sq = sq.clamp_min(normalize.NORM_SQ_EPS)
    return (g / torch.sqrt(sq)).reshape(b, c, h, w)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commit = "3ed54b1"
    if "--before" in argv:
        i = argv.index("--before")
        commit = argv[i + 1]
        del argv[i : i + 2]
    old = load_old_cost_volume(commit)
    new_ops = pyramid.REFERENCE_OPS
    patches = {"oldsncv": {"sncv": old.spatial_cost_volume}, "oldpscv": {"pscv": old.parallax_sweep_cost_volume},
               "oldcat": {"concat": functools.partial(torch.cat, dim=1)}}
    train_ab.SWITCHES |= set(patches) | {"olddinl", "unfused", "oldl2"}
    make_variant, step = train_ab.make_variant, train_ab.step

    def make(spec, base, cfg):
        v = make_variant(spec, base, cfg)
        if "olddinl" in spec.split(","):  # a spatial_mean other than the default: DINL's plain ops
            v["model"].encoder.dinl.spatial_mean = lambda x: x.mean(dim=(2, 3), keepdim=True)
        return v

    def patched_step(v, batch, cfg):
        kw = {k: f for s in v["spec"].split(",") for k, f in patches.get(s, {}).items()}
        pyramid.REFERENCE_OPS = dataclasses.replace(new_ops, **kw)
        fused, l2 = conv_ops._FUSED, pyramid.grouped_l2_normalize
        conv_ops._FUSED = fused and "unfused" not in v["spec"].split(",")
        if "oldl2" in v["spec"].split(","):
            pyramid.grouped_l2_normalize = plain_grouped_l2
        try:
            return step(v, batch, cfg)
        finally:
            pyramid.REFERENCE_OPS = new_ops
            conv_ops._FUSED, pyramid.grouped_l2_normalize = fused, l2

    train_ab.make_variant, train_ab.step = make, patched_step
    return train_ab.main(argv)


if __name__ == "__main__":
    raise SystemExit(main())
