"""resolve_device: the one device-name check (train.device and every --device)."""

import pytest
import torch

from cosemdepth.devices import resolve_device
from cosemdepth.errors import ConfigError


def test_accepted_names():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto") == torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if torch.cuda.is_available():
        assert resolve_device("cuda:0", "train.device") == torch.device("cuda:0")


@pytest.mark.parametrize("name, message", [
    ("gpu", r"^--device: not a device name: 'gpu' \(auto, cpu, cuda\[:N\] or mps\)$"),
    ("", r"^--device: not a device name: ''"),
    ("meta", r"^--device: unsupported device 'meta'"),
    ("xpu", r"^--device: unsupported device 'xpu'"),
])
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
