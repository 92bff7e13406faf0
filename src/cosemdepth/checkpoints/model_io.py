"""Our model file format: a folder with ``model.safetensors`` (the weights) and ``config.json``.

``config.json``::

    {"format": "cosemdepth", "format_version": 1,
     "model": {...ModelConfig fields...},
     "source": {...where the weights came from: a TF checkpoint, a training run...},
     "operating_point": {"size": [H, W], "focal_px": [fx, fy], "step_translation_m": {...}, "source": "..."},
     "num_parameters": 5202528, "cosemdepth_version": "0.1.0"}

``operating_point`` (:class:`cosemdepth.operating_point.OperatingPoint`): the input size, the focal length in pixels
and the per-step camera translations the weights were trained with (written by training and ``cosemdepth convert``;
:func:`read_operating_point` reads it, and a folder without it falls back to the training size its ``source``
records). :func:`load_model` sets it as ``model.operating_point``; the commands run the model at its focal length.

Both files are written atomically (temporary file + rename), and both are fully written before either is renamed
into place, so a crash never leaves a half-written file. :func:`load_model` also accepts an official TensorFlow
checkpoint (converted on the fly).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Mapping

import safetensors.torch
import torch
from safetensors import SafetensorError

from .. import __version__
from ..errors import CheckpointError, ConfigError
from ..inference.fast_model import FastModel, reference_model
from ..models import SceneModel, build_model
from ..models.config import ModelConfig
from ..operating_point import OperatingPoint
from ..output_safety.atomic import atomic_open
from ..output_safety.manifest import MANIFEST_FILE, sha256_file, validate_manifest
from ..output_safety.staging import missing_ancestors, remove_empty
from .convert import MIDAIR_OPERATING_POINT, convert_checkpoint, expected_param_shapes
from .tf_checkpoint import is_tf_checkpoint

FORMAT = "cosemdepth"
FORMAT_VERSION = 1
WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
#: config.json key holding the SHA-256 of model.safetensors (written by save_weights, checked by every load).
WEIGHTS_CHECKSUM = "weights_sha256"
#: config.json key of the operating point (:class:`~cosemdepth.operating_point.OperatingPoint`).
OPERATING_POINT = "operating_point"
#: ``load_model``'s ``mode``: a :class:`~cosemdepth.inference.FastModel`, or the :class:`~cosemdepth.models.SceneModel`
LOAD_MODES = ("fast", "reference")


def check_state_dict(state_dict: Mapping[str, torch.Tensor], cfg: ModelConfig, origin: str) -> None:
    """Raise :class:`CheckpointError` unless ``state_dict`` has exactly the parameters of ``cfg``, shapes included."""
    expected = expected_param_shapes(cfg)
    missing = sorted(set(expected) - set(state_dict))
    unexpected = sorted(set(state_dict) - set(expected))
    wrong = [
        f"{k} has shape {list(state_dict[k].shape)}, expected {list(s)}"
        for k, s in expected.items()
        if k in state_dict and tuple(state_dict[k].shape) != s
    ]
    not_float = [k for k, t in state_dict.items() if k in expected and not torch.is_floating_point(t)]
    problems = []
    if missing:
        problems.append(f"missing {_show(missing)}")
    if unexpected:
        problems.append(f"unexpected {_show(unexpected)}")
    if wrong:
        more = f" ({len(wrong)} in all)" if len(wrong) > 5 else ""
        problems.append("shape mismatch: " + "; ".join(wrong[:5]) + more)
    if not_float:
        problems.append(f"not floating point: {_show(not_float)}")
    if problems:
        raise CheckpointError(
            f"{origin}: weights do not match the {cfg.arch} model (levels={cfg.levels}, classes={cfg.num_classes}): "
            + "; ".join(problems)
        )


def check_finite(state_dict: Mapping[str, torch.Tensor], origin: str) -> None:
    """Raise :class:`CheckpointError` if a floating-point tensor of ``state_dict`` holds NaN or inf."""
    bad = []
    for k, t in state_dict.items():
        if torch.is_floating_point(t):
            n = int((~torch.isfinite(t)).sum())
            if n:
                bad.append(f"{k} ({n} of {t.numel()} values)")
    if bad:
        raise CheckpointError(f"{origin}: weights hold NaN/inf: {_show(bad)}; the model is corrupt or diverged")


def _show(keys: list[str], n: int = 5) -> str:
    return ", ".join(keys[:n]) + (f", ... ({len(keys)} in all)" if len(keys) > n else "")


# ----------------------------------------------------------------------------------------------------------------
# Writing


def save_weights(
    state_dict: Mapping[str, torch.Tensor],
    config: ModelConfig,
    out_dir: str | os.PathLike,
    source: Mapping[str, Any] | None = None,
    operating_point: OperatingPoint | None = None,
) -> Path:
    """Write ``OUT_DIR/model.safetensors`` and ``OUT_DIR/config.json``; return ``OUT_DIR``.

    The state dict is checked against ``config`` first; nothing is written if it does not match. ``OUT_DIR`` is
    created if needed (and removed again if writing fails); existing files of ours in it are replaced atomically.
    ``operating_point``: recorded as config.json's ``"operating_point"`` (none when None).
    """
    if operating_point is not None and not isinstance(operating_point, OperatingPoint):
        raise ConfigError(f"operating_point must be an OperatingPoint, got {type(operating_point).__name__}")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise CheckpointError(
            f"{out}: exists and is not a folder; the output must be a folder (it gets {CONFIG_FILE} and {WEIGHTS_FILE})"
        )
    check_state_dict(state_dict, config, f"weights for {out}")
    tensors = {k: v.detach().to("cpu").contiguous().clone() for k, v in state_dict.items()}
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model": config.to_dict(),
        "source": dict(source) if source else {},
        **({OPERATING_POINT: operating_point.to_dict()} if operating_point is not None else {}),
        "num_parameters": sum(int(t.numel()) for t in tensors.values()),
        "cosemdepth_version": __version__,
    }
    created = missing_ancestors(out)
    try:
        # serialised in memory and written by Python: a failed write (a full disk) is an OSError naming the file,
        # not the library's own error. Looked up at call time (module attribute): tests replace it.
        data = safetensors.torch.save(tensors, metadata={"format": FORMAT, "format_version": str(FORMAT_VERSION)})
        with atomic_open(out / WEIGHTS_FILE, "wb") as w:
            w.write(data)
            w.flush()  # a failed write is the weights' (the config's context below would name itself)
            meta[WEIGHTS_CHECKSUM] = hashlib.sha256(data).hexdigest()  # verified on every load
            with atomic_open(out / CONFIG_FILE, "w") as f:
                f.write(json.dumps(meta, indent=2) + "\n")
    except BaseException:
        remove_empty(created)  # only folders we made and that are still empty
        raise
    return out


def save_model(
    model: SceneModel | FastModel,
    out_dir: str | os.PathLike,
    source: Mapping[str, Any] | None = None,
    operating_point: OperatingPoint | None = None,
) -> Path:
    """Save ``model`` (which has a ``config: ModelConfig``) in our format; see :func:`save_weights`.

    ``operating_point`` defaults to the model's own ``model.operating_point`` (set by :func:`load_model`), if any.
    A :class:`~cosemdepth.inference.FastModel` saves the weights of its model.
    """
    model = reference_model(model)
    cfg = getattr(model, "config", None)
    if not isinstance(cfg, ModelConfig):
        raise ConfigError(f"save_model needs a model with a ModelConfig in .config, got {type(cfg).__name__}")
    if operating_point is None:
        operating_point = getattr(model, "operating_point", None)
    return save_weights(model.state_dict(), cfg, out_dir, source=source, operating_point=operating_point)


# ----------------------------------------------------------------------------------------------------------------
# Reading


def _model_dir(path: str | os.PathLike) -> Path:
    p = Path(path)
    if p.is_file() and p.name in (CONFIG_FILE, WEIGHTS_FILE):
        return p.parent
    if not p.exists():
        raise CheckpointError(f"{p}: model folder not found")
    if not p.is_dir():
        raise CheckpointError(f"{p}: not a model folder (expected a folder with {CONFIG_FILE} and {WEIGHTS_FILE})")
    return p


def read_config_file(path: str | os.PathLike) -> tuple[ModelConfig, dict[str, Any]]:
    """``(ModelConfig, whole config.json)`` of the model folder ``path``."""
    cfg_path = _model_dir(path) / CONFIG_FILE
    if not cfg_path.is_file():
        raise CheckpointError(f"{cfg_path}: not found; a model folder needs {CONFIG_FILE} and {WEIGHTS_FILE}")
    try:
        meta = json.loads(cfg_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CheckpointError(f"{cfg_path}: corrupt model config (not valid JSON: {e})") from e
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CheckpointError(f'{cfg_path}: not a cosemdepth model config (no "format": "{FORMAT}")')
    version = meta.get("format_version")
    if not isinstance(version, int) or version < 1:
        raise CheckpointError(f"{cfg_path}: bad format_version {version!r}")
    if version > FORMAT_VERSION:
        raise CheckpointError(
            f"{cfg_path}: format_version {version} is newer than this cosemdepth supports ({FORMAT_VERSION}); upgrade"
        )
    try:
        cfg = ModelConfig.from_dict(meta.get("model"))
    except (ConfigError, TypeError) as e:
        raise CheckpointError(f'{cfg_path}: invalid "model" entry: {e}') from e
    return cfg, meta


def _training_size(source: Mapping[str, Any]) -> tuple[int, int] | None:
    """The image size ``(H, W)`` recorded in a model folder's ``source``, if its trainer recorded one.

    Looks at ``source.size``, ``source.data.size`` and the ``data.size`` of a recorded ``config`` / ``run_config``
    (``scripts/ship_weights.py`` records the run's config as ``run_config``, with the size as ``[H, W]``); a size is
    an integer ``S`` (square) or ``[H, W]``.
    """
    places = [source, source.get("data")]
    for key in ("config", "run_config"):
        cfg = source.get(key)
        if isinstance(cfg, Mapping):
            places += [cfg, cfg.get("data")]
    for d in places:
        v = d.get("size") if isinstance(d, Mapping) else None
        if isinstance(v, int) and not isinstance(v, bool):
            v = [v, v]
        if (
            isinstance(v, (list, tuple))
            and len(v) == 2
            and all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in v)
        ):
            return int(v[0]), int(v[1])
    return None


def read_operating_point(meta: Mapping[str, Any], origin: str = CONFIG_FILE) -> OperatingPoint | None:
    """The operating point of a model folder from its parsed ``config.json`` (``meta``), or None.

    ``meta["operating_point"]`` when present; otherwise, for folders written before it existed, the training size
    recorded in ``meta["source"]`` with the 90-degree camera of the Mid-Air-format datasets (``fx = W/2``,
    ``fy = H/2``) and no motion statistics; None when neither is there. A malformed entry is a
    :class:`CheckpointError` naming ``origin``.
    """
    if meta.get(OPERATING_POINT) is not None:
        try:
            return OperatingPoint.from_dict(meta[OPERATING_POINT])
        except ConfigError as e:
            raise CheckpointError(f'{origin}: invalid "{OPERATING_POINT}" entry: {e}') from None
    source = meta.get("source")
    size = _training_size(source) if isinstance(source, Mapping) else None
    if size is None:
        return None
    return OperatingPoint(
        size,
        (size[1] / 2, size[0] / 2),
        None,
        "the training size in config.json's source; the 90-degree camera of Mid-Air's format",
    )


def read_model_files(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], ModelConfig, dict[str, Any]]:
    """``(state_dict, ModelConfig, meta)`` of the model folder ``path`` (or its config.json / model.safetensors).

    ``meta`` is the whole parsed config.json (format, source, ...). A folder with a checkpoint ``manifest.json`` is
    verified against it (sizes, SHA-256), and the weights against the SHA-256 that config.json records (every folder
    :func:`save_weights` wrote); the weights are checked against the config (names, shapes, floating point) and must
    be finite. Any problem is a :class:`CheckpointError` naming the file.
    """
    folder = _model_dir(path)
    cfg, meta = read_config_file(folder)
    weights = folder / WEIGHTS_FILE
    if not weights.is_file():
        raise CheckpointError(f"{weights}: not found; a model folder needs {CONFIG_FILE} and {WEIGHTS_FILE}")
    if (folder / MANIFEST_FILE).exists():  # a training checkpoint: its checksums first (the same check as resume)
        validate_manifest(folder, (CONFIG_FILE, WEIGHTS_FILE))
    try:
        state_dict = safetensors.torch.load_file(str(weights))
    except (SafetensorError, OSError, ValueError, RuntimeError, OverflowError, MemoryError) as e:
        raise CheckpointError(f"{weights}: corrupt or truncated safetensors file ({type(e).__name__}: {e})") from e
    check_state_dict(state_dict, cfg, str(weights))
    check_finite(state_dict, str(weights))
    if WEIGHTS_CHECKSUM in meta:  # what still decodes: the checksum that save_weights recorded
        expected = meta[WEIGHTS_CHECKSUM]
        if not isinstance(expected, str) or sha256_file(weights) != expected:
            raise CheckpointError(
                f"{weights}: checksum mismatch with {folder / CONFIG_FILE} (corrupt or modified weights file)"
            )
    return state_dict, cfg, meta


def read_weights(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], ModelConfig, str]:
    """``(state_dict, ModelConfig, origin)`` of one of our model folders or an official TensorFlow checkpoint.

    ``path`` as :func:`load_model` takes it; a TensorFlow checkpoint is converted on the fly. ``origin`` names the
    folder or checkpoint for messages. The tensors keep their stored precision; every problem is a
    :class:`CheckpointError` naming the file.
    """
    state_dict, cfg, origin, _ = _read(path)
    return state_dict, cfg, origin


def _is_tf(p: Path) -> bool:
    """``p`` names an official TensorFlow checkpoint rather than one of our model folders."""
    ours = p.is_dir() and ((p / CONFIG_FILE).exists() or (p / WEIGHTS_FILE).exists())
    if not ours and p.name not in (CONFIG_FILE, WEIGHTS_FILE) and is_tf_checkpoint(p):
        return True
    if p.is_dir() and not ours:
        raise CheckpointError(
            f"{p}: neither a cosemdepth model folder ({CONFIG_FILE} + {WEIGHTS_FILE}) nor a TensorFlow "
            "checkpoint folder (a 'checkpoint' file naming cp-XXXX.ckpt)"
        )
    return False


def _read(path: str | os.PathLike):
    """``(state_dict, ModelConfig, origin, operating point)`` of :func:`read_weights`' ``path``."""
    p = Path(path)
    if _is_tf(p):
        state_dict, cfg = convert_checkpoint(p)
        check_finite(state_dict, str(p))
        return state_dict, cfg, str(p), MIDAIR_OPERATING_POINT
    state_dict, cfg, meta = read_model_files(p)
    folder = _model_dir(p)
    return state_dict, cfg, str(folder), read_operating_point(meta, str(folder / CONFIG_FILE))


def operating_point_of(path: str | os.PathLike) -> OperatingPoint | None:
    """The operating point of the model at ``path`` (a model folder or an official TensorFlow checkpoint, as
    :func:`load_model` takes it) without reading the weights: ``config.json``'s (:func:`read_operating_point`), or
    Mid-Air's for a TensorFlow checkpoint (the official weights were trained on Mid-Air at 384x384)."""
    p = Path(path)
    if _is_tf(p):
        return MIDAIR_OPERATING_POINT
    folder = _model_dir(p)
    _, meta = read_config_file(folder)
    return read_operating_point(meta, str(folder / CONFIG_FILE))


def load_model(
    path: str | os.PathLike,
    device: str | torch.device = "cpu",
    mode: str = "fast",
    dtype: torch.dtype | str = torch.float32,
) -> FastModel | SceneModel:
    """Build the model stored at ``path`` and load its weights, in eval mode on ``device``.

    ``path`` is one of our model folders, or an official TensorFlow checkpoint (a prefix such as
    ``.../cp-0059.ckpt``, its ``.index`` file, or a folder with a ``checkpoint`` file), converted on the fly.

    ``mode="fast"`` (default) returns a :class:`~cosemdepth.inference.FastModel`: the fast streaming path in
    ``dtype`` (float32 by default: the modules' results up to float rounding; ``"bfloat16"`` / ``"int8"`` are faster
    and less exact, opt in after measuring), its modules in ``.model``. ``mode="reference"`` returns the
    :class:`~cosemdepth.models.SceneModel` itself, whose ``step`` / ``infer`` run the plain PyTorch modules (as do
    training and the ONNX export). Both have the same ``step`` and ``infer``.

    The returned model has ``model.operating_point``: the :class:`~cosemdepth.operating_point.OperatingPoint` its
    folder records (:func:`read_operating_point`; Mid-Air's for a TensorFlow checkpoint), or None.
    """
    if mode not in LOAD_MODES:
        raise ValueError(f"mode must be one of {list(LOAD_MODES)}, got {mode!r}")
    state_dict, cfg, origin, op = _read(path)
    if mode == "reference" and dtype not in (torch.float32, "float32", "fp32"):
        raise ValueError(f"dtype {dtype!r} is a setting of the fast path; mode='reference' runs float32")

    # Build on the meta device (no random initialisation to throw away) and adopt the loaded tensors, in float32
    # whatever precision they were stored in.
    with torch.device("meta"):
        model = build_model(cfg)
    state_dict = {k: v.float() if v.is_floating_point() else v for k, v in state_dict.items()}
    try:
        model.load_state_dict(state_dict, strict=True, assign=True)
    except RuntimeError as e:
        raise CheckpointError(f"{origin}: weights do not fit the {cfg.arch} model: {e}") from e
    model = model.eval().to(device)
    model.operating_point = op
    return model if mode == "reference" else FastModel(model, dtype)


__all__ = [
    "CONFIG_FILE",
    "FORMAT",
    "FORMAT_VERSION",
    "LOAD_MODES",
    "OPERATING_POINT",
    "WEIGHTS_CHECKSUM",
    "WEIGHTS_FILE",
    "check_finite",
    "check_state_dict",
    "load_model",
    "operating_point_of",
    "read_config_file",
    "read_model_files",
    "read_operating_point",
    "read_weights",
    "save_model",
    "save_weights",
]
