"""resolve_device: the one device-name check (train.device and every --device); bf16 convolutions and the commands
that refuse bf16 without them; the host allocator setting."""

import subprocess
import sys

import pytest
import torch

import cosemdepth.devices as devices
from cosemdepth.devices import bf16_convolutions, resolve_device
from cosemdepth.errors import ConfigError


def test_accepted_names():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto") == torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if torch.cuda.is_available():
        assert resolve_device("cuda:0", "train.device") == torch.device("cuda:0")


@pytest.mark.parametrize(
    "name, message",
    [
        ("gpu", r"^--device: not a device name: 'gpu' \(auto, cpu, cuda\[:N\] or mps\)$"),
        ("", r"^--device: not a device name: ''"),
        ("meta", r"^--device: unsupported device 'meta'"),
        ("xpu", r"^--device: unsupported device 'xpu'"),
    ],
)
def test_refused_names(name, message):
    with pytest.raises(ConfigError, match=message) as e:
        resolve_device(name)
    assert "\n" not in str(e.value)


def test_names_the_argument_and_refuses_missing_accelerators():
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match=r"^train.device cuda:1: CUDA is not available"):
            resolve_device("cuda:1", "train.device")
    else:
        n = torch.cuda.device_count()
        with pytest.raises(ConfigError, match=rf"^train.device cuda:{n}: only {n} CUDA device"):
            resolve_device(f"cuda:{n}", "train.device")
    if not (torch.backends.mps.is_available()):
        with pytest.raises(ConfigError, match=r"^--device mps: MPS is not available"):
            resolve_device("mps")


def test_bf16_convolutions_by_device_and_onednn(monkeypatch):
    assert bf16_convolutions("cuda") and not bf16_convolutions("mps")
    with torch.backends.mkldnn.flags(enabled=False):
        assert bf16_convolutions("cpu")  # PyTorch's own kernels take bf16 anywhere
        x = torch.randn(1, 2, 5, 5, dtype=torch.bfloat16)
        assert torch.nn.functional.conv2d(x, torch.ones(3, 2, 3, 3, dtype=torch.bfloat16)).dtype == torch.bfloat16
    monkeypatch.setattr(devices, "_onednn_bf16", lambda: False)
    assert bf16_convolutions("cpu") == (not devices.onednn_enabled())
    monkeypatch.setattr(devices, "_onednn_bf16", lambda: True)
    assert bf16_convolutions("cpu")


@pytest.fixture
def no_bf16(monkeypatch):
    """A CPU whose oneDNN has no bf16 convolutions (as an AVX2-only one), whatever this one has."""
    monkeypatch.setattr(devices, "_onednn_bf16", lambda: False)
    if not devices.onednn_enabled():
        pytest.fail("these checks need oneDNN (the CPU build of PyTorch has it)")


def test_without_bf16_convolutions_training_and_the_fast_path_refuse_bf16_in_one_line(no_bf16, tmp_path, capsys):
    from cosemdepth.checkpoints.model_io import save_model
    from cosemdepth.cli.main import main
    from cosemdepth.inference.engine import FastEngine
    from cosemdepth.jobs.model import load
    from cosemdepth.models import build_model

    out = tmp_path / "run"
    assert main(["train", "--out", str(out), "--dataset", "toy", "--device", "cpu", "--bf16", "--max-steps", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "train.bf16 (--bf16)" in err and "bfloat16 convolutions" in err, err
    assert not out.exists()  # nothing written
    m = build_model(arch="m4semantic").eval()
    with pytest.raises(ValueError, match="bfloat16 convolutions"):
        FastEngine(m, dtype="bf16")
    with pytest.raises(ValueError, match="bfloat16 convolutions"):
        FastEngine(m, dtype="int8", int8_float_dtype="bf16")
    FastEngine(m, dtype="int8")  # int8 keeps its float refiners in float32 here
    model_dir = save_model(m, tmp_path / "m")
    with pytest.raises(ConfigError, match=r"^--precision bf16: bfloat16 needs bfloat16 convolutions"):
        load(model_dir, "cpu", precision="bf16")
    assert main(["benchmark", "--device", "cpu", "--precision", "bf16", "--json", "", "--md", ""]) == 2
    assert "--precision bf16: oneDNN has no bfloat16 convolutions" in capsys.readouterr().err


_FAULTS = r"""
import resource, sys, torch
from cosemdepth.devices import retain_freed_host_memory
if sys.argv[1] == "retain":
    assert retain_freed_host_memory()
torch.set_num_threads(1)
net = torch.nn.Sequential(torch.nn.Conv2d(16, 64, 3, padding=1), torch.nn.LeakyReLU(0.1),
                          torch.nn.Conv2d(64, 64, 3, padding=1), torch.nn.LeakyReLU(0.1),
                          torch.nn.Conv2d(64, 1, 3, padding=1))
x = torch.randn(4, 16, 96, 96)  # activations of 9.4 MB
def step():
    net.zero_grad(set_to_none=True)
    net(x).square().mean().backward()
step(); step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    step()
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 5)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_retained_memory_is_not_faulted_in_again():
    # fresh interpreters (the setting is process-wide), the same small training step: by default glibc maps the
    # step's multi-MB activations afresh every step (measured ~25,000 page faults a step); retained, the freed
    # blocks are reused (~500)
    def faults(mode):
        out = subprocess.run([sys.executable, "-c", _FAULTS, mode], capture_output=True, text=True, check=True)
        return float(out.stdout.strip())

    default, retained = faults("default"), faults("retain")
    assert default > 5000
    assert retained < 0.1 * default
