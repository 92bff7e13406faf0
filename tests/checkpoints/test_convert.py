"""TF checkpoint -> our state dict + ModelConfig: the real fixture, M4Depth / M4Semantic bundles, ablations, errors.

Expected parameter counts come from design 12.1 (its table and the other configurations below it) or are computed
by hand in the comments from the refiner formula P(C_in, C_out) = 1152·C_in + 336,848 + 145·C_out.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from tf_bundle_writer import SUFFIX, depth_refiner_inputs, model_tensors, refiner_params, write_bundle

from cosemdepth.checkpoints.convert import (
    convert_checkpoint,
    convert_tensors,
    count_parameters,
    expected_param_shapes,
    import_checkpoint,
)
from cosemdepth.checkpoints.tf_checkpoint import read_checkpoint
from cosemdepth.errors import CheckpointError
from cosemdepth.models.config import ModelConfig

# Design 4.1: encoder totals (with the 32 DINL parameters).
ENCODER = {4: 210_544, 5: 468_848, 6: 1_022_192}
# 3 levels: 448 + 32 + 2,320 + 4,640 + 9,248 + 18,496 + 36,928 (design 4.1 table)
ENCODER_L3 = 72_112

# ------------------------------------------------------------------------------------------------------------------
# The real checkpoint


@pytest.fixture(scope="module")
def fixture_conversion(tfref_dir):
    return import_checkpoint(tfref_dir / "ckpt"), read_checkpoint(tfref_dir / "ckpt")


def test_fixture_config_and_parameter_count(fixture_conversion):
    conv, _ = fixture_conversion
    # every switch on; float16 cost-volume products like the original
    assert conv.config == ModelConfig(arch="cosemdepth", levels=5, num_classes=7, pscv_dtype="float16")
    assert conv.num_parameters == 5_202_528
    assert conv.parameters_by_part() == {
        "encoder": 468_848,
        "depth_decoder": 2_591_033,
        "semantic_decoder": 2_142_647,
    }
    assert len(conv.state_dict) == 162
    assert set(conv.state_dict) == set(expected_param_shapes(conv.config))
    assert all(t.dtype == torch.float32 and t.is_contiguous() for t in conv.state_dict.values())
    assert conv.dropped_keys == []


def test_fixture_per_level_refiner_counts(fixture_conversion):
    conv, _ = fixture_conversion
    per_level = {}
    for name, t in conv.state_dict.items():
        if name.startswith(("depth_decoder", "semantic_decoder")):
            part, _, j = name.split(".")[:3]
            per_level[(part, int(j))] = per_level.get((part, int(j)), 0) + t.numel()
    # design 12.1
    assert [per_level["depth_decoder", j] for j in range(5)] == [411_301, 478_117, 478_117, 611_749, 611_749]
    assert [per_level["semantic_decoder", j] for j in range(5)] == [369_547, 387_979, 424_843, 461_707, 498_571]


def test_fixture_tensor_mapping_and_layout(fixture_conversion):
    conv, tf = fixture_conversion
    sd = conv.state_dict
    k = tf["encoder/conv_layers_s1/0/kernel/.ATTRIBUTES/VARIABLE_VALUE"]  # [kh, kw, C_in, C_out] = [3,3,3,16]
    w = sd["encoder.conv_s1.0.weight"]  # [C_out, C_in, kh, kw]
    assert tuple(w.shape) == (16, 3, 3, 3)
    for o, i, y, x in [(0, 0, 0, 0), (15, 2, 2, 1), (7, 1, 0, 2), (3, 2, 1, 0)]:
        assert w[o, i, y, x].item() == k[y, x, i, o]
    est = tf["d_estimator/levels/2/disp_refiner/est_d_conv_layers/1/kernel/.ATTRIBUTES/VARIABLE_VALUE"]
    assert est.shape == (3, 3, 64, 32)
    w = sd["depth_decoder.levels.2.refiner.convs.4.weight"]  # est stack conv 1 = stack position 3 + 1
    assert w[31, 63, 2, 0].item() == est[2, 0, 63, 31]
    np.testing.assert_array_equal(
        sd["semantic_decoder.levels.4.refiner.convs.6.bias"].numpy(),
        tf["s_estimator/levels/4/semantic_refiner/est_s_conv_layers/3/bias/.ATTRIBUTES/VARIABLE_VALUE"],
    )
    np.testing.assert_array_equal(
        sd["encoder.dinl.weight"].numpy(), tf["encoder/dn_layers/0/scale/.ATTRIBUTES/VARIABLE_VALUE"].reshape(16)
    )
    np.testing.assert_array_equal(
        sd["encoder.dinl.bias"].numpy(), tf["encoder/dn_layers/0/bias/.ATTRIBUTES/VARIABLE_VALUE"].reshape(16)
    )
    assert tuple(sd["encoder.dinl.weight"].shape) == (16,)


def test_fixture_ignored_entries(fixture_conversion):
    conv, tf = fixture_conversion
    assert conv.ignored_keys["optimizer/_iterations/.ATTRIBUTES/VARIABLE_VALUE"] == "optimizer"
    assert conv.ignored_keys["step_counter/.ATTRIBUTES/VARIABLE_VALUE"] == "counter"
    assert conv.ignored_keys["depth_metrics/3/count/.ATTRIBUTES/VARIABLE_VALUE"] == "metric"
    assert len(conv.ignored_keys) + len(conv.converted_keys) == len(tf) == 180
    assert conv.source["entries"] == 181 and conv.source["ignored_tensors"] == 19
    assert conv.source["checkpoint"].endswith("cp-0000.ckpt")
    assert conv.source["not_from_checkpoint"] == {"feature_normalization": True, "pscv_dtype": "float16"}


def test_fixture_partial_arch(tfref_dir):
    sd, cfg = convert_checkpoint(tfref_dir / "ckpt", arch="m4depth")
    assert cfg.arch == "m4depth" and cfg.levels == 5
    assert sum(t.numel() for t in sd.values()) == 3_059_881  # design 12.1
    assert not any(k.startswith("semantic_decoder") for k in sd)
    conv = import_checkpoint(tfref_dir / "ckpt", arch="m4semantic")
    assert conv.num_parameters == 2_611_495  # design 12.1
    assert len(conv.dropped_keys) == 70 and all(k.startswith("d_estimator/") for k in conv.dropped_keys)
    assert "arch" not in conv.inferred


# ------------------------------------------------------------------------------------------------------------------
# Bundles written by the test writer


def test_m4depth_four_levels_from_file(tmp_path):
    t = model_tensors(levels=4, semantic=False, seed=1)
    prefix = write_bundle(tmp_path / "train" / "cp-0042.ckpt", t)
    conv = import_checkpoint(tmp_path / "train")
    assert conv.config == ModelConfig(arch="m4depth", levels=4, pscv_dtype="float16")
    assert conv.num_parameters == 2_189_828  # design 12.1 table, L = 4 M4Depth part
    assert "num_classes" not in conv.inferred and "sncv" in conv.inferred
    # inference state variables of both naming schemes and the string object graph are ignored, not converted
    assert conv.ignored_keys[f"d_estimator/levels/0/prev_f_maps{SUFFIX}"] == "inference state"
    assert conv.ignored_keys[f"d_estimator/levels/0/depth_prev_t{SUFFIX}"] == "inference state"
    assert conv.ignored_keys[f"encoder/conv_layers_s1/0/kernel/.OPTIMIZER_SLOT/optimizer/m{SUFFIX}"] == "optimizer slot"
    w = t[f"d_estimator/levels/3/disp_refiner/prep_conv_layers/0/kernel{SUFFIX}"]
    assert w.shape == (3, 3, 238, 128)
    np.testing.assert_array_equal(
        conv.state_dict["depth_decoder.levels.3.refiner.convs.0.weight"].numpy(), w.transpose(3, 2, 0, 1)
    )
    assert conv.source["checkpoint"] == str(prefix.resolve())


def test_m4depth_six_levels_other_root_names(tmp_path):
    """M4Depth's released weights are 6-level; keys are matched below any root attribute name."""
    roots = ("model/feature_pyramid", "model/depth_net", "unused")
    t = model_tensors(levels=6, semantic=False, roots=roots, zeros=True)
    prefix = write_bundle(tmp_path / "m4d" / "cp-0001.ckpt", t)
    conv = import_checkpoint(prefix)
    assert conv.config.arch == "m4depth" and conv.config.levels == 6
    # design 12.1: the original 6-level M4Depth; refiner inputs 64, 122, 122, 238, 238, 470 (design 5.1)
    assert conv.num_parameters == 4_492_238
    assert [conv.state_dict[f"depth_decoder.levels.{j}.refiner.convs.0.weight"].shape[1] for j in range(6)] == [
        64,
        122,
        122,
        238,
        238,
        470,
    ]


def test_m4semantic_twelve_classes(tmp_path):
    t = model_tensors(levels=5, depth=False, classes=12, roots=("encoder", "unused", "semantic_estimator"), zeros=True)
    prefix = write_bundle(tmp_path / "sem" / "cp-0000.ckpt", t)
    conv = import_checkpoint(tmp_path / "sem")
    assert conv.config.arch == "m4semantic" and conv.config.num_classes == 12 and conv.config.levels == 5
    assert conv.num_parameters == 2_643_920  # design 12.1, Aeroscapes M4Semantic
    assert conv.state_dict["semantic_decoder.levels.0.refiner.convs.6.weight"].shape == (16, 16, 3, 3)
    assert conv.source["checkpoint"] == str(prefix.resolve())


def test_m4semantic_six_levels_nine_classes_no_dinl(tmp_path):
    t = model_tensors(levels=6, depth=False, classes=9, dinl=False, zeros=True)
    conv = import_checkpoint(write_bundle(tmp_path / "cp-0003.ckpt", t))
    assert conv.config.arch == "m4semantic" and conv.config.num_classes == 9 and conv.config.levels == 6
    assert conv.config.dinl is False
    # encoder 1,022,192 - 32 (no DINL); semantic inputs 9 + 4 + C_l = 29, 45, 77, 109, 141, 205
    expected = ENCODER[6] - 32 + sum(refiner_params(c, 13) for c in (29, 45, 77, 109, 141, 205))
    assert expected == 3_752_670
    assert conv.num_parameters == expected


def test_joint_nine_classes():
    conv = convert_tensors(model_tensors(levels=5, classes=9, zeros=True))
    assert conv.config == ModelConfig(levels=5, num_classes=9, pscv_dtype="float16")
    assert conv.num_parameters == 5_215_498  # design 12.1, TopAir


def test_m4depth_four_levels_without_sncv(tmp_path):
    t = model_tensors(levels=4, semantic=False, sncv=False, seed=3)
    conv = import_checkpoint(write_bundle(tmp_path / "cp-0000.ckpt", t))
    cfg = conv.config
    assert (cfg.sncv, cfg.time_recurrence, cfg.level_memory, cfg.feature_subdivision) == (False, True, True, True)
    # refiner inputs 9K + 1 + 4 + 1 with K = 1, 2, 2, 4: 15, 24, 24, 42
    assert conv.num_parameters == ENCODER[4] + sum(refiner_params(c, 5) for c in (15, 24, 24, 42)) == 1_681_796


def test_m4depth_heavily_ablated(tmp_path):
    t = model_tensors(
        levels=5, semantic=False, dinl=False, time_recurrence=False, level_memory=False, subdivision=False, zeros=True
    )
    conv = import_checkpoint(write_bundle(tmp_path / "cp-0000.ckpt", t))
    cfg = conv.config
    assert (cfg.dinl, cfg.sncv, cfg.time_recurrence, cfg.level_memory, cfg.feature_subdivision) == (
        False,
        True,
        False,
        False,
        False,
    )
    # refiner inputs 9 + 1 + 49 = 59 at every level (K = 1)
    assert conv.num_parameters == ENCODER[5] - 32 + 5 * refiner_params(59, 5) == 2_496_521


@pytest.mark.parametrize("switches", list(itertools.product((True, False), repeat=4)))
def test_every_depth_ablation_combination_is_recovered(switches):
    sncv, tr, lm, sub = switches
    t = model_tensors(
        levels=3,
        semantic=False,
        sncv=sncv,
        time_recurrence=tr,
        level_memory=lm,
        subdivision=sub,
        extras=False,
        zeros=True,
    )
    cfg = convert_tensors(t).config
    assert (cfg.sncv, cfg.time_recurrence, cfg.level_memory, cfg.feature_subdivision) == switches
    assert count_parameters(cfg) == ENCODER_L3 + sum(
        refiner_params(depth_refiner_inputs(l, sncv, tr, lm, sub), 5) for l in (1, 2, 3)
    )


def test_the_semantic_sncv_is_read_from_the_refiner_inputs_and_other_layouts_are_refused():
    assert convert_tensors(model_tensors(levels=2, depth=False, zeros=True)).config.semantic_sncv is False
    cfg = convert_tensors(model_tensors(levels=2, depth=False, zeros=True, semantic_extra=49)).config
    assert cfg.semantic_sncv is True and cfg.semantic_time == "off"
    # N + 1 more channels would be a previous-frame input, which the authors' code does not have
    with pytest.raises(CheckpointError, match=r"semantic refiner input channels \[35, 51\].*S\^\{t-1\}"):
        convert_tensors(model_tensors(levels=2, depth=False, zeros=True, semantic_extra=8))


def test_one_level_model_subdivision_is_indistinguishable():
    """With one level K = 1 either way; the default (on) is kept."""
    cfg = convert_tensors(model_tensors(levels=1, semantic=False, subdivision=False, zeros=True)).config
    assert cfg.levels == 1 and cfg.feature_subdivision is True


def test_settings_without_weights_come_from_the_caller():
    t = model_tensors(levels=2, zeros=True)
    assert convert_tensors(t).config.feature_normalization is True
    assert convert_tensors(t, feature_normalization=False).config.feature_normalization is False
    assert convert_tensors(t).config.pscv_dtype == "float16"
    assert convert_tensors(t, pscv_dtype="float32").config.pscv_dtype == "float32"


def test_arch_subset_of_joint_and_impossible_arch():
    t = model_tensors(levels=2, zeros=True)
    conv = convert_tensors(t, arch="m4depth")
    assert conv.config.arch == "m4depth"
    assert all(k.startswith("s_estimator/") for k in conv.dropped_keys) and len(conv.dropped_keys) == 28
    with pytest.raises(CheckpointError, match="no semantic decoder.*cannot be loaded as cosemdepth"):
        convert_tensors(model_tensors(levels=2, semantic=False, zeros=True), arch="cosemdepth")
    with pytest.raises(CheckpointError, match="no depth decoder.*cannot be loaded as m4depth"):
        convert_tensors(model_tensors(levels=2, depth=False, zeros=True), arch="m4depth")


# ------------------------------------------------------------------------------------------------------------------
# Errors


def _small() -> dict:
    return model_tensors(levels=2, zeros=True)


def test_missing_tensor():
    t = _small()
    del t[f"s_estimator/levels/1/semantic_refiner/est_s_conv_layers/2/bias{SUFFIX}"]
    with pytest.raises(CheckpointError, match=r"missing weights 'semantic_decoder\.levels\.1\.refiner\.convs\.5\."):
        convert_tensors(t, origin="my.ckpt")


def test_wrong_shape_names_the_tf_key():
    t = _small()
    key = f"encoder/conv_layers_s2/1/kernel{SUFFIX}"
    t[key] = np.zeros((3, 3, 32, 33), np.float32)
    with pytest.raises(
        CheckpointError,
        match=r"my\.ckpt: .*wrong shapes: 'encoder/conv_layers_s2/1/kernel.*"
        r"has shape \[3, 3, 32, 33\], expected \[3, 3, 32, 32\]",
    ):
        convert_tensors(t, origin="my.ckpt")


def test_dinl_with_wrong_shape():
    t = _small()
    t[f"encoder/dn_layers/0/scale{SUFFIX}"] = np.ones(16, np.float32)
    with pytest.raises(CheckpointError, match=r"expected \[1, 1, 1, 16\]"):
        convert_tensors(t)


def test_unexpected_weight_tensors():
    t = _small()
    t[f"encoder/extra_head/kernel{SUFFIX}"] = np.zeros((3, 3, 16, 4), np.float32)
    with pytest.raises(CheckpointError, match="unexpected tensors 'encoder/extra_head/kernel"):
        convert_tensors(t)
    t = _small()
    t[f"encoder/dn_layers/1/scale{SUFFIX}"] = np.ones((1, 1, 1, 32), np.float32)  # DINL only exists at level 1
    with pytest.raises(CheckpointError, match="unexpected tensors 'encoder/dn_layers/1/scale"):
        convert_tensors(t)
    t = _small()
    t[f"d_estimator/levels/0/disp_refiner/est_d_conv_layers/4/kernel{SUFFIX}"] = np.zeros((3, 3, 5, 5), np.float32)
    with pytest.raises(CheckpointError, match="unexpected tensors 'd_estimator/levels/0/disp_refiner/est_d_conv_l"):
        convert_tensors(t)


def test_checkpoint_of_another_model(tmp_path):
    t = {
        f"backbone/dense/kernel{SUFFIX}": np.zeros((4, 4), np.float32),
        f"backbone/dense/bias{SUFFIX}": np.zeros(4, np.float32),
        f"step_counter{SUFFIX}": np.array(3, np.int64),
    }
    prefix = write_bundle(tmp_path / "other" / "cp-0000.ckpt", t)
    with pytest.raises(CheckpointError, match="no Co-SemDepth / M4Depth / M4Semantic weights found") as e:
        import_checkpoint(tmp_path / "other")
    assert str(prefix) in str(e.value)


def test_encoder_without_decoder():
    t = {k: v for k, v in _small().items() if k.startswith("encoder/")}
    with pytest.raises(CheckpointError, match="an encoder but no decoder"):
        convert_tensors(t)


def test_decoder_without_encoder():
    t = {k: v for k, v in _small().items() if not k.startswith("encoder/")}
    with pytest.raises(CheckpointError, match="no encoder weights"):
        convert_tensors(t)


def test_decoder_level_count_differs_from_encoder():
    t = model_tensors(levels=3, zeros=True, extras=False)
    t = {k: v for k, v in t.items() if "s_estimator/levels/2/" not in k}
    with pytest.raises(CheckpointError, match="the encoder has 3 levels but the semantic decoder has 2"):
        convert_tensors(t)


def test_gap_in_levels():
    t = model_tensors(levels=3, zeros=True, extras=False)
    t = {k: v for k, v in t.items() if "d_estimator/levels/1/" not in k}
    with pytest.raises(CheckpointError, match=r"depth decoder level indices \[0, 2\] are not 0..1"):
        convert_tensors(t)


def test_two_encoders_are_ambiguous():
    t = _small()
    t.update(
        {
            k.replace("encoder/", "encoder_copy/"): v
            for k, v in model_tensors(levels=2, zeros=True).items()
            if k.startswith("encoder/conv")
        }
    )
    with pytest.raises(CheckpointError, match="encoder weights under several roots"):
        convert_tensors(t)


def test_refiner_channels_matching_no_ablation():
    t = model_tensors(levels=2, semantic=False, zeros=True, extras=False)
    for j, c_in in ((0, 63), (1, 120)):  # 120 at l = 2 fits no switch combination (K = 2 or 1)
        key = f"d_estimator/levels/{j}/disp_refiner/prep_conv_layers/0/kernel{SUFFIX}"
        t[key] = np.zeros((3, 3, c_in, 128), np.float32)
    with pytest.raises(CheckpointError, match=r"input channels \[63, 120\].*match no combination"):
        convert_tensors(t)


def test_integer_weights_are_rejected():
    t = _small()
    key = f"encoder/conv_layers_s1/0/bias{SUFFIX}"
    t[key] = np.zeros(16, np.int32)
    with pytest.raises(CheckpointError, match="dtype int32, expected a floating-point type"):
        convert_tensors(t)


def test_too_few_classes():
    t = model_tensors(levels=1, depth=False, classes=1, zeros=True)
    with pytest.raises(CheckpointError, match="last semantic conv has 5 channels"):
        convert_tensors(t)


def test_float16_weights_are_converted_to_float32():
    t = {
        k: (v.astype(np.float16) if isinstance(v, np.ndarray) and v.dtype == np.float32 else v)
        for k, v in model_tensors(levels=1, seed=5).items()
    }
    conv = convert_tensors(t)
    w = conv.state_dict["encoder.conv_s1.0.bias"]
    assert w.dtype == torch.float32
    np.testing.assert_array_equal(w.numpy(), t[f"encoder/conv_layers_s1/0/bias{SUFFIX}"].astype(np.float32))
