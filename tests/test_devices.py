"""resolve_device: the one device-name check (train.device and every --device); the host allocator setting."""

import subprocess
import sys

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
