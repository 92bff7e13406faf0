"""``cosemdepth convert TF_CHECKPOINT OUT_DIR``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from tf_bundle_writer import model_tensors, write_bundle

from cosemdepth.checkpoints.convert import MIDAIR_STEP_TRANSLATION, convert_checkpoint
from cosemdepth.checkpoints.model_io import read_model_files
from cosemdepth.cli.main import main

SRC = Path(__file__).resolve().parents[2] / "src"


def test_convert_fixture(tfref_dir, tmp_path, capsys):
    out = tmp_path / "converted"
    assert main(["convert", str(tfref_dir / "ckpt"), str(out)]) == 0
    text = capsys.readouterr().out
    assert "arch:       cosemdepth" in text
    assert "levels:     5" in text and "classes:    7" in text
    assert "5,202,528" in text
    assert str((tfref_dir / "ckpt" / "cp-0000.ckpt").resolve()) in text
    assert sorted(os.listdir(out)) == [".cosemdepth-output.json", "config.json", "model.safetensors"]
    sd, cfg, meta = read_model_files(out)
    assert cfg.arch == "cosemdepth" and cfg.levels == 5 and cfg.num_classes == 7
    assert meta["source"]["type"] == "tensorflow_checkpoint"
    assert meta["source"]["checkpoint"] == str((tfref_dir / "ckpt" / "cp-0000.ckpt").resolve())
    ref, _ = convert_checkpoint(tfref_dir / "ckpt")
    assert all(torch.equal(sd[k], ref[k]) for k in ref)
    # Mid-Air's operating point: 384x384, a 90-degree camera (f = 192 px), the training CSVs' per-step motion
    op = meta["operating_point"]
    assert op["size"] == [384, 384] and op["focal_px"] == [192.0, 192.0]
    assert op["step_translation_m"] == MIDAIR_STEP_TRANSLATION.to_dict()
    assert "operating:  384x384 px, focal length 192 px (90 degrees)" in text


def test_convert_with_arch(tfref_dir, tmp_path, capsys):
    out = tmp_path / "depth_only"
    assert main(["convert", str(tfref_dir / "ckpt" / "cp-0000.ckpt"), str(out), "--arch", "m4depth"]) == 0
    text = capsys.readouterr().out
    assert "arch:       m4depth" in text and "3,059,881" in text and "70 dropped" in text
    assert "classes:    - (no semantic decoder)" in text
    assert json.loads((out / "config.json").read_text())["model"]["arch"] == "m4depth"


def test_convert_m4semantic_bundle(tmp_path, capsys):
    write_bundle(tmp_path / "best" / "cp-0011.ckpt", model_tensors(levels=4, depth=False, classes=12, zeros=True))
    assert main(["convert", str(tmp_path / "best"), str(tmp_path / "out")]) == 0
    text = capsys.readouterr().out
    assert "arch:       m4semantic" in text and "classes:    12" in text and "levels:     4" in text
    assert "SNCV" not in text  # depth switches are not shown for a semantic-only model


def test_no_feature_normalization_flag(tmp_path):
    write_bundle(tmp_path / "ck" / "cp-0000.ckpt", model_tensors(levels=1, zeros=True))
    assert main(["convert", str(tmp_path / "ck"), str(tmp_path / "out"), "--no-feature-normalization"]) == 0
    meta = json.loads((tmp_path / "out" / "config.json").read_text())
    assert meta["model"]["feature_normalization"] is False
    assert meta["source"]["not_from_checkpoint"] == {"feature_normalization": False, "pscv_dtype": "float16"}
    assert main(["convert", str(tmp_path / "ck"), str(tmp_path / "out32"), "--pscv-dtype", "float32"]) == 0
    assert json.loads((tmp_path / "out32" / "config.json").read_text())["model"]["pscv_dtype"] == "float32"


def _fails(argv, capsys, *needles):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("cosemdepth convert: error: ")
    for n in needles:
        assert n in err, err
    return err


def test_out_dir_is_a_file(tmp_path, capsys):
    write_bundle(tmp_path / "ck" / "cp-0000.ckpt", model_tensors(levels=1, zeros=True))
    target = tmp_path / "model.out"
    target.write_text("x")
    _fails(["convert", str(tmp_path / "ck"), str(target)], capsys, str(target), "is not a folder")
    assert target.read_text() == "x"


def test_corrupt_checkpoint(tmp_path, capsys):
    prefix = write_bundle(tmp_path / "ck" / "cp-0000.ckpt", model_tensors(levels=1, zeros=True))
    data = Path(f"{prefix}.data-00000-of-00001")
    raw = bytearray(data.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    data.write_bytes(bytes(raw))
    out = tmp_path / "out"
    _fails(["convert", str(prefix), str(out)], capsys, str(data), "CRC32C mismatch")
    assert not out.exists()  # never a partial output


def test_folder_without_checkpoint_file(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    _fails(["convert", str(tmp_path / "empty"), str(tmp_path / "out")], capsys, "no 'checkpoint' file")
    assert not (tmp_path / "out").exists()


def test_other_model_and_impossible_arch(tmp_path, capsys):
    write_bundle(tmp_path / "d" / "cp-0000.ckpt", model_tensors(levels=1, semantic=False, zeros=True))
    _fails(
        ["convert", str(tmp_path / "d"), str(tmp_path / "o1"), "--arch", "m4semantic"], capsys, "no semantic decoder"
    )
    import numpy as np

    foreign = {"net/dense/kernel/.ATTRIBUTES/VARIABLE_VALUE": np.ones((2, 2), np.float32)}
    write_bundle(tmp_path / "x" / "cp-0000.ckpt", foreign)
    _fails(["convert", str(tmp_path / "x"), str(tmp_path / "o2")], capsys, "no Co-SemDepth / M4Depth / M4Semantic")
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()


def test_command_line_entry_point(tmp_path):
    """The real command line: ``python -m cosemdepth convert`` (success, then a user error without traceback)."""
    write_bundle(tmp_path / "ck" / "cp-0000.ckpt", model_tensors(levels=1, zeros=True))
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    ok = subprocess.run(
        [sys.executable, "-m", "cosemdepth", "convert", str(tmp_path / "ck"), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert ok.returncode == 0, ok.stderr
    assert (tmp_path / "out" / "model.safetensors").is_file() and (tmp_path / "out" / "config.json").is_file()
    argv = [sys.executable, "-m", "cosemdepth", "convert", str(tmp_path / "nowhere"), str(tmp_path / "o")]
    bad = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120)
    assert bad.returncode == 2
    assert "Traceback" not in bad.stderr and "nowhere" in bad.stderr


def test_missing_arguments_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as e:
        main(["convert", "only-one"])
    assert e.value.code == 2
    assert "OUT_DIR" in capsys.readouterr().err
