"""Co-SemDepth and its single-task siblings M4Depth and M4Semantic: one encoder and one or two decoders.

Two ways to run a model:

* training: :meth:`SceneModel.forward_sequence` on a whole sequence ``[B, T, 3, H, W]`` returns every frame's
  per-level outputs (frame 0, or any frame flagged in ``reset``, takes the depth decoder's reset branch);
* streaming: :meth:`SceneModel.step` on one frame ``[B, 3, H, W]`` with an explicit :class:`StreamState` in and a new
  one out, and a per-sample reset mask.

Both run the same per-frame decoder code, so they agree exactly.
"""

from __future__ import annotations

from typing import Optional, Sequence

import torch
import torch.nn as nn

from ..config import ModelConfig
from ..ops.resample import resize_nn2
from .depth_decoder import DepthDecoder
from .encoder import Encoder
from .outputs import SequenceOutput, StepOutput, StreamState, step_output
from .semantic_decoder import SemanticDecoder


class SceneModel(nn.Module):
    """Shared encoder + depth decoder and/or semantic decoder, as selected by ``config.arch``."""

    def __init__(self, config: ModelConfig | None = None, **overrides):
        super().__init__()
        if config is None:
            config = ModelConfig(arch=self.default_arch, **overrides)
        elif overrides:
            config = ModelConfig.from_dict({**config.to_dict(), **overrides})
        self.config = config
        self.encoder = Encoder(config.encoder_channels, dinl=config.dinl)
        self.depth_decoder = DepthDecoder(config) if config.has_depth else None
        self.semantic_decoder = SemanticDecoder(config) if config.has_semantic else None
        self.set_numerics(pscv_half=config.pscv_dtype == "float16")
        self._fast = None  # the fast inference engine, see optimize()
        self._fast_options: dict | None = None
        self.register_load_state_dict_post_hook(_rebuild_fast_engine)

    default_arch = "cosemdepth"

    # ------------------------------------------------------------------ fast inference switch
    def optimize(self, mode: str = "fast", dtype: torch.dtype | str = torch.float32, device=None) -> "SceneModel":
        """Select the streaming inference path of :meth:`step` / :meth:`infer`; returns ``self``.

        * ``mode="fast"``: a :class:`~cosemdepth.inference.FastEngine` built from the current weights (channels-last
          pre-packed convolutions with fused activations, vectorised cost volumes); with ``dtype=torch.float32`` it
          gives the reference results up to float rounding (the *safe* setting, which the inference commands use by
          default). ``dtype=torch.bfloat16`` (CPU or GPU) or ``torch.float16`` (GPU) runs the refiners' hidden
          convolutions in that precision, faster and less exact: opt in after checking the accuracy of your weights
          (``benchmarks/fast_accuracy.py``).
        * ``mode="reference"``: the plain PyTorch modules (the default of a freshly built model).

        The fast path is used only in eval mode and never records gradients; ``forward_sequence`` (training) always
        runs the reference modules. Loading a state dict rebuilds the engine; so does a change of device.
        """
        if mode == "reference":
            self._fast = None
            self._fast_options = None
            return self
        if mode != "fast":
            raise ValueError(f"mode must be 'fast' or 'reference', got {mode!r}")
        from ..inference.engine import FastEngine, parse_dtype

        self._fast_options = {"dtype": parse_dtype(dtype), "device": device}
        self._fast = FastEngine(self, **self._fast_options)
        return self

    @property
    def inference_mode(self) -> str:
        """``"fast"`` or ``"reference"``: the path :meth:`step` takes in eval mode."""
        return "reference" if self._fast is None else "fast"

    def _fast_engine(self):
        if self._fast is None or self.training:
            return None
        p = next(self.parameters())
        if self._fast_options.get("device") is None and self._fast.device != p.device:
            self._fast = type(self._fast)(self, **self._fast_options)
        return self._fast

    # ------------------------------------------------------------------ numerics switches
    def set_numerics(self, guard: bool | None = None, pscv_half: bool | None = None, static: bool | None = None):
        """Numerical options: ``guard`` (degenerate-case guards, default on), ``pscv_half`` (float16 cost-volume
        products like the original, default off), ``static`` (no data-dependent branching on the reset mask)."""
        for dec in (self.depth_decoder, self.semantic_decoder):
            if dec is None:
                continue
            if guard is not None:
                dec.guard = guard
            if isinstance(dec, DepthDecoder):
                if pscv_half is not None:
                    dec.pscv_half = pscv_half
                if static is not None:
                    dec.static = static
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
    ) -> SequenceOutput:
        """Run a whole sequence (training mode).

        Args:
            rgb: ``[B, T, 3, H, W]`` in [0, 1].
            rot: ``[B, T, 4]`` quaternions (w, x, y, z); trans: ``[B, T, 3]`` metres (motion previous -> current).
            intrinsics: ``[B, 4]`` (fx, fy, cx, cy) at the input size (one camera per sequence), or ``[B, T, 4]``.
            reset: ``[B, T]`` bool; default resets frame 0 only. Frame 0 always resets (it has no previous frame).
        Returns:
            :class:`SequenceOutput` with per-level lists (finest first) of ``[B, T, ...]`` tensors.
        """
        _check_sequence(rgb, rot, trans, intrinsics, reset)
        b, t = rgb.shape[:2]
        feats = self.encoder(rgb.flatten(0, 1))
        out = SequenceOutput(features=[f.unflatten(0, (b, t)) for f in feats])
        if self.depth_decoder is not None:
            per_frame = []
            state = None
            for k in range(t):
                intr = intrinsics[:, k] if intrinsics.dim() == 3 else intrinsics
                frame_reset = None if reset is None else reset[:, k]
                levels, state = self._decode_depth(
                    [f[:, k] for f in out.features], rot[:, k], trans[:, k], intr, frame_reset, state
                )
                per_frame.append(levels)
            n_levels = len(per_frame[0])
            out.depth = [torch.stack([fr[j].depth for fr in per_frame], 1) for j in range(n_levels)]
            out.parallax = [torch.stack([fr[j].parallax for fr in per_frame], 1) for j in range(n_levels)]
            out.depth_other = [torch.stack([fr[j].other for fr in per_frame], 1) for j in range(n_levels)]
        if self.semantic_decoder is not None:
            sem = self.semantic_decoder(feats)
            out.semantic = [s.probs.unflatten(0, (b, t)) for s in sem]
            out.semantic_logits = [s.logits.unflatten(0, (b, t)) for s in sem]
            out.semantic_other = [s.other.unflatten(0, (b, t)) for s in sem]
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
    ) -> tuple[StepOutput, StreamState]:
        """Process one frame per sample, streaming.

        Args:
            rgb: ``[B, 3, H, W]`` in [0, 1].
            rot: ``[B, 4]`` quaternion (w, x, y, z); trans: ``[B, 3]`` metres; relative motion previous -> current in
                camera axes, ``X_prev = R X_curr + t`` (ignored for samples that reset).
            intrinsics: ``[B, 4]`` = (fx, fy, cx, cy) in pixels of the input size.
            reset: ``[B]`` bool, True where a sample starts a new trajectory (None: no reset).
            state: the state returned by the previous call, or None for a fresh start (every sample resets).
        Returns:
            ``(out, new_state)``; ``out.depth [B,1,H,W]`` metres and ``out.semantic [B,N,H,W]`` probabilities at the
            input size (nearest upsampling of the finest level), ``out.levels`` the per-level maps.
        """
        _check_step(rgb, rot, trans, intrinsics, reset)
        engine = self._fast_engine()
        if engine is not None:
            return engine.step(rgb, rot, trans, intrinsics, reset, state)
        feats = self.encoder(rgb)
        size = tuple(rgb.shape[-2:])
        dl = sl = None
        new_state = StreamState()
        if self.depth_decoder is not None:
            dl, new_state = self._decode_depth(feats, rot, trans, intrinsics, reset, state)
        if self.semantic_decoder is not None:
            sl = self.semantic_decoder(feats)
        return step_output(dl, sl, lambda x: resize_nn2(x, size)), new_state

    def _decode_depth(self, feats, rot, trans, intrinsics, reset, state):
        prev_f = prev_d = None
        if state is not None and state.features:
            if reset is not None and not self.depth_decoder.static and bool(reset.all()):
                pass  # nothing of the state is used: a new batch size or resolution is fine
            else:
                _check_state(state, feats)
                prev_f, prev_d = state.features, state.depths
        outs, nf, nd = self.depth_decoder(feats, rot, trans, intrinsics, prev_f, prev_d, reset)
        return outs, StreamState(nf, nd)

    @torch.no_grad()
    def infer(
        self,
        frames: torch.Tensor,
        motions: torch.Tensor | Sequence[torch.Tensor],
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
    ) -> StepOutput:
        """Stream a whole sequence and return the full-resolution outputs of every frame.

        Args:
            frames: ``[T, 3, H, W]`` or ``[B, T, 3, H, W]`` in [0, 1] (numpy arrays accepted).
            motions: ``(rot [.., T, 4], trans [.., T, 3])`` or one ``[.., T, 7]`` tensor ``(qw qx qy qz tx ty tz)``;
                the motion of frame 0 is ignored.
            intrinsics: ``[4]`` or ``[B, 4]`` (fx, fy, cx, cy) at the frame size.
            reset: optional ``[T]`` / ``[B, T]`` bool; frame 0 always resets.
        Returns:
            :class:`StepOutput` whose ``depth`` is ``[.., T, 1, H, W]`` and ``semantic`` ``[.., T, N, H, W]``.
        """
        p = next(self.parameters())
        frames = torch.as_tensor(frames, dtype=p.dtype, device=p.device)
        single = frames.dim() == 4
        if single:
            frames = frames.unsqueeze(0)
        if isinstance(motions, (tuple, list)):
            rot, trans = (torch.as_tensor(m, dtype=p.dtype, device=p.device) for m in motions)
        else:
            m = torch.as_tensor(motions, dtype=p.dtype, device=p.device)
            rot, trans = m[..., :4], m[..., 4:7]
        if single:
            rot, trans = rot.unsqueeze(0), trans.unsqueeze(0)
        b, t = frames.shape[:2]
        intr = torch.as_tensor(intrinsics, dtype=p.dtype, device=p.device)
        intr = intr.expand(b, 4) if intr.dim() == 1 else intr
        rs = torch.zeros(b, t, dtype=torch.bool, device=p.device)
        if reset is not None:
            rs |= torch.as_tensor(reset, dtype=torch.bool, device=p.device).view(-1, t).expand(b, t)
        rs[:, 0] = True
        state = None
        depths, sems = [], []
        for k in range(t):
            out, state = self.step(frames[:, k], rot[:, k], trans[:, k], intr, rs[:, k], state)
            depths.append(out.depth)
            sems.append(out.semantic)
        depth = torch.stack(depths, 1) if depths[0] is not None else None
        semantic = torch.stack(sems, 1) if sems[0] is not None else None
        if single:
            depth = None if depth is None else depth[0]
            semantic = None if semantic is None else semantic[0]
        return StepOutput(depth, semantic)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


class CoSemDepth(SceneModel):
    """Joint depth + semantic model (AlaaEldin & Odone)."""

    default_arch = "cosemdepth"


class M4Depth(SceneModel):
    """Depth-only model (Fonder et al.): encoder + depth decoder."""

    default_arch = "m4depth"


class M4Semantic(SceneModel):
    """Semantic-only model: encoder + semantic decoder."""

    default_arch = "m4semantic"


MODELS = {"cosemdepth": CoSemDepth, "m4depth": M4Depth, "m4semantic": M4Semantic}


def build_model(config: ModelConfig | None = None, **overrides) -> SceneModel:
    """Build a freshly initialised model; ``build_model(arch="m4depth", levels=6)`` or from a :class:`ModelConfig`."""
    if config is None:
        config = ModelConfig(**overrides)
    elif overrides:
        config = ModelConfig.from_dict({**config.to_dict(), **overrides})
    return MODELS[config.arch](config)


def _rebuild_fast_engine(module: SceneModel, incompatible_keys) -> None:
    """``load_state_dict`` post-hook: the fast engine holds copies of the weights, refresh them."""
    if module._fast is not None:
        module._fast = type(module._fast)(module, **module._fast_options)


# ---------------------------------------------------------------------- input checks
def _shape_error(name: str, expected: str, got: torch.Tensor) -> ValueError:
    return ValueError(f"argument {name} must have shape {expected}, got {list(got.shape)}")


def _check_step(rgb, rot, trans, intrinsics, reset) -> None:
    if rgb.dim() != 4 or rgb.shape[1] != 3:
        raise _shape_error("rgb", "[B, 3, H, W]", rgb)
    b = rgb.shape[0]
    if rot.shape != (b, 4):
        raise _shape_error("rot", f"[{b}, 4]", rot)
    if trans.shape != (b, 3):
        raise _shape_error("trans", f"[{b}, 3]", trans)
    if intrinsics.shape != (b, 4):
        raise _shape_error("intrinsics", f"[{b}, 4]", intrinsics)
    if reset is not None and (reset.shape != (b,) or reset.dtype != torch.bool):
        raise ValueError(f"argument reset must be a bool tensor of shape [{b}], got {reset.dtype} {list(reset.shape)}")


def _check_sequence(rgb, rot, trans, intrinsics, reset) -> None:
    if rgb.dim() != 5 or rgb.shape[2] != 3:
        raise _shape_error("rgb", "[B, T, 3, H, W]", rgb)
    b, t = rgb.shape[:2]
    if rot.shape != (b, t, 4):
        raise _shape_error("rot", f"[{b}, {t}, 4]", rot)
    if trans.shape != (b, t, 3):
        raise _shape_error("trans", f"[{b}, {t}, 3]", trans)
    if intrinsics.shape not in ((b, 4), (b, t, 4)):
        raise _shape_error("intrinsics", f"[{b}, 4] or [{b}, {t}, 4]", intrinsics)
    if reset is not None and (reset.shape != (b, t) or reset.dtype != torch.bool):
        raise ValueError(f"argument reset must be a bool tensor of shape [{b}, {t}], got {list(reset.shape)}")


def _check_state(state: StreamState, feats: list[torch.Tensor]) -> None:
    if len(state.features) != len(feats):
        raise ValueError(f"state has {len(state.features)} levels, the model has {len(feats)}")
    for j, (s, f) in enumerate(zip(state.features, feats)):
        if s.shape != f.shape:
            raise ValueError(
                f"state level {j + 1} has shape {list(s.shape)} but this frame gives {list(f.shape)}: the batch size "
                "or resolution changed; pass reset=True for every sample (or state=None) to start over"
            )
