"""The model of every architecture (Co-SemDepth, its single-task siblings M4Depth and M4Semantic, Co-SemDepth-T,
any registered one): the shared encoder and the registered decoders the architecture names.

Two ways to run a model:

* training: :meth:`SceneModel.forward_sequence` on a whole sequence ``[B, T, 3, H, W]`` returns every frame's
  per-level outputs (frame 0, or any frame flagged in ``reset``, takes the depth decoder's reset branch; with
  ``first_frame`` the stateless decoders skip the frames before it, which the training loss does not read);
* streaming: :meth:`SceneModel.step` on one frame ``[B, 3, H, W]`` with an explicit :class:`StreamState` in and a new
  one out, and a per-sample reset mask (the contract of :class:`~cosemdepth.models.protocol.StreamingModel`, which
  every streaming path implements).

Both run the same per-frame decoder code, so they agree exactly, and both always run the modules. The fast inference
path is an object of its own built from a model (:class:`cosemdepth.inference.FastModel`, what
:func:`~cosemdepth.checkpoints.model_io.load_model` returns by default): this package does not know it.
"""

from __future__ import annotations

from typing import Optional, Sequence

import torch
import torch.nn as nn

from ..operating_point import OperatingPoint
from ..ops.resample import resize_nn2
from .config import ModelConfig
from .encoder import Encoder
from .infer import infer_sequence
from .outputs import SequenceOutput, StepOutput, StreamState
from .pyramid import PyramidDecoder, decode_step, decoder_guide, depth_pyramid
from .registry import DECODERS


class SceneModel(nn.Module):
    """Shared encoder + the decoders of ``config.arch`` (see :mod:`cosemdepth.models.registry`); decoder ``name`` is
    the submodule ``<name>_decoder`` (``depth_decoder``, ``semantic_decoder``; None when the architecture lacks it).
    ``SceneModel(arch="m4depth")``: the config from keywords."""

    def __init__(self, config: ModelConfig | None = None, **overrides):
        super().__init__()
        if config is None:
            config = ModelConfig(**overrides)
        elif overrides:
            config = ModelConfig.from_dict({**config.to_dict(), **overrides})
        self.config = config
        self.encoder = Encoder(config.encoder_channels, dinl=config.dinl)
        for name in DECODERS:
            setattr(self, f"{name}_decoder", DECODERS[name](config) if name in config.decoders else None)
        self.set_numerics(pscv_half=config.pscv_dtype == "float16")

    default_arch = "cosemdepth"
    #: The model folder's operating point (the focal length and motion it was trained with; set by ``load_model``),
    #: None for a model built in memory.
    operating_point: Optional[OperatingPoint] = None

    @property
    def decoders(self) -> dict[str, PyramidDecoder]:
        """The decoders of this architecture by registered name, in order."""
        return {name: getattr(self, f"{name}_decoder") for name in self.config.decoders}

    def state_shapes(self, batch: int, height: int, width: int) -> dict[str, list[tuple[int, ...]]]:
        """Per-level shapes of every :class:`StreamState` component for a ``batch x 3 x height x width`` input (no
        weights needed: works on a model built on the meta device), in the order of :meth:`StreamState.flatten`."""
        return {k: v for dec in self.decoders.values() for k, v in dec.state_shapes(batch, height, width).items()}

    # ------------------------------------------------------------------ numerics switches
    def set_numerics(self, guard: bool | None = None, pscv_half: bool | None = None, static: bool | None = None):
        """Numerical options of the decoders: ``guard`` (degenerate-case guards, default on), ``pscv_half`` (float16
        cost-volume products like the original, default off; depth decoder), ``static`` (no data-dependent branching
        on the reset mask)."""
        for dec in self.decoders.values():
            for name, value in (("guard", guard), ("pscv_half", pscv_half), ("static", static)):
                if value is not None and hasattr(dec, name):
                    setattr(dec, name, value)
        return self

    # ------------------------------------------------------------------ training forward
    def forward(self, *args, **kwargs) -> SequenceOutput:
        return self.forward_sequence(*args, **kwargs)

    def forward_sequence(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        first_frame: int = 0,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> SequenceOutput:
        """Run a whole sequence (training mode).

        Args:
            rgb: ``[B, T, 3, H, W]`` in [0, 1].
            rot: ``[B, T, 4]`` quaternions (w, x, y, z); trans: ``[B, T, 3]`` metres (motion previous -> current).
            intrinsics: ``[B, 4]`` (fx, fy, cx, cy) at the input size (one camera per sequence), or ``[B, T, 4]``.
            reset: ``[B, T]`` bool; default resets frame 0 only. Frame 0 always resets (it has no previous frame).
            first_frame: the first frame whose outputs are wanted (the trainer passes the loss's first supervised
                frame, 1). A stateless decoder (semantic) does not run on the frames before it, and its maps hold NaN
                there; a temporal decoder (depth) runs every frame, as its later frames depend on the earlier ones.
                The outputs from ``first_frame`` on, and the gradients of anything computed from them, are those of
                a run with ``first_frame=0``: a quarter of the semantic decoder's work saved at ``T = 4``.
            guide_depth: ``[B, T, 1, H, W]`` ground-truth depth (metres), for a model whose semantic decoder warps
                with it (``config.needs_depth_input``, ``semantic_time="gt"``); refused otherwise.
        Returns:
            :class:`SequenceOutput` with per-level lists (finest first) of ``[B, T, ...]`` tensors.
        """
        _check_inputs(rgb, rot, trans, intrinsics, reset, sequence=True)
        self._check_guide(rgb, guide_depth, sequence=True)
        b, t = rgb.shape[:2]
        if not 0 <= first_frame < t:
            raise ValueError(f"argument first_frame must be in [0, T-1] = [0, {t - 1}], got {first_frame}")
        # frame-major batch (frame 0 of every sample, then frame 1...): a frame, or the frames from first_frame on,
        # are one contiguous block of every level's features
        feats = self.encoder(rgb.transpose(0, 1).flatten(0, 1))
        out = SequenceOutput(features=[f.unflatten(0, (t, b)).transpose(0, 1) for f in feats])
        frame_maps: list[dict[str, list[torch.Tensor]]] = [{} for _ in range(t)]  # the temporal decoders' maps
        for dec in self.decoders.values():
            if dec.temporal:  # frame by frame, the state carried along
                per_frame, state = [], None
                for k in range(t):
                    intr = intrinsics[:, k] if intrinsics.dim() == 3 else intrinsics
                    frame_reset = None if reset is None else reset[:, k]
                    frame_feats = [f[k * b : (k + 1) * b] for f in feats]
                    guide = None
                    if dec.reads:
                        gt = None if guide_depth is None else depth_pyramid(guide_depth[:, k], frame_feats)
                        guide = decoder_guide(dec, frame_maps[k], gt)
                    levels, state = dec(frame_feats, rot[:, k], trans[:, k], intr, state, frame_reset, guide=guide)
                    per_frame.append(dec.level_maps(levels))
                    frame_maps[k].update(per_frame[-1])
                maps = {
                    key: [torch.stack(per_level, 1) for per_level in zip(*(fr[key] for fr in per_frame))]
                    for key in dec.maps
                }
            else:  # every wanted frame at once
                levels = dec([f[first_frame * b :] for f in feats])[0]
                maps = {
                    key: [
                        _skipped_frames_nan(m.unflatten(0, (t - first_frame, b)).transpose(0, 1), first_frame)
                        for m in v
                    ]
                    for key, v in dec.level_maps(levels).items()
                }
            out.levels.update(maps)
        return out

    # ------------------------------------------------------------------ streaming
    def step(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        state: Optional[StreamState] = None,
        decoders: Optional[Sequence[str]] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> tuple[StepOutput, StreamState]:
        """The streaming step of :class:`~cosemdepth.models.protocol.StreamingModel` (its arguments and outputs), on
        the model's modules, in training and in eval mode (the fast path: :class:`cosemdepth.inference.FastModel`).
        Every frame is estimated from the previous one (``out.status`` is ``"reset"`` or ``"estimated"``; the
        baseline-aware policy of :class:`~cosemdepth.inference.Streamer` also holds frames)."""
        self.check_step(rgb, rot, trans, intrinsics, reset, decoders, guide_depth)
        if decoders is not None and not decoders:  # nothing to run: the state passes through
            return StepOutput(), state if state is not None else StreamState()
        size = tuple(rgb.shape[-2:])
        feats = self.encoder(rgb)
        return decode_step(
            self.decoders,
            feats,
            rot,
            trans,
            intrinsics,
            reset,
            state,
            lambda x: resize_nn2(x, size),
            only=decoders,
            guide_depth=guide_depth,
        )

    def check_step(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        decoders: Optional[Sequence[str]] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> None:
        """Raise a one-line ValueError naming the argument unless these are inputs :meth:`step` takes (shapes, the
        reset mask, decoder names, a ground-truth depth exactly for a model that reads one); every implementation of
        the streaming step checks its inputs with it."""
        _check_inputs(rgb, rot, trans, intrinsics, reset, sequence=False)
        self._check_guide(rgb, guide_depth, sequence=False)
        if decoders is not None:
            unknown = sorted(set(decoders) - set(self.decoders))
            if unknown:
                raise ValueError(f"argument decoders: {unknown} not among this model's {list(self.decoders)}")

    def _check_guide(self, rgb: torch.Tensor, guide_depth: Optional[torch.Tensor], sequence: bool) -> None:
        """A ground-truth depth is given exactly when the model reads one, with one map per frame of ``rgb``."""
        if guide_depth is None:
            return  # a model that needs one says so when the decoder reads it (decoder_guide)
        if not self.config.needs_depth_input:
            raise ValueError(
                f"argument guide_depth: this model (semantic_time {self.config.semantic_time!r}) takes no "
                "ground-truth depth"
            )
        want = (*rgb.shape[: 1 + sequence], 1, *rgb.shape[-2:])
        if tuple(guide_depth.shape) != want:
            raise _shape_error("guide_depth", "[" + ", ".join(map(str, want)) + "]", guide_depth)

    @torch.no_grad()
    def infer(
        self,
        frames: torch.Tensor,
        motions: torch.Tensor | Sequence[torch.Tensor],
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> StepOutput:
        """A whole sequence streamed with :meth:`step`: :meth:`StreamingModel.infer
        <cosemdepth.models.protocol.StreamingModel.infer>`."""
        p = next(self.parameters())
        return infer_sequence(
            self.step, frames, motions, intrinsics, reset, guide_depth, device=p.device, dtype=p.dtype
        )

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def build_model(config: ModelConfig | None = None, **overrides) -> SceneModel:
    """Build a freshly initialised model; ``build_model(arch="m4depth", levels=6)`` or from a :class:`ModelConfig`."""
    if config is None:
        config = ModelConfig(**overrides)
    elif overrides:
        config = ModelConfig.from_dict({**config.to_dict(), **overrides})
    return SceneModel(config)


def _skipped_frames_nan(x: torch.Tensor, n: int) -> torch.Tensor:
    """``[B, T - n, ...]`` -> ``[B, T, ...]``, the first ``n`` frames NaN (outputs not computed)."""
    if n == 0:
        return x
    return torch.cat([x.new_full((x.shape[0], n, *x.shape[2:]), float("nan")), x], dim=1)


# ---------------------------------------------------------------------- input checks
def _shape_error(name: str, expected: str, got: torch.Tensor) -> ValueError:
    return ValueError(f"argument {name} must have shape {expected}, got {list(got.shape)}")


def _check_inputs(rgb, rot, trans, intrinsics, reset, sequence: bool) -> None:
    """Shapes of the inputs of :meth:`SceneModel.step` (``[B, ...]``) or ``forward_sequence`` (``[B, T, ...]``)."""
    if rgb.dim() != 4 + sequence or rgb.shape[-3] != 3:
        raise _shape_error("rgb", "[B, T, 3, H, W]" if sequence else "[B, 3, H, W]", rgb)
    lead = tuple(rgb.shape[: 1 + sequence])
    dims = ", ".join(map(str, lead))
    for name, t, n in (("rot", rot, 4), ("trans", trans, 3)):
        if t.shape != (*lead, n):
            raise _shape_error(name, f"[{dims}, {n}]", t)
    if intrinsics.shape not in ((lead[0], 4), (*lead, 4)):
        raise _shape_error("intrinsics", f"[{lead[0]}, 4]" + (f" or [{dims}, 4]" if sequence else ""), intrinsics)
    if reset is not None and (reset.shape != lead or reset.dtype != torch.bool):
        raise ValueError(
            f"argument reset must be a bool tensor of shape [{dims}], got {reset.dtype} {list(reset.shape)}"
        )
    if not torch.jit.is_tracing():  # values: only of real inputs (an export traces placeholders)
        _check_motion(rot, trans, reset, sequence)


def _check_motion(rot: torch.Tensor, trans: torch.Tensor, reset: Optional[torch.Tensor], sequence: bool) -> None:
    """The motion of every sample that does not reset (a reset ignores it; frame 0 of a sequence always resets) is
    a rotation quaternion of finite, non-zero norm and a finite translation: else a ValueError naming the sample."""
    used = torch.ones(rot.shape[:-1], dtype=torch.bool, device=rot.device)
    if reset is not None:
        used &= ~reset.to(rot.device)
    if sequence:
        used[:, 0] = False
    norm2 = rot.detach().float().pow(2).sum(-1)
    bad_rot = used & ~(torch.isfinite(norm2) & (norm2 > 0))
    bad_trans = used & ~torch.isfinite(trans.detach().float()).all(-1)
    if not bool((bad_rot | bad_trans).any()):
        return
    for name, bad, t, what in (
        ("rot", bad_rot, rot, "not a rotation quaternion (w, x, y, z): zero or non-finite"),
        ("trans", bad_trans, trans, "not a finite translation"),
    ):
        if bool(bad.any()):
            idx = [int(i) for i in bad.nonzero()[0].tolist()]
            where = f"sample {idx[0]}" + (f", frame {idx[1]}" if sequence else "")
            values = [round(float(v), 6) for v in t[tuple(idx)].tolist()]
            raise ValueError(f"argument {name}: {where} is {what}: {values}")
