"""Start a model from the weights of a model of another config (``train.init_from``): fine-tuning a variant with
new inputs from trained weights.

:func:`transfer_state_dict` is the general rule, on state dicts alone: a tensor of the same name and shape is
copied; a weight whose input channels (dim 1) grew, every other dim equal, gets the source's weights on its leading
input channels and zeros on the new ones; a tensor the source lacks keeps the target's own (initialised) values.
Any other difference of shapes is an error. Zero weights on the new input channels make the target compute exactly
what the source computes, whatever those inputs hold, as long as the new channels come after the old ones in the
layer's input; training then moves them away from zero (their gradient is the upstream gradient times the input).

:func:`read_transfer_source` applies the rule to a model folder and a run's model config, after checking that the
two configs differ only in ways whose new input channels come last (:func:`check_transferable`): the architecture
and the semantic decoder's switches (``semantic_sncv``, ``semantic_time``; their blocks are appended in that order,
:func:`cosemdepth.decoders.semantic.decoder.semantic_refiner_inputs`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping

import torch

from ..checkpoints.convert import expected_param_shapes
from ..checkpoints.model_io import read_weights
from ..decoders.semantic.decoder import semantic_refiner_inputs
from ..errors import CheckpointError
from ..models.config import ModelConfig

#: ModelConfig fields a transfer may change: they add decoders or append input channels to existing layers
#: (``pscv_dtype`` changes no parameter).
TRANSFERABLE_FIELDS = ("arch", "semantic_sncv", "semantic_time", "pscv_dtype")


@dataclass(frozen=True)
class TransferPlan:
    """What :func:`transfer_state_dict` does with each tensor (names sorted).

    Attributes:
        copied: tensors of the same shape in both, copied.
        grown: ``(name, source input channels, target input channels)`` of the weights whose input channels grew:
            the leading channels copied, the others zero.
        new: target tensors the source lacks: they keep the target's values.
        dropped: source tensors the target lacks: not used.
    """

    copied: tuple[str, ...]
    grown: tuple[tuple[str, int, int], ...]
    new: tuple[str, ...]
    dropped: tuple[str, ...]

    def summary(self, prefix: str = "") -> dict:
        """``copied`` (a count), ``grown`` (``"name C_src->C_target"``), ``new`` and ``dropped`` (names), the keys
        prefixed with ``prefix`` (the ``start`` event's ``init_copied``, ...)."""
        return {
            f"{prefix}copied": len(self.copied),
            f"{prefix}grown": [f"{k} {a}->{b}" for k, a, b in self.grown],
            f"{prefix}new": list(self.new),
            f"{prefix}dropped": list(self.dropped),
        }


def plan_transfer(
    source: Mapping[str, tuple[int, ...]], target: Mapping[str, tuple[int, ...]], origin: str = "source"
) -> TransferPlan:
    """The :class:`TransferPlan` of source shapes into target shapes (name -> shape).

    Raises:
        CheckpointError: a tensor of both whose shapes differ other than by more input channels (dim 1 of a tensor of
            two or more dims, every other dim equal); the message names it, both shapes and ``origin``.
    """
    copied, grown, bad = [], [], []
    for k in sorted(set(source) & set(target)):
        s, t = tuple(source[k]), tuple(target[k])
        if s == t:
            copied.append(k)
        elif len(s) == len(t) >= 2 and s[0] == t[0] and s[2:] == t[2:] and t[1] > s[1]:
            grown.append((k, s[1], t[1]))
        else:
            bad.append(f"{k} has shape {list(s)}, the target {list(t)}")
    if bad:
        more = f" ({len(bad)} in all)" if len(bad) > 3 else ""
        raise CheckpointError(
            f"{origin}: the weights do not transfer: {'; '.join(bad[:3])}{more}; only a weight's "
            "input channels (dim 1) may grow"
        )
    return TransferPlan(
        tuple(copied), tuple(grown), tuple(sorted(set(target) - set(source))), tuple(sorted(set(source) - set(target)))
    )


def transfer_state_dict(
    source: Mapping[str, torch.Tensor], target: Mapping[str, torch.Tensor], origin: str = "source"
) -> tuple[dict[str, torch.Tensor], TransferPlan]:
    """A full state dict for the target (its names, shapes and dtypes) from ``source``, and the plan it followed.

    Copied tensors and the leading input channels of grown weights take the source's values (cast to the target's
    dtype); the new input channels of a grown weight are zero; tensors the source lacks are the target's own
    (cloned). Raises :class:`CheckpointError` as :func:`plan_transfer`.
    """
    plan = plan_transfer(
        {k: tuple(v.shape) for k, v in source.items()}, {k: tuple(v.shape) for k, v in target.items()}, origin
    )
    out = {k: target[k].detach().clone() for k in plan.new}
    for k in plan.copied:
        out[k] = source[k].detach().to(dtype=target[k].dtype, device=target[k].device).clone()
    for k, c_src, _ in plan.grown:
        t = torch.zeros_like(target[k])
        t[:, :c_src] = source[k].detach().to(dtype=t.dtype, device=t.device)
        out[k] = t
    return {k: out[k] for k in target}, plan


def check_transferable(source: ModelConfig, target: ModelConfig, origin: str = "source") -> None:
    """Raise :class:`CheckpointError` unless a model of ``target`` can start from one of ``source`` by
    :func:`transfer_state_dict`: every field but :data:`TRANSFERABLE_FIELDS` equal, and the semantic refiners'
    input blocks of the source the leading blocks of the target's (so the new channels are the last ones)."""
    differ = [
        f"{f.name} {getattr(source, f.name)!r} (run: {getattr(target, f.name)!r})"
        for f in dataclasses.fields(ModelConfig)
        if f.name not in TRANSFERABLE_FIELDS and getattr(source, f.name) != getattr(target, f.name)
    ]
    if differ:
        raise CheckpointError(
            f"{origin}: the weights do not transfer: {', '.join(differ)}; only "
            f"{', '.join(TRANSFERABLE_FIELDS)} may differ"
        )
    if source.has_semantic and target.has_semantic:
        src = [name for name, _ in semantic_refiner_inputs(0, source)]
        dst = [name for name, _ in semantic_refiner_inputs(0, target)]
        if dst[: len(src)] != src:
            raise CheckpointError(
                f"{origin}: the weights do not transfer: the semantic refiners' inputs "
                f"{', '.join(src)} are not the leading inputs of the run's "
                f"({', '.join(dst)})"
            )


def read_transfer_source(
    path: str, model_config: ModelConfig, what: str = "train.init_from"
) -> tuple[dict[str, torch.Tensor], TransferPlan]:
    """The float32 state dict of the model at ``path`` and the plan of its transfer into a model of
    ``model_config``; every problem (unreadable weights, a config or a shape that does not transfer) is a
    :class:`CheckpointError` starting with ``what``."""
    try:
        state_dict, source_config, origin = read_weights(path)
        check_transferable(source_config, model_config, origin)
        plan = plan_transfer(
            {k: tuple(v.shape) for k, v in state_dict.items()}, expected_param_shapes(model_config), origin
        )
    except CheckpointError as e:
        raise CheckpointError(f"{what}: {e}") from None
    return {k: v.float() if v.is_floating_point() else v for k, v in state_dict.items()}, plan


__all__ = [
    "TRANSFERABLE_FIELDS",
    "TransferPlan",
    "check_transferable",
    "plan_transfer",
    "read_transfer_source",
    "transfer_state_dict",
]
