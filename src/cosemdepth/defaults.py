"""Values more than one part of the package must agree on, each with one home here (the base layer: every layer may
read them). A default that only one part uses stays beside it (its options dataclass or module constant)."""

from __future__ import annotations

#: The depth cap of the evaluation (design 10.7), in metres: ground truth is clipped to ``[0, DEPTH_CAP_M]`` and
#: predictions to ``[EVAL_MIN_PRED, DEPTH_CAP_M]`` by the metrics; beyond it two depths are both "far" (the policy's
#: consistency check), and the depth colour maps end there.
DEPTH_CAP_M = 80.0
#: The smallest depth a prediction is taken to have, in metres (the metrics' clip, the policy's consistency check).
MIN_DEPTH_M = 1e-3
#: Where a model runs when no device is named (``--device``, ``train.device``, ``run_demo``): CUDA when available,
#: else the CPU.
DEFAULT_DEVICE = "auto"

__all__ = ["DEFAULT_DEVICE", "DEPTH_CAP_M", "MIN_DEPTH_M"]
