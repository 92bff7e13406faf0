"""SynthAir: a procedural aerial world rendered into the Mid-Air format (colour, exact depth, labels, poses).

- :mod:`.world` (terrain, object tile, buildings) builds the world of a seed;
- :mod:`.trajectory` makes smooth 6-DoF flights (Mid-Air ground truth, NED, 100 Hz);
- :mod:`.render` renders colour, z-depth and Mid-Air labels for a pose (:mod:`.raymarch`, :mod:`.shading`);
- :mod:`.writer` writes the Mid-Air tree, ``sensor_records.hdf5``, the split CSVs and ``synthair.json``.
"""

from .climate import CLIMATES, Climate, get_climate
from .render import SKY_DEPTH, Frame, render_frame
from .writer import ENVIRONMENT, SynthConfig, generate

__all__ = [
    "CLIMATES", "Climate", "get_climate", "SKY_DEPTH", "Frame", "render_frame", "ENVIRONMENT", "SynthConfig",
    "generate",
]
