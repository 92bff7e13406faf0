"""A whole sequence through a streaming step: the loop behind ``infer`` of the model and of the fast path."""

from __future__ import annotations

from typing import Callable, Sequence

import torch

from .outputs import StepOutput


def infer_sequence(
    step: Callable,
    frames,
    motions,
    intrinsics,
    reset=None,
    guide_depth=None,
    *,
    device: torch.device,
    dtype: torch.dtype,
) -> StepOutput:
    """Stream ``frames`` through ``step`` (the contract of :meth:`~cosemdepth.models.SceneModel.step`) and stack the
    full-resolution outputs of every frame; the inputs (tensors or numpy arrays) are given to ``step`` as ``dtype`` on
    ``device``. Arguments and result as :meth:`~cosemdepth.models.SceneModel.infer`."""
    frames = torch.as_tensor(frames, dtype=dtype, device=device)
    single = frames.dim() == 4
    if single:
        frames = frames.unsqueeze(0)
    rot, trans = _motions(motions, dtype, device)
    if single:
        rot, trans = rot.unsqueeze(0), trans.unsqueeze(0)
    b, t = frames.shape[:2]
    intr = torch.as_tensor(intrinsics, dtype=dtype, device=device)
    intr = intr.expand(b, 4) if intr.dim() == 1 else intr
    rs = torch.zeros(b, t, dtype=torch.bool, device=device)
    if reset is not None:
        rs |= torch.as_tensor(reset, dtype=torch.bool, device=device).view(-1, t).expand(b, t)
    rs[:, 0] = True
    gd = None if guide_depth is None else torch.as_tensor(guide_depth, dtype=dtype, device=device)
    if gd is not None and single:
        gd = gd.unsqueeze(0)
    state, heads = None, []
    for k in range(t):
        try:
            out, state = step(
                frames[:, k],
                rot[:, k],
                trans[:, k],
                intr,
                rs[:, k],
                state,
                guide_depth=None if gd is None else gd[:, k],
            )
        except ValueError as e:  # the step's one-line input errors, said of this frame of the sequence
            raise ValueError(f"{e} (frame {k} of the sequence)") from None
        heads.append(out.heads)
    full = {h: torch.stack([o[h] for o in heads], 1)[0 if single else slice(None)] for h in heads[0]}
    return StepOutput(heads=full)


def _motions(
    motions: torch.Tensor | Sequence[torch.Tensor], dtype: torch.dtype, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(rot, trans)`` from a pair or from one ``[.., 7]`` array (qw qx qy qz tx ty tz)."""
    if isinstance(motions, (tuple, list)):
        rot, trans = (torch.as_tensor(m, dtype=dtype, device=device) for m in motions)
        return rot, trans
    m = torch.as_tensor(motions, dtype=dtype, device=device)
    return m[..., :4], m[..., 4:7]


__all__ = ["infer_sequence"]
