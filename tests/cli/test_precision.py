import pytest
import torch

from cosemdepth.checkpoints.model_io import save_model
from cosemdepth.cli.main import main
from cosemdepth.errors import ConfigError
from cosemdepth.inference import FastModel
from cosemdepth.jobs.model import load
from cosemdepth.models import SceneModel, build_model


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    torch.manual_seed(0)
    return save_model(build_model(), tmp_path_factory.mktemp("m") / "model")


@pytest.mark.parametrize("precision,dtype", [("fp32", torch.float32), ("bf16", torch.bfloat16), ("int8", "int8")])
def test_load_selects_the_fast_path_in_the_precision(model_dir, precision, dtype, request):
    if precision == "bf16":
        request.getfixturevalue("bf16_cpu")  # PyTorch's own bf16 kernels on a CPU where oneDNN has none
    model, _ = load(model_dir, "cpu", precision=precision)
    assert isinstance(model, FastModel) and model.dtype == dtype
    if dtype == "int8":
        assert model.engine.int8 and not model.engine.calibrated  # calibrates on the first frames it sees
    else:
        assert model.engine.dtype == dtype and not model.engine.int8


def test_reference_with_a_reduced_precision_is_a_user_error(model_dir):
    with pytest.raises(ConfigError, match="--precision int8 is a setting of the fast path: drop --reference"):
        load(model_dir, "cpu", fast=False, precision="int8")
    model, _ = load(model_dir, "cpu", fast=False, precision="fp32")
    assert isinstance(model, SceneModel) and not model.training


@pytest.mark.parametrize("cmd", ["predict", "evaluate"])
def test_unknown_precision_exits_2(cmd, model_dir, capsys):
    with pytest.raises(SystemExit) as e:
        main([cmd, "--model", str(model_dir), "--precision", "int4"])
    assert e.value.code == 2
    assert "--precision" in capsys.readouterr().err
