"""Lens distortion models as pure functions on normalised image coordinates (kornia style: shapes in docstrings).

A camera maps a point ``X = (X, Y, Z)`` in its optical frame (x right, y down, z forward) to the *undistorted*
normalised coordinates ``(x, y) = (X / Z, Y / Z)``, then to the *distorted* normalised coordinates ``(x_d, y_d)``
by its lens model, then to pixels by ``u = fx x_d + s y_d + cx``, ``v = fy y_d + cy``. The models (names as used
throughout :mod:`cosemdepth.camera`):

* ``"pinhole"``: no distortion, ``(x_d, y_d) = (x, y)``; no coefficients.
* ``"radtan"``: OpenCV's radial-tangential model, ROS ``plumb_bob`` (5 coefficients) and ``rational_polynomial``
  (8), Kalibr ``radtan`` (4), COLMAP ``SIMPLE_RADIAL`` / ``RADIAL`` / ``OPENCV`` / ``FULL_OPENCV``. Coefficients
  ``(k1, k2, p1, p2, k3, k4, k5, k6)`` (missing ones are 0); with ``r^2 = x^2 + y^2``::

      radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
      x_d = x radial + 2 p1 x y + p2 (r^2 + 2 x^2)
      y_d = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y

* ``"equidistant"``: the Kannala-Brandt fisheye model of OpenCV's ``cv::fisheye``, ROS ``equidistant``, Kalibr
  ``equidistant`` and COLMAP ``OPENCV_FISHEYE``. Coefficients ``(k1, k2, k3, k4)``; with ``theta = atan(r)`` the
  angle off the optical axis::

      theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
      (x_d, y_d) = (theta_d / r) (x, y)

  so the distorted radius is ``theta_d`` (a pure equidistant lens, all ``k = 0``, has ``r_d = theta``). It
  describes rays up to (and beyond) 90 degrees off-axis, which no pinhole image holds; the undistorted coordinates
  of such rays do not exist (:func:`undistort_points` marks them).

The *radial profile* ``rho`` is the distorted radius as a function of the ray's radius parameter (``r`` for radtan,
``theta`` for equidistant). A lens is usable only where ``rho`` increases: past its first maximum the model folds
(two rays land on one pixel), which happens when a calibration is extrapolated beyond the field it was fitted on.
:func:`monotonic_limit` finds that point; the remap and the renderer use the model only inside it.
"""

from __future__ import annotations

import math

import torch

#: The lens models and their number of coefficients (those of :func:`coefficient_count`).
MODELS = {"pinhole": 0, "radtan": 8, "equidistant": 4}
#: Samples of the radial profile searched by :func:`monotonic_limit` (uniform in the off-axis angle).
PROFILE_SAMPLES = 20001
#: The largest off-axis angle (degrees) :func:`monotonic_limit` searches for a radtan lens (a pinhole
#: image cannot reach 90 degrees).
RADTAN_MAX_ANGLE = 89.5
#: Newton refinements of :func:`undistort_points` after the radial bisection.
NEWTON_STEPS = 8
#: Bisection steps of the radial inverse (float64: the interval shrinks below the precision).
BISECTION_STEPS = 64


def coefficient_count(model: str) -> int:
    """The number of coefficients of ``model`` (see :data:`MODELS`)."""
    if model not in MODELS:
        raise ValueError(f"unknown lens model {model!r}; one of {', '.join(MODELS)}")
    return MODELS[model]


def _radtan_radial(r2: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    num = 1 + r2 * (c[0] + r2 * (c[1] + r2 * c[4]))
    den = 1 + r2 * (c[5] + r2 * (c[6] + r2 * c[7]))
    return num / den


def _coeffs(coefficients, like: torch.Tensor, n: int) -> torch.Tensor:
    c = torch.as_tensor(coefficients, dtype=like.dtype, device=like.device).reshape(-1)
    if c.numel() > n:
        raise ValueError(f"expected at most {n} distortion coefficients, got {c.numel()}")
    return torch.nn.functional.pad(c, (0, n - c.numel()))


def distort_radtan(xy: torch.Tensor, coefficients) -> torch.Tensor:
    """Undistorted -> distorted normalised coordinates of the radtan model.

    Args:
        xy: ``[..., 2]`` undistorted normalised coordinates ``(x, y)``.
        coefficients: ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``.
    Returns:
        ``[..., 2]`` distorted normalised coordinates.
    """
    c = _coeffs(coefficients, xy, 8)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = _radtan_radial(r2, c)
    xd = x * radial + 2 * c[2] * x * y + c[3] * (r2 + 2 * x * x)
    yd = y * radial + c[2] * (r2 + 2 * y * y) + 2 * c[3] * x * y
    return torch.stack([xd, yd], -1)


def equidistant_theta_d(theta: torch.Tensor, coefficients) -> torch.Tensor:
    """``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` of ``theta [...]`` (radians)."""
    c = _coeffs(coefficients, theta, 4)
    t2 = theta * theta
    return theta * (1 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3]))))


def distort_equidistant(xy: torch.Tensor, coefficients) -> torch.Tensor:
    """Undistorted -> distorted normalised coordinates of the equidistant (Kannala-Brandt) model.

    Args:
        xy: ``[..., 2]`` undistorted normalised coordinates.
        coefficients: ``(k1, k2, k3, k4)``.
    Returns:
        ``[..., 2]``: ``(theta_d / r) (x, y)``, and ``(x, y)`` itself at ``r = 0``.
    """
    r = torch.sqrt(xy[..., 0] ** 2 + xy[..., 1] ** 2)
    theta_d = equidistant_theta_d(torch.atan(r), coefficients)
    tiny = r < 1e-12
    scale = torch.where(tiny, torch.ones_like(r), theta_d / torch.where(tiny, torch.ones_like(r), r))
    return xy * scale.unsqueeze(-1)


def distort(model: str, xy: torch.Tensor, coefficients=()) -> torch.Tensor:
    """Undistorted -> distorted normalised coordinates ``[..., 2]`` of ``model`` (see the module docstring)."""
    coefficient_count(model)
    if model == "radtan":
        return distort_radtan(xy, coefficients)
    if model == "equidistant":
        return distort_equidistant(xy, coefficients)
    return xy.clone()


def radial_profile(model: str, radius: torch.Tensor, coefficients=()) -> torch.Tensor:
    """The distorted radius ``rho [...]`` of a ray whose radius parameter is ``radius [...]``: ``r`` (undistorted
    normalised radius) for ``pinhole`` and ``radtan`` (tangential terms left out), ``theta`` (radians off-axis) for
    ``equidistant``."""
    coefficient_count(model)
    if model == "radtan":
        c = _coeffs(coefficients, radius, 8)
        return radius * _radtan_radial(radius * radius, c)
    if model == "equidistant":
        return equidistant_theta_d(radius, coefficients)
    return radius.clone()


def to_radius_parameter(model: str, r: torch.Tensor) -> torch.Tensor:
    """The radius parameter of :func:`radial_profile` for undistorted normalised radii ``r [...]`` (``atan(r)`` for
    ``equidistant``, ``r`` otherwise)."""
    return torch.atan(r) if model == "equidistant" else r


def monotonic_limit(model: str, coefficients=(), max_angle_deg: float | None = None) -> tuple[float, float]:
    """Where the radial profile stops increasing: ``(parameter, rho)`` at its first maximum, searched up to
    ``max_angle_deg`` off-axis (default :data:`RADTAN_MAX_ANGLE` for radtan and pinhole, 180 for equidistant). When
    the profile increases over the whole range, the end of the range and its ``rho``. The parameter is ``r`` (radtan,
    pinhole) or ``theta`` (equidistant), float64."""
    if max_angle_deg is None:
        max_angle_deg = 180.0 if model == "equidistant" else RADTAN_MAX_ANGLE
    angle = torch.linspace(0.0, math.radians(max_angle_deg), PROFILE_SAMPLES, dtype=torch.float64)
    param = angle if model == "equidistant" else torch.tan(angle)
    rho = radial_profile(model, param, coefficients)
    if model == "radtan":  # a denominator crossing zero ends the model too
        c = _coeffs(coefficients, param, 8)
        r2 = param * param
        ok = (1 + r2 * (c[5] + r2 * (c[6] + r2 * c[7]))) > 0
        rho = torch.where(ok, rho, torch.full_like(rho, -math.inf))
    rising = (rho[1:] > rho[:-1]) & torch.isfinite(rho[1:])
    stop = (~rising).nonzero()
    last = int(stop[0]) if stop.numel() else PROFILE_SAMPLES - 1
    return float(param[last]), float(rho[last])


def invert_profile(model: str, rho: torch.Tensor, coefficients, limit: float) -> torch.Tensor:
    """The radius parameter ``[...]`` whose radial profile is ``rho [...]``, by bisection on ``[0, limit]`` (where
    the profile increases: :func:`monotonic_limit`); NaN where ``rho`` is beyond the profile at ``limit``."""
    lo = torch.zeros_like(rho)
    hi = torch.full_like(rho, limit)
    top = radial_profile(model, hi, coefficients)
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        below = radial_profile(model, mid, coefficients) < rho
        lo = torch.where(below, mid, lo)
        hi = torch.where(below, hi, mid)
    out = 0.5 * (lo + hi)
    return torch.where(rho <= top, out, torch.full_like(out, math.nan))


def _radtan_jacobian(xy: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """``[..., 2, 2]`` Jacobian of :func:`distort_radtan` at ``xy [..., 2]`` (``c``: 8 coefficients)."""
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    num = 1 + r2 * (c[0] + r2 * (c[1] + r2 * c[4]))
    den = 1 + r2 * (c[5] + r2 * (c[6] + r2 * c[7]))
    dnum = c[0] + r2 * (2 * c[1] + 3 * c[4] * r2)  # d num / d r2
    dden = c[5] + r2 * (2 * c[6] + 3 * c[7] * r2)
    radial = num / den
    drad = (dnum * den - num * dden) / (den * den)  # d radial / d r2
    p1, p2 = c[2], c[3]
    dxdx = radial + x * drad * 2 * x + 2 * p1 * y + 6 * p2 * x
    dxdy = x * drad * 2 * y + 2 * p1 * x + 2 * p2 * y
    dydx = y * drad * 2 * x + 2 * p1 * x + 2 * p2 * y
    dydy = radial + y * drad * 2 * y + 6 * p1 * y + 2 * p2 * x
    return torch.stack([torch.stack([dxdx, dxdy], -1), torch.stack([dydx, dydy], -1)], -2)


def undistort_points(model: str, xy_d: torch.Tensor, coefficients=(), limit: float | None = None) -> torch.Tensor:
    """Distorted -> undistorted normalised coordinates: the inverse of :func:`distort` inside the monotonic part of
    the lens (compute in float64 for exact results).

    The radial part is inverted by bisection (:func:`invert_profile`, unique inside :func:`monotonic_limit`), then
    radtan's tangential terms by Newton steps from there.

    Args:
        xy_d: ``[..., 2]`` distorted normalised coordinates.
        limit: the radius parameter where the lens stops being monotonic (default :func:`monotonic_limit`).
    Returns:
        ``[..., 2]`` undistorted normalised coordinates; NaN for points no ray inside the limit reaches, and for
        equidistant rays at 90 degrees or more off-axis (they have no pinhole coordinates).
    """
    coefficient_count(model)
    if model == "pinhole":
        return xy_d.clone()
    if limit is None:
        limit = monotonic_limit(model, coefficients)[0]
    rho = torch.sqrt(xy_d[..., 0] ** 2 + xy_d[..., 1] ** 2)
    param = invert_profile(model, rho, coefficients, limit)
    if model == "equidistant":
        r = torch.where(param < math.pi / 2, torch.tan(param), torch.full_like(param, math.nan))
    else:
        r = param
    tiny = rho < 1e-15
    scale = torch.where(tiny, torch.ones_like(rho), r / torch.where(tiny, torch.ones_like(rho), rho))
    xy = xy_d * scale.unsqueeze(-1)
    if model == "radtan":
        c = _coeffs(coefficients, xy, 8)
        if bool((c[2:4] != 0).any()):
            for _ in range(NEWTON_STEPS):
                e = distort_radtan(xy, c) - xy_d
                j = _radtan_jacobian(xy, c)
                a, b, cc, d = j[..., 0, 0], j[..., 0, 1], j[..., 1, 0], j[..., 1, 1]
                det = a * d - b * cc
                step = torch.stack([d * e[..., 0] - b * e[..., 1], a * e[..., 1] - cc * e[..., 0]], -1)
                xy = xy - step / det.unsqueeze(-1)
    return xy


__all__ = [
    "MODELS",
    "coefficient_count",
    "distort",
    "distort_equidistant",
    "distort_radtan",
    "equidistant_theta_d",
    "invert_profile",
    "monotonic_limit",
    "radial_profile",
    "to_radius_parameter",
    "undistort_points",
]
