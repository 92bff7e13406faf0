"""Climates: light colour and direction, sky colours, clouds and fog (all colours linear RGB)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

#: Climate preset names (``cosemdepth synth --climate``).
CLIMATES = ("sunny", "cloudy", "foggy", "sunset")


@dataclass(frozen=True)
class Climate:
    """A climate preset: sun, sky and ambient light, clouds, fog and exposure (colours linear RGB)."""

    name: str
    sun_elevation: float  # degrees above the horizon
    sun_azimuth: float  # degrees, clockwise from north (towards east)
    sun_colour: tuple[float, float, float]  # direct light
    sky_light: tuple[float, float, float]  # ambient light from the upper hemisphere
    ground_light: tuple[float, float, float]  # ambient light bounced from below
    zenith: tuple[float, float, float]  # sky colour straight up
    horizon: tuple[float, float, float]  # sky colour at the horizon (also the fog colour)
    sun_glow: tuple[float, float, float]  # sky brightening around the sun
    fog_distance: float  # metres; fog fraction 1 - exp(-(distance / fog_distance)^2)
    cloud_cover: float  # 0 (clear) .. 1 (overcast)
    cloud_colour: tuple[float, float, float]
    exposure: float

    def sun_direction(self) -> np.ndarray:
        """Unit vector towards the sun in world ``(x north, y east, up)``."""
        e, a = np.radians(self.sun_elevation), np.radians(self.sun_azimuth)
        return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])

    def with_sun_azimuth(self, azimuth: float) -> "Climate":
        return dataclasses.replace(self, sun_azimuth=float(azimuth) % 360.0)


PRESETS: dict[str, Climate] = {
    "sunny": Climate(
        name="sunny",
        sun_elevation=52.0,
        sun_azimuth=150.0,
        sun_colour=(2.9, 2.7, 2.35),
        sky_light=(0.42, 0.55, 0.78),
        ground_light=(0.16, 0.17, 0.12),
        zenith=(0.16, 0.34, 0.78),
        horizon=(0.62, 0.74, 0.90),
        sun_glow=(0.9, 0.8, 0.6),
        fog_distance=1500.0,
        cloud_cover=0.25,
        cloud_colour=(1.0, 1.0, 1.0),
        exposure=1.15,
    ),
    "cloudy": Climate(
        name="cloudy",
        sun_elevation=40.0,
        sun_azimuth=120.0,
        sun_colour=(0.55, 0.55, 0.55),
        sky_light=(0.85, 0.88, 0.92),
        ground_light=(0.22, 0.22, 0.20),
        zenith=(0.46, 0.50, 0.56),
        horizon=(0.70, 0.72, 0.74),
        sun_glow=(0.15, 0.15, 0.14),
        fog_distance=1000.0,
        cloud_cover=0.85,
        cloud_colour=(0.80, 0.81, 0.83),
        exposure=1.5,
    ),
    "foggy": Climate(
        name="foggy",
        sun_elevation=30.0,
        sun_azimuth=200.0,
        sun_colour=(0.45, 0.44, 0.42),
        sky_light=(0.80, 0.82, 0.84),
        ground_light=(0.25, 0.25, 0.24),
        zenith=(0.66, 0.68, 0.70),
        horizon=(0.74, 0.75, 0.76),
        sun_glow=(0.10, 0.10, 0.09),
        fog_distance=260.0,
        cloud_cover=0.0,
        cloud_colour=(0.8, 0.8, 0.8),
        exposure=1.45,
    ),
    "sunset": Climate(
        name="sunset",
        sun_elevation=9.0,
        sun_azimuth=255.0,
        sun_colour=(2.6, 1.45, 0.62),
        sky_light=(0.48, 0.44, 0.56),
        ground_light=(0.20, 0.14, 0.09),
        zenith=(0.16, 0.22, 0.48),
        horizon=(0.95, 0.58, 0.34),
        sun_glow=(1.6, 0.8, 0.3),
        fog_distance=1300.0,
        cloud_cover=0.35,
        cloud_colour=(0.95, 0.60, 0.45),
        exposure=1.6,
    ),
}


def get_climate(name: str) -> Climate:
    """The climate preset ``name`` (one of :data:`CLIMATES`); ValueError naming the choices for another."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown climate {name!r}; choose from {', '.join(CLIMATES)}") from None
