"""Feature normalisation (spec 4.3 and 5.1)."""

from __future__ import annotations

import torch

#: Guard on the squared norm of a feature group: an all-zero group gives 0 instead of NaN (the original divides by
#: the plain norm). Squared norms of real features are many orders of magnitude above it.
NORM_SQ_EPS = 1e-30


def grouped_l2_normalize(x: torch.Tensor, groups: int, guard: bool = True) -> torch.Tensor:
    """Split the channels into ``groups`` contiguous groups and divide each group by its per-pixel L2 norm.

    Args:
        x: ``[B, C, H, W]`` with ``C`` divisible by ``groups``.
        groups: number of groups ``K`` (1 = normalise over all channels).
        guard: avoid 0/0 for an all-zero group.
    Returns:
        ``[B, C, H, W]``.
    """
    b, c, h, w = x.shape
    if c % groups:
        raise ValueError(f"{c} channels cannot be split into {groups} groups")
    g = x.reshape(b, groups, c // groups, h, w)
    sq = (g * g).sum(dim=2, keepdim=True)
    if guard:
        sq = sq.clamp_min(NORM_SQ_EPS)
    return (g / torch.sqrt(sq)).reshape(b, c, h, w)
