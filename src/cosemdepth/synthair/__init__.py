"""SynthAir: a procedural aerial world rendered into the Mid-Air format (colour, exact depth, labels, poses).

- :mod:`.world` (:mod:`.terrain`, :mod:`.objects`, :mod:`.buildings`) builds the world of a seed;
- :mod:`.trajectory` makes smooth 6-DoF flights (Mid-Air ground truth: NED, body x forward, 100 Hz);
  :mod:`.motion` warps their timeline (motion profiles: hover, yaw in place, slow/fast segments, ramps);
- :mod:`.render` renders colour, z-depth and Mid-Air labels for poses (:mod:`.raymarch`, :mod:`.shading`,
  :mod:`.climate`);
- :mod:`.writer` writes the Mid-Air tree, ``sensor_records.hdf5``, the split CSVs and ``synthair.json``
  (``cosemdepth synth``); :mod:`.export` the flights' video and flight-controller logs (``--export``).

Attributes are imported lazily (``cosemdepth synth --help`` does not load torch).
"""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "CLIMATES": ".climate",
    "Climate": ".climate",
    "get_climate": ".climate",
    "SKY_DEPTH": ".render",
    "Frame": ".render",
    "render_frame": ".render",
    "render_frames": ".render",
    "ENVIRONMENT": ".writer",
    "SynthConfig": ".writer",
    "generate": ".writer",
    "World": ".world",
    "get_world": ".world",
    "build_world": ".world",
    "make_flight": ".trajectory",
    "MotionProfile": ".motion",
    "parse_motion": ".motion",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
