"""How much memory a model needs at an input size, from the shapes of its per-level activations (nothing is run).

The estimate reads the model's module tree (a model built on the meta device will do) and counts, in float32:

* the network input ``[B, 3, H, W]`` and the decoders' heads, upsampled to ``H x W``;
* every map the encoder produces: its stride-1 convolution at level ``k`` runs on level ``k``'s grid
  (``ceil(H / 2^k) x ceil(W / 2^k)``, level 0 being the input), its stride-2 convolution writes level ``k + 1``;
* the maps of each decoder level (at ``ceil(H / 2^l) x ceil(W / 2^l)``): the refiner's input and the output of every
  convolution of the level.

A streaming step runs the decoders one after the other and frees a decoder's maps before the next one runs, so it
needs the encoder's maps plus those of its widest decoder; a training step keeps every map of every decoder and every
frame of the window for the backward pass. The weights (and, when training, their gradients and two Adam moments)
come on top. Cost-volume temporaries are not counted: the finest refiner's maps dominate them.

:func:`check_size` is the one size check of the commands that take a size (predict, evaluate, view, demo, export,
benchmark, train): a hard pixel cap, then the estimate against the memory available on the device.
"""

from __future__ import annotations

import torch.nn as nn

from ..devices import available_memory
from ..errors import ConfigError
from .model import SceneModel

#: Largest network input, in pixels (8192 x 8192), whatever the memory: the readers decode at most this many
#: pixels per image (``cosemdepth.data.decode.MAX_PIXELS``), and the model's coarsest grid is already 256x256 there.
MAX_INPUT_PIXELS = 1 << 26
#: Bytes per activation value (the estimate is for float32; bf16 and int8 paths need less).
VALUE_BYTES = 4
#: Values kept per weight while training: the weight, its gradient and Adam's two moments.
TRAINING_VALUES_PER_WEIGHT = 4


def _grid(height: int, width: int, level: int) -> int:
    """Pixels of level ``level``'s grid (level 0: the input)."""
    return -(-height // 2**level) * -(-width // 2**level)


def _convs(module: nn.Module) -> list[nn.Conv2d]:
    return [m for m in module.modules() if isinstance(m, nn.Conv2d)]


def encoder_values(model: SceneModel, height: int, width: int) -> int:
    """Values of every map the encoder of ``model`` produces for one ``height x width`` image."""
    enc = model.encoder
    total = 0
    for k, (c1, c2) in enumerate(zip(enc.conv_s1, enc.conv_s2)):
        total += c1.out_channels * _grid(height, width, k) + c2.out_channels * _grid(height, width, k + 1)
    return total


def decoder_values(decoder, height: int, width: int) -> int:
    """Values of the maps of every level of ``decoder`` (a :class:`~cosemdepth.models.pyramid.PyramidDecoder`) for one
    ``height x width`` image: per level, its first convolution's input and every convolution's output."""
    total = 0
    for level in decoder.levels:
        convs = _convs(level)
        if convs:
            channels = convs[0].in_channels + sum(c.out_channels for c in convs)
            total += channels * _grid(height, width, level.level)
    return total


def _head_values(decoder, height: int, width: int) -> int:
    finest = _convs(decoder.levels[0])
    return (finest[-1].out_channels if finest else 1) * height * width


def step_bytes(model: SceneModel, height: int, width: int, batch: int = 1) -> int:
    """Estimated peak memory in bytes of streaming ``model`` (a :class:`~cosemdepth.models.model.SceneModel`, may be
    on the meta device) at ``batch x 3 x height x width``: the weights, the input and heads, the encoder's maps and
    the maps of its widest decoder (see the module docstring)."""
    decoders = list(model.decoders.values())
    per_image = (
        3 * height * width
        + encoder_values(model, height, width)
        + sum(_head_values(d, height, width) for d in decoders)
        + max((decoder_values(d, height, width) for d in decoders), default=0)
    )
    weights = sum(p.numel() for p in model.parameters())
    return VALUE_BYTES * (weights + batch * per_image)


def training_step_bytes(model: SceneModel, height: int, width: int, batch: int, frames: int) -> int:
    """Estimated peak memory in bytes of one training step of ``model`` on ``batch`` windows of ``frames`` frames of
    ``height x width``: the weights with their gradients and Adam moments, and every map of every frame (all decoders
    at once: the backward pass needs them)."""
    decoders = list(model.decoders.values())
    per_frame = (
        3 * height * width
        + encoder_values(model, height, width)
        + sum(decoder_values(d, height, width) + _head_values(d, height, width) for d in decoders)
    )
    weights = sum(p.numel() for p in model.parameters())
    return VALUE_BYTES * (TRAINING_VALUES_PER_WEIGHT * weights + batch * frames * per_frame)


def format_bytes(n: float) -> str:
    """``1536`` -> ``"1.5 kB"`` (powers of 1000: kB, MB, GB, TB, PB)."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(n) < 1000:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} PB"


def _largest_square(need, available: int) -> int:
    """The largest side ``s`` (>= 8, <= sqrt of the pixel cap) with ``need(s, s) <= available``; 0 if none."""
    lo, hi = 7, int(MAX_INPUT_PIXELS**0.5)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if need(mid, mid) <= available:
            lo = mid
        else:
            hi = mid - 1
    return lo if lo >= 8 else 0


def check_size(
    model: SceneModel,
    height: int,
    width: int,
    *,
    device="cpu",
    batch: int = 1,
    frames: int = 1,
    training: bool = False,
    what: str = "--size",
) -> int:
    """Raise a one-line :class:`ConfigError` naming ``what`` unless ``model`` can run at ``height x width`` here:
    at most :data:`MAX_INPUT_PIXELS` pixels, and the estimated memory (:func:`step_bytes`, or
    :func:`training_step_bytes` with ``training``; ``batch`` images or windows of ``frames``) within the memory
    available on ``device`` (:func:`cosemdepth.devices.available_memory`). The message states the bound. Returns
    the estimate in bytes.

    Call it before anything is allocated at that size (data decoded, a step run)."""
    if height < 1 or width < 1:
        raise ConfigError(f"{what}: {height}x{width}: sizes must be positive")
    side = int(MAX_INPUT_PIXELS**0.5)
    if height * width > MAX_INPUT_PIXELS:
        raise ConfigError(
            f"{what}: {height}x{width} is {height * width} pixels, more than the model takes (at most "
            f"{MAX_INPUT_PIXELS} pixels, e.g. {side}x{side}); choose a smaller size"
        )

    def need(h: int, w: int, b: int = batch) -> int:
        return training_step_bytes(model, h, w, b, frames) if training else step_bytes(model, h, w, b)

    estimate = need(height, width)
    available, source = available_memory(device)
    if available is None or estimate <= available:
        return estimate
    how = (
        f"a training step (batch {batch} of {frames} frames)"
        if training
        else f"a streaming step (batch {batch})"
        if batch > 1
        else "a streaming step"
    )
    fits = _largest_square(need, available)
    hint = f"the largest square size that fits is about {fits}x{fits}" if fits else "no size fits"
    if batch > 1:
        per_item = need(height, width, 2) - need(height, width, 1)
        most = max((available - need(height, width, 0)) // per_item, 0)
        hint = (
            f"at this size at most {most} fit in a batch" if most else "not even one fits at this size"
        ) + f"; at batch {batch} {hint}"
    raise ConfigError(
        f"{what}: at {height}x{width} {how} of this model needs about {format_bytes(estimate)}, more "
        f"than the {format_bytes(available)} of memory available ({source}); {hint}"
    )


__all__ = [
    "MAX_INPUT_PIXELS",
    "check_size",
    "decoder_values",
    "encoder_values",
    "format_bytes",
    "step_bytes",
    "training_step_bytes",
]
