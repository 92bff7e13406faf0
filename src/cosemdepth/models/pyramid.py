"""The decoder pyramid, once for every decoder: the coarse -> fine level loop and the per-sample reset logic.

A decoder is a :class:`PyramidDecoder` whose levels (:class:`PyramidLevel`) provide a few per-level operations:
``prepare`` the encoder features, the ``coarse_inputs`` from the coarser level (or the constant init, which is also
what a resetting sample outputs), ``refine`` them, and for a temporal decoder the state it hands to the next frame.
How the heavy parts of a level run (cost volumes, concatenation, refiner, nearest resize, feature layout) comes from
:class:`LevelOps`: the reference modules by default, packed equivalents from the fast inference engine.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Callable, Collection, Mapping, Optional, Sequence

import torch
import torch.nn as nn

from ..geometry.motion import baseline
from ..geometry.validity import depth_validity
from ..ops.concat import concat_into
from ..ops.cost_volume import parallax_sweep_cost_volume, spatial_cost_volume
from ..ops.normalize import grouped_l2_normalize
from ..ops.resample import resize_nn1, resize_nn2
from .outputs import ESTIMATED, RESET, StepOutput, StreamState

Tensor = torch.Tensor


def _identity(x: Tensor) -> Tensor:
    return x


@dataclass(frozen=True)
class LevelOps:
    """The operations of a level that an inference engine may replace by equivalents (defaults: the reference ones).

    Attributes:
        layout: applied to the encoder features before ``prepare`` (e.g. to NCHW for the cost volumes).
        concat: ``blocks -> refiner input`` (channel concatenation, written once in the convolution's dtype and layout).
        refiner: ``x -> y``, or None for the level's own :class:`~cosemdepth.models.layers.Refiner`.
        nearest: ``(x, size) -> x`` TF nearest resize without half-pixel centres (NN1).
        pscv: ``(feat, prev, points, groups, half) -> (pscv, warped_parallax)`` (see ``parallax_sweep_cost_volume``).
        sncv: ``(feat, groups, radius) -> volume`` (see ``spatial_cost_volume``).
        hypot: compute the epipolar distances with ``hypot`` (see ``epipolar_geometry``).
    """

    layout: Callable = _identity
    concat: Callable = concat_into
    refiner: Optional[Callable] = None
    nearest: Callable = resize_nn1
    pscv: Callable = parallax_sweep_cost_volume
    sncv: Callable = spatial_cost_volume
    hypot: bool = False


REFERENCE_OPS = LevelOps()


class PyramidLevel(nn.Module):
    """One level l (absolute, 1 = finest) of a decoder. Its operations:

    * ``prepare(feat, guard)``: the encoder features as the level uses them (grouped L2 normalisation, design 5.2, if
      ``normalize``);
    * ``coarse_inputs(coarse, f_hat, ops)``: the level's inputs from the coarser level's output (None at the
      coarsest level), a dataclass of tensors like the output: also what a resetting sample outputs;
    * ``refine(f_hat, inputs, frame, prev, ops)``: the output; ``prev`` is this level's entry of every state
      component (temporal decoders), ``frame`` the decoder's per-frame context;
    * ``next_state(f_hat, out)`` / ``reset_state(f_hat, inputs)``: this level's entry of every state component after
      a normal step / for a sample that resets (temporal decoders).
    """

    level: int
    groups: int = 1  # channel groups of the feature normalisation
    normalize: bool = False
    #: :class:`LevelOps` fields the fast inference engine sets for this level besides its packed operations (e.g.
    #: ``layout``: the features as its cost volumes read them; ``hypot``)
    fast_ops: Mapping[str, Any] = {}

    def prepare(self, feat: Tensor, guard: bool) -> Tensor:
        return grouped_l2_normalize(feat, self.groups, guard=guard) if self.normalize else feat

    def next_state(self, f_hat: Tensor, out: Any) -> tuple[Tensor, ...]:
        return ()

    def reset_state(self, f_hat: Tensor, inputs: Any) -> tuple[Tensor, ...]:
        return ()


class PyramidDecoder(nn.Module):
    """A decoder pyramid run coarse -> fine, one frame at a time; with ``state_names`` it is temporal (explicit state
    per level, per-sample reset).

    Class attributes of a subclass: ``level_class`` (its :class:`PyramidLevel`), ``state_names`` (state components,
    empty: stateless), ``maps`` (``StepOutput.levels`` key -> attribute of a level output) and ``head`` (the key whose
    finest map, upsampled to the input size, is the decoder's output).

    Attributes:
        guard: protect the degenerate cases of design 2.4 (default True; results on normal inputs are unchanged).
        static: never branch on the reset mask (always refine and select per sample); for graph capture and export.
            The default skips the refiners when every sample resets.
    """

    level_class: type = PyramidLevel
    state_names: tuple[str, ...] = ()
    maps: Mapping[str, str] = {}
    head: str = ""
    #: level maps of the same frame this decoder reads (``StepOutput.levels`` keys of the decoders before it, or
    #: ``"gt_depth"``: the ground-truth depth resized to the levels), handed to :meth:`frame` as ``guide``
    reads: tuple[str, ...] = ()
    #: the decoder whose state this one's follows: on a frame that decoder does not run (``decode_step(only=...)``),
    #: this one's state passes through unchanged
    state_follows: Optional[str] = None
    #: a temporal decoder whose resetting samples still refine, with ``fresh`` set in the frame context (their
    #: temporal input is empty), instead of returning the coarse inputs and the reset state
    refines_resets: bool = False

    def __init__(self, cfg):
        super().__init__()
        self.levels = nn.ModuleList(self.level_class(l, c, cfg) for l, c in enumerate(cfg.encoder_channels, start=1))
        self.guard = True
        self.static = False

    @property
    def temporal(self) -> bool:
        return bool(self.state_names)

    def frame(
        self,
        rot: Tensor,
        trans: Tensor,
        intrinsics: Tensor,
        fresh: Optional[Tensor] = None,
        guide: Optional[Mapping[str, Sequence[Tensor]]] = None,
    ) -> Any:
        """Per-frame context handed to every level's ``refine`` (e.g. the rotation matrix); ``fresh`` ``[B]`` the
        samples without a previous frame (``refines_resets`` decoders; None: none), ``guide`` the maps of ``reads``
        that are available on this frame, per level (finest first)."""

    def level_state_shapes(self, level: PyramidLevel, batch: int, h: int, w: int) -> tuple[tuple[int, ...], ...]:
        """Shape of each state component at ``level`` for an ``h x w`` level map (temporal decoders)."""
        return ()

    def state_shapes(self, batch: int, height: int, width: int) -> dict[str, list[tuple[int, ...]]]:
        """Per-level shapes of every state component (finest first) for a ``batch x 3 x height x width`` input."""
        sizes = [(-(-height // 2**lvl.level), -(-width // 2**lvl.level)) for lvl in self.levels]
        per_level = [self.level_state_shapes(lvl, batch, h, w) for lvl, (h, w) in zip(self.levels, sizes)]
        return {name: [shapes[k] for shapes in per_level] for k, name in enumerate(self.state_names)}

    def level_maps(self, outs: Sequence[Any]) -> dict[str, list[Tensor]]:
        return {key: [getattr(o, attr) for o in outs] for key, attr in self.maps.items()}

    def forward(
        self,
        feats: Sequence[Tensor],
        rot: Optional[Tensor] = None,
        trans: Optional[Tensor] = None,
        intrinsics: Optional[Tensor] = None,
        prev: Optional[Sequence[Sequence[Tensor]]] = None,
        reset: Optional[Tensor] = None,
        ops: Optional[Sequence[LevelOps]] = None,
        static: Optional[bool] = None,
        guide: Optional[Mapping[str, Sequence[Tensor]]] = None,
    ) -> tuple[list[Any], tuple[tuple[Tensor, ...], ...]]:
        """Decode one frame.

        Args:
            feats: encoder features, finest first, ``[B, C_l, h_l, w_l]``.
            rot, trans: ``[B, 4]``, ``[B, 3]`` relative motion previous -> current; intrinsics ``[B, 4]`` at the input
                size (temporal decoders).
            prev: the previous frame's state, one per-level tuple per state component (None: no previous frame,
                every sample resets).
            reset: ``[B]`` bool, samples that start a new trajectory (None: no sample resets).
            ops: per-level operations (default: the reference ones); static: overrides ``self.static``.
            guide: the maps of ``reads`` available on this frame (see :meth:`frame`).
        Returns:
            per-level outputs (finest first) and the new state (one per-level tuple per state component).
        """
        n = len(self.levels)
        ops = ops or [REFERENCE_OPS] * n
        static = self.static if static is None else static
        fresh = None
        if self.temporal and self.refines_resets:  # a reset empties the temporal input; every sample refines
            all_reset = any_reset = False
            if prev is not None and reset is not None and not static and bool(reset.all()):
                prev = None  # a state of another batch size or resolution is fine when every sample resets
            if prev is None:
                fresh = torch.ones(feats[0].shape[0], dtype=torch.bool, device=feats[0].device)
            else:
                fresh = reset
        elif not self.temporal or (prev is not None and reset is None):
            all_reset = any_reset = False
        elif prev is None:
            all_reset = any_reset = True
        elif static:
            all_reset, any_reset = False, True
        else:
            all_reset, any_reset = bool(reset.all()), bool(reset.any())
        if prev is not None and self.temporal and not all_reset:
            check_state(prev, feats)
        frame = self.frame(rot, trans, intrinsics, fresh, guide) if self.temporal else None
        mask = reset.view(-1, 1, 1, 1) if any_reset and not all_reset else None
        outs: list[Any] = [None] * n
        states: list[tuple[Tensor, ...]] = [()] * n
        coarse = None
        for j in range(n - 1, -1, -1):
            lvl: PyramidLevel = self.levels[j]
            f_hat = lvl.prepare(ops[j].layout(feats[j]), self.guard)
            inputs = lvl.coarse_inputs(coarse, f_hat, ops[j])
            if all_reset:
                out, states[j] = inputs, lvl.reset_state(f_hat, inputs)
            else:
                level_prev = None if prev is None else tuple(comp[j] for comp in prev)
                out = lvl.refine(f_hat, inputs, frame, level_prev, ops[j])
                states[j] = lvl.next_state(f_hat, out)
                if mask is not None:
                    out = _select(mask, inputs, out)
                    states[j] = tuple(
                        s if s is r else torch.where(mask, r, s)
                        for r, s in zip(lvl.reset_state(f_hat, inputs), states[j])
                    )
            coarse = outs[j] = out
        return outs, tuple(zip(*states)) if self.temporal else ()


def _select(mask: Tensor, where_true: Any, where_false: Any) -> Any:
    """Per-sample choice between two level outputs (dataclasses of tensors)."""
    return type(where_false)(
        *(
            torch.where(mask, getattr(where_true, f.name), getattr(where_false, f.name))
            for f in dataclasses.fields(where_false)
        )
    )


def check_state(prev: Sequence[Sequence[Tensor]], feats: Sequence[Tensor]) -> None:
    """Raise ValueError unless every state component has one entry per level with the batch size and level size of
    ``feats`` (a state from another batch size or resolution)."""
    for comp in prev:
        if len(comp) != len(feats):
            raise ValueError(f"state has {len(comp)} levels, the model has {len(feats)}")
        for j, (s, f) in enumerate(zip(comp, feats)):
            if s.shape[0] != f.shape[0] or s.shape[2:] != f.shape[2:]:
                raise ValueError(
                    f"state level {j + 1} has shape {list(s.shape)} but this frame gives {list(f.shape)}: the batch "
                    "size or resolution changed; pass reset=True for every sample (or state=None) to start over"
                )


#: The ``reads`` key of the ground-truth depth resized to the levels (``guide_depth`` of :func:`decode_step`).
GT_DEPTH = "gt_depth"


def depth_pyramid(depth: Tensor, feats: Sequence[Tensor]) -> list[Tensor]:
    """A depth map ``[B, 1, H, W]`` at the size of every level of ``feats`` (finest first), NN2 as the label pyramids
    (design 3.4: depths are not blended across edges)."""
    return [resize_nn2(depth.to(feats[0].dtype), tuple(f.shape[-2:])) for f in feats]


def decoder_guide(
    dec: PyramidDecoder, levels: Mapping[str, Sequence[Tensor]], gt_levels: Optional[Sequence[Tensor]]
) -> dict[str, Sequence[Tensor]]:
    """The maps of ``dec.reads`` available on a frame: those of the decoders that ran before it (``levels``) and the
    ground-truth depth pyramid ``gt_levels``. Raises ValueError when ``dec`` reads the ground truth and none is
    given."""
    if GT_DEPTH in dec.reads and gt_levels is None:
        raise ValueError(
            f"argument guide_depth: the {dec.head} decoder warps its previous output with the ground-truth "
            "depth (semantic_time 'gt'), so every frame needs its depth map [B, 1, H, W]"
        )
    found = {**levels, GT_DEPTH: gt_levels}
    return {k: found[k] for k in dec.reads if found.get(k) is not None}


def decode_step(
    decoders: Mapping[str, PyramidDecoder],
    feats: Sequence[Tensor],
    rot: Tensor,
    trans: Tensor,
    intrinsics: Tensor,
    reset: Optional[Tensor],
    state: Optional[StreamState],
    upsample: Callable[[Tensor], Tensor],
    ops: Optional[Mapping[str, Sequence[LevelOps]]] = None,
    static: Optional[bool] = None,
    only: Optional[Collection[str]] = None,
    guide_depth: Optional[Tensor] = None,
) -> tuple[StepOutput, StreamState]:
    """One streaming step of every decoder on the encoder features of a frame (the reference path and the fast
    engine both run this): the per-level maps, each decoder's head (its finest map passed through ``upsample``, to
    the input size), the depth's validity and status (:func:`depth_status`; not in static mode, which must not
    read values on the host) and the new state. With ``only``, just
    the decoders named there run; the state components of the others pass through unchanged, and so do those of a
    decoder whose ``state_follows`` one did not run. ``guide_depth`` ``[B, 1, H, W]``: the frame's ground-truth depth,
    for the decoders that read it."""
    levels: dict[str, list[Tensor]] = {}
    components: dict[str, tuple[Tensor, ...]] = {}
    ran, ran_names = [], []
    gt_levels = None if guide_depth is None else depth_pyramid(guide_depth, feats)
    for name, dec in decoders.items():
        if only is not None and name not in only:
            if state is not None:
                components.update((c, state.components[c]) for c in dec.state_names if c in state.components)
            continue
        prev = None
        if dec.temporal and state is not None and all(state.components.get(c) for c in dec.state_names):
            prev = [state.components[c] for c in dec.state_names]
        guide = decoder_guide(dec, levels, gt_levels) if dec.reads else None
        outs, new = dec(feats, rot, trans, intrinsics, prev, reset, None if ops is None else ops[name], static, guide)
        levels.update(dec.level_maps(outs))
        if prev is not None and dec.state_follows in decoders and dec.state_follows not in ran_names:
            new = prev  # the decoder it follows held its state: so does this one
        components.update(zip(dec.state_names, new))
        ran.append(dec)
        ran_names.append(name)
    heads = {dec.head: upsample(levels[dec.head][0]) for dec in ran}
    out = StepOutput(heads=heads, levels=levels)
    is_static = static if static is not None else any(dec.static for dec in ran)
    if out.depth is not None and not is_static:  # graph capture and export: the host calls depth_status itself
        resets = state is None or not state.flatten()
        if not resets and reset is None:
            reset = torch.zeros(out.depth.shape[0], dtype=torch.bool, device=out.depth.device)
        elif resets:
            reset = torch.ones(out.depth.shape[0], dtype=torch.bool, device=out.depth.device)
        out.valid, out.status, out.baseline = depth_status(out.depth, rot, trans, intrinsics, reset)
    return out, StreamState(**components)


def depth_status(
    depth: Tensor, rot: Tensor, trans: Tensor, intrinsics: Tensor, reset: Tensor
) -> tuple[Tensor, list[str], Tensor]:
    """``(valid [B,1,H,W], status, baseline [B])`` of a depth estimated from parallax with the motion
    ``rot, trans`` (reset samples: nothing valid, status ``reset``, baseline 0); see :class:`StepOutput`."""
    reset = reset.to(depth.device)
    valid = depth_validity(depth.float(), rot.float(), trans.float(), intrinsics.float(), reset)
    status = [RESET if r else ESTIMATED for r in reset.tolist()]
    base = torch.where(reset, torch.zeros_like(trans[:, 0]), baseline(trans)).float()
    return valid, status, base
