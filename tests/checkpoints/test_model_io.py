"""Our model folder format (config.json + model.safetensors) and load_model / save_model."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import save_file
from tf_bundle_writer import model_tensors, write_bundle

from cosemdepth.checkpoints.convert import convert_checkpoint, expected_param_shapes
from cosemdepth.checkpoints.model_io import load_model, read_model_files, save_model, save_weights
from cosemdepth.errors import CheckpointError, ConfigError
from cosemdepth.models.config import ModelConfig

SMALL = ModelConfig(arch="cosemdepth", levels=2, num_classes=5)


def _random_state(cfg: ModelConfig) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return {k: torch.randn(s, generator=g) for k, s in expected_param_shapes(cfg).items()}


# ------------------------------------------------------------------------------------------------------------------
# Writing and reading the files


def test_round_trip(tmp_path):
    sd = _random_state(SMALL)
    out = save_weights(sd, SMALL, tmp_path / "runs" / "model", source={"type": "test", "note": "round trip"})
    assert sorted(os.listdir(out)) == ["config.json", "model.safetensors"]  # no temporary files left
    sd2, cfg, meta = read_model_files(out)
    assert cfg == SMALL
    assert sd2.keys() == sd.keys()
    for k in sd:
        assert torch.equal(sd[k], sd2[k]), k
    assert meta["source"] == {"type": "test", "note": "round trip"}
    # the other two ways to name the folder
    assert read_model_files(out / "config.json")[1] == SMALL
    assert read_model_files(out / "model.safetensors")[1] == SMALL


def test_saved_files_get_the_umask_permissions(tmp_path):
    # safetensors writes its files 0600; shipped weights must be readable like any other file the user writes
    old = os.umask(0o022)
    try:
        out = save_weights(_random_state(SMALL), SMALL, tmp_path / "model")
    finally:
        os.umask(old)
    for name in ("config.json", "model.safetensors"):
        assert (out / name).stat().st_mode & 0o777 == 0o644, name


def test_config_json_content(tmp_path):
    cfg = ModelConfig(arch="m4depth", levels=3, sncv=False)
    save_weights(_random_state(cfg), cfg, tmp_path)
    meta = json.loads((tmp_path / "config.json").read_text())
    assert meta["format"] == "cosemdepth" and meta["format_version"] == 1
    assert meta["model"] == {
        "arch": "m4depth",
        "levels": 3,
        "num_classes": 7,
        "dinl": True,
        "sncv": False,
        "time_recurrence": True,
        "feature_normalization": True,
        "feature_subdivision": True,
        "level_memory": True,
        "pscv_dtype": "float32",
        "semantic_sncv": False,
        "semantic_time": "off",
        "semantic_fusion": 0.0,
    }
    assert meta["source"] == {}
    assert meta["num_parameters"] == sum(s.numel() for s in _random_state(cfg).values())


def test_overwrite_replaces_both_files(tmp_path):
    save_weights(_random_state(SMALL), SMALL, tmp_path)
    other = ModelConfig(arch="m4semantic", levels=1, num_classes=3)
    sd = _random_state(other)
    save_weights(sd, other, tmp_path)
    sd2, cfg, _ = read_model_files(tmp_path)
    assert cfg == other and sd2.keys() == sd.keys()


def test_out_dir_is_a_file(tmp_path):
    f = tmp_path / "model"
    f.write_text("keep me")
    with pytest.raises(CheckpointError, match="exists and is not a folder"):
        save_weights(_random_state(SMALL), SMALL, f)
    assert f.read_text() == "keep me"


def test_mismatched_state_dict_writes_nothing(tmp_path):
    sd = _random_state(SMALL)
    sd["encoder.conv_s1.0.weight"] = torch.zeros(16, 3, 5, 5)
    del sd["encoder.dinl.bias"]
    with pytest.raises(CheckpointError, match=r"missing encoder\.dinl\.bias.*shape mismatch: encoder\.conv_s1\.0\."):
        save_weights(sd, SMALL, tmp_path / "a" / "b")
    assert not (tmp_path / "a").exists()


def test_failed_write_leaves_no_partial_output(tmp_path, full_disk):
    import errno

    full_disk(tmp_path, room=1000)  # the weights run out of room part-way
    with pytest.raises(OSError) as e:
        save_weights(_random_state(SMALL), SMALL, tmp_path / "new" / "model")
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(tmp_path / "new" / "model" / "model.safetensors")
    assert not (tmp_path / "new").exists()
    existing = tmp_path / "existing"
    existing.mkdir()
    with pytest.raises(OSError, match="No space left"):
        save_weights(_random_state(SMALL), SMALL, existing)
    assert os.listdir(existing) == []


@pytest.fixture()
def saved(tmp_path):
    return save_weights(_random_state(SMALL), SMALL, tmp_path / "m")


def test_missing_folder(tmp_path):
    with pytest.raises(CheckpointError, match="model folder not found"):
        read_model_files(tmp_path / "nope")


def test_missing_config(saved):
    (saved / "config.json").unlink()
    with pytest.raises(CheckpointError, match=r"config\.json: not found"):
        read_model_files(saved)


def test_corrupt_config(saved):
    (saved / "config.json").write_text('{"format": "cosemdepth", ')
    with pytest.raises(CheckpointError, match=r"config\.json: corrupt model config"):
        read_model_files(saved)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda m: m.update(format="something-else"), "not a cosemdepth model config"),
        (lambda m: m.update(format_version=2), "format_version 2 is newer"),
        (lambda m: m.update(format_version="1"), "bad format_version"),
        (lambda m: m["model"].update(levels=9), r"invalid \"model\" entry: model levels"),
        (lambda m: m["model"].update(colour="red"), r"invalid \"model\" entry: unknown config key 'model.colour'"),
        (lambda m: m.pop("model"), r"invalid \"model\" entry"),
    ],
)
def test_bad_config_values(saved, edit, message):
    meta = json.loads((saved / "config.json").read_text())
    edit(meta)
    (saved / "config.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match=message) as e:
        read_model_files(saved)
    assert str(saved / "config.json") in str(e.value)


def test_missing_weights(saved):
    (saved / "model.safetensors").unlink()
    with pytest.raises(CheckpointError, match=r"model\.safetensors: not found"):
        read_model_files(saved)


def test_corrupt_weights(saved):
    (saved / "model.safetensors").write_bytes(b"\x00\x01garbage" * 10)
    with pytest.raises(CheckpointError, match=r"model\.safetensors: corrupt or truncated"):
        read_model_files(saved)


def test_truncated_weights(saved):
    f = saved / "model.safetensors"
    f.write_bytes(f.read_bytes()[:-1000])
    with pytest.raises(CheckpointError, match=r"model\.safetensors: corrupt or truncated"):
        read_model_files(saved)


def test_weights_not_matching_config(saved):
    sd = _random_state(SMALL)
    sd["semantic_decoder.levels.1.refiner.convs.6.weight"] = torch.zeros(10, 16, 3, 3)
    save_file(sd, str(saved / "model.safetensors"))
    with pytest.raises(
        CheckpointError,
        match=r"model\.safetensors: .*shape mismatch: "
        r"semantic_decoder\.levels\.1\.refiner\.convs\.6\.weight has shape "
        r"\[10, 16, 3, 3\], expected \[9, 16, 3, 3\]",
    ):
        read_model_files(saved)


def test_converted_fixture_round_trip(tfref_dir, tmp_path):
    sd, cfg = convert_checkpoint(tfref_dir / "ckpt")
    save_weights(sd, cfg, tmp_path)
    sd2, cfg2, meta = read_model_files(tmp_path)
    assert cfg2 == cfg and meta["num_parameters"] == 5_202_528
    assert all(torch.equal(sd[k], sd2[k]) for k in sd)


# ------------------------------------------------------------------------------------------------------------------
# With the model (cosemdepth.models.build_model)


CONFIGS = [
    ModelConfig(),
    ModelConfig(arch="m4depth", levels=4, sncv=False, dinl=False),
    ModelConfig(arch="m4depth", levels=3, time_recurrence=False, level_memory=False, feature_subdivision=False),
    ModelConfig(arch="m4semantic", levels=6, num_classes=12),
]


@pytest.mark.parametrize("cfg", CONFIGS, ids=lambda c: f"{c.arch}-L{c.levels}")
def test_model_parameters_match_the_converter(cfg):
    """The model's parameter names and shapes are exactly those the converter and the file format expect."""
    from cosemdepth.models import build_model

    model = build_model(cfg)
    assert {k: tuple(v.shape) for k, v in model.state_dict().items()} == expected_param_shapes(cfg)


def test_save_model_and_load_model(tmp_path):
    from cosemdepth.models import build_model

    cfg = ModelConfig(arch="cosemdepth", levels=2, num_classes=6, sncv=False)
    model = build_model(cfg)
    out = save_model(model, tmp_path / "m", source={"type": "test"})
    loaded = load_model(out)  # a FastModel: its weights are those of its model
    assert loaded.config == cfg
    assert not loaded.model.training
    ref = model.state_dict()
    for k, v in loaded.model.state_dict().items():
        assert torch.equal(v, ref[k]), k
    assert all(p.device.type == "cpu" for p in loaded.parameters())


def test_save_model_needs_a_config(tmp_path):
    with pytest.raises(ConfigError, match="ModelConfig"):
        save_model(torch.nn.Linear(2, 2), tmp_path)


def test_load_model_from_tf_checkpoint(tfref_dir):
    model = load_model(tfref_dir / "ckpt")
    assert model.config == ModelConfig(pscv_dtype="float16")
    assert sum(p.numel() for p in model.parameters()) == 5_202_528
    sd, _ = convert_checkpoint(tfref_dir / "ckpt")
    got = model.model.state_dict()
    assert all(torch.equal(got[k], sd[k]) for k in sd)


def test_load_model_from_written_m4depth_checkpoint(tmp_path):
    t = model_tensors(levels=1, semantic=False, seed=2)
    prefix = write_bundle(tmp_path / "train" / "cp-0007.ckpt", t)
    for path in (tmp_path / "train", prefix, f"{prefix}.index"):
        model = load_model(path)
        assert model.config.arch == "m4depth" and model.config.levels == 1
    bias = model.model.state_dict()["depth_decoder.levels.0.refiner.convs.6.bias"]
    np.testing.assert_array_equal(
        bias.numpy(), t["d_estimator/levels/0/disp_refiner/est_d_conv_layers/3/bias/.ATTRIBUTES/VARIABLE_VALUE"]
    )


def test_load_model_errors(tmp_path):
    with pytest.raises(CheckpointError, match="model folder not found"):
        load_model(tmp_path / "missing")
    with pytest.raises(CheckpointError, match="neither a cosemdepth model folder.*nor a TensorFlow checkpoint"):
        load_model(tmp_path)
    from cosemdepth.models import build_model

    folder = save_model(build_model(levels=2), tmp_path / "m")
    with pytest.raises(ValueError, match=r"^dtype must be one of \[.*'fp32', 'int8'\] .*got 'int4'$"):
        load_model(folder, dtype="int4")  # every value it takes, int8 included


def test_converted_checkpoint_reproduces_tensorflow_outputs(tfref_dir):
    """End to end: the TF checkpoint loaded through the converter gives the outputs the authors' TF code computed
    with it (streaming, every frame of the fixture). Semantic probabilities agree to float32 rounding; depth agrees
    closely except in rare pixels where TF's float16 / oneDNN arithmetic differs (fixture README)."""
    ref = np.load(tfref_dir / "reference.npz")
    model = load_model(tfref_dir / "ckpt")
    intrinsics = torch.from_numpy(np.concatenate([ref["camera_f"], ref["camera_c"]], -1))  # [B,4] (fx, fy, cx, cy)
    state = None
    with torch.no_grad():
        for t in range(ref["rgb"].shape[0]):
            out, state = model.step(
                torch.from_numpy(ref["rgb"][t]).permute(0, 3, 1, 2),
                torch.from_numpy(ref["rot"][t]),
                torch.from_numpy(ref["trans"][t]),
                intrinsics,
                torch.from_numpy(ref["new_traj"][t].astype(bool)),
                state,
            )
            sem = torch.from_numpy(ref["infer_semantic"][t]).permute(0, 3, 1, 2)
            depth = torch.from_numpy(ref["infer_depth"][t]).permute(0, 3, 1, 2)
            assert (out.semantic - sem).abs().max().item() < 1e-5, t
            rel = ((out.depth - depth).abs() / depth.abs().clamp_min(1e-3)).flatten()
            if t == 0:
                assert torch.all(out.depth == 1000.0)  # reset frame
            assert rel.median().item() < 1e-4, t
            assert rel.quantile(0.99).item() < 2e-2, t


def test_weights_stored_in_float16_load_as_float32(tmp_path):
    from cosemdepth.models import build_model

    cfg = ModelConfig(arch="m4semantic", levels=2, num_classes=3)
    model = build_model(cfg)
    half = {k: v.half() for k, v in model.state_dict().items()}
    save_weights(half, cfg, tmp_path / "m")
    loaded = load_model(tmp_path / "m", mode="reference")
    for k, v in loaded.state_dict().items():
        assert v.dtype == torch.float32, k
        assert torch.equal(v, half[k].float()), k


def test_a_changed_byte_in_saved_weights_is_refused_by_its_checksum(tmp_path):
    """save_model records the SHA-256 of model.safetensors in config.json; a flipped byte (which may still decode
    to finite weights) is refused on load, naming the file; a folder without the key (older) still loads."""
    import json

    from cosemdepth.checkpoints.model_io import WEIGHTS_CHECKSUM, load_model, save_model
    from cosemdepth.models import build_model

    out = save_model(build_model(arch="m4semantic"), tmp_path / "m")
    meta = json.loads((out / "config.json").read_text())
    assert len(meta[WEIGHTS_CHECKSUM]) == 64
    load_model(out)
    w = out / "model.safetensors"
    data = bytearray(w.read_bytes())
    data[-5] ^= 0x01  # the last bytes of the tensor data: still a valid, finite float32
    w.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match=r"model\.safetensors: checksum mismatch"):
        load_model(out)
    del meta[WEIGHTS_CHECKSUM]
    (out / "config.json").write_text(json.dumps(meta))
    load_model(out)  # no recorded checksum: shapes and finiteness are still checked, the flip is not detectable


def test_shipped_weights_carry_their_checksum():
    import hashlib
    import json

    from cosemdepth.checkpoints.model_io import WEIGHTS_CHECKSUM

    folder = Path(__file__).resolve().parents[2] / "weights" / "synthair-cosemdepth"
    meta = json.loads((folder / "config.json").read_text())
    assert meta[WEIGHTS_CHECKSUM] == hashlib.sha256((folder / "model.safetensors").read_bytes()).hexdigest()


# ------------------------------------------------------------------------------------------------------------------
# The operating point (config.json "operating_point")


def _op(**kw):
    from cosemdepth.operating_point import MotionStats, OperatingPoint

    motion = MotionStats.from_samples([0.5, 1.0, 1.5, 2.0])
    return OperatingPoint(kw.pop("size", (96, 128)), kw.pop("focal", (64.0, 48.0)), motion, "test", **kw)


def test_operating_point_round_trip(tmp_path):
    from cosemdepth.checkpoints.model_io import operating_point_of, read_operating_point

    op = _op()
    out = save_weights(_random_state(SMALL), SMALL, tmp_path / "m", operating_point=op)
    meta = json.loads((out / "config.json").read_text())
    written = dict(meta["operating_point"])
    motion = written.pop("step_translation_m")
    assert written == {"size": [96, 128], "focal_px": [64.0, 48.0], "source": "test"}
    # numpy's linear quantiles of 0.5, 1, 1.5, 2 by hand
    assert motion == pytest.approx(
        {"count": 4, "mean": 1.25, "median": 1.25, "p05": 0.575, "p25": 0.875, "p75": 1.625, "p95": 1.925}, rel=1e-12
    )
    assert read_operating_point(meta) == op and operating_point_of(out) == op
    loaded = load_model(out)
    assert loaded.operating_point == op
    # save_model keeps the model's own operating point
    again = save_model(loaded, tmp_path / "again")
    assert read_operating_point(read_model_files(again)[2]) == op
    # a model without one writes none
    plain = save_weights(_random_state(SMALL), SMALL, tmp_path / "plain")
    assert "operating_point" not in json.loads((plain / "config.json").read_text())
    assert load_model(plain).operating_point is None


@pytest.mark.parametrize(
    "source, size",
    [
        ({"size": 96}, (96, 96)),
        ({"data": {"size": 64}}, (64, 64)),
        ({"run_config": {"data": {"size": [128, 128]}}}, (128, 128)),  # what scripts/ship_weights.py records
        ({"run_config": {"data": {"size": [128, 96]}}}, (128, 96)),
        ({"type": "tensorflow"}, None),
        ({"size": True}, None),
    ],
)
def test_a_folder_without_an_operating_point_falls_back_to_its_training_size(source, size):
    from cosemdepth.checkpoints.model_io import read_operating_point

    op = read_operating_point({"source": source})
    if size is None:
        assert op is None
        return
    h, w = size
    # the 90-degree camera of the Mid-Air-format datasets: f = W/2 (and H/2), no motion statistics
    assert op.size == size and op.focal_px == (w / 2, h / 2) and op.step_translation is None
    assert op.hfov_deg == pytest.approx(90.0)


def test_a_malformed_operating_point_is_refused_naming_the_file(tmp_path):
    out = save_weights(_random_state(SMALL), SMALL, tmp_path / "m", operating_point=_op())
    meta = json.loads((out / "config.json").read_text())
    meta["operating_point"]["focal_px"] = [-1, 64]
    (out / "config.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match=r"config\.json: invalid \"operating_point\" entry.*focal_px"):
        load_model(out)


def test_a_tensorflow_checkpoint_gets_mid_air_s_operating_point(tfref_dir):
    from cosemdepth.checkpoints.model_io import operating_point_of

    op = load_model(tfref_dir / "ckpt").operating_point
    assert op.size == (384, 384) and op.focal_px == (192.0, 192.0) and op.hfov_deg == pytest.approx(90.0)
    assert op.step_translation is not None and operating_point_of(tfref_dir / "ckpt") == op


def test_mid_air_s_motion_statistics_fit_the_spec():
    from cosemdepth.checkpoints.convert import MIDAIR_STEP_TRANSLATION as m

    # design 2.2: in the shipped Mid-Air CSVs ||t|| ranges from 0.044 to 3.8 m and t_z has a median of +1.48 m
    assert 0.044 <= m.p05 < m.p25 < m.median < m.p75 < m.p95 <= 3.8
    assert 1.48 <= m.median <= 3.8 and m.count == 3 * (m.count // 3)  # three steps per 4-row window


def test_shipped_weights_record_their_operating_point():
    from cosemdepth.checkpoints.model_io import operating_point_of

    folder = Path(__file__).resolve().parents[2] / "weights" / "synthair-cosemdepth"
    op = operating_point_of(folder)
    assert op.size == (128, 128) and op.focal_px == (64.0, 64.0)
    assert op.step_translation is not None and op.step_translation.count == 6 * 2 * 3 * 24 * 3  # worlds x climates
    # x trajectories x 4-row chunks of 99 rows x 3 steps
