"""Periodic noise used to build the SynthAir world (numpy, float64, deterministic for a generator).

Everything here is periodic so that the world tiles seamlessly: the renderer wraps world coordinates.
"""

from __future__ import annotations

import numpy as np


def fractal_field(
    rng: np.random.Generator, n: int, spacing: float, beta: float, cutoff: float, upsample: int = 1
) -> np.ndarray:
    """Periodic fractal (1/f^beta amplitude spectrum) field by spectral synthesis.

    Args:
        rng: random generator.
        n: grid size (the field is ``[n, n]``).
        spacing: metres per grid cell.
        beta: spectral slope of the amplitude, ``|F(k)| ~ (k^2 + k_c^2)^(-beta/2)``.
        cutoff: wavelength in metres above which the spectrum flattens (``k_c = 1 / cutoff``).
        upsample: synthesise on an ``n / upsample`` grid and interpolate (bilinear) up to ``n``; for smooth fields.
    Returns:
        ``[n, n]`` float32 field with zero mean and unit standard deviation.
    """
    m = n // upsample
    kx = np.fft.fftfreq(m, d=spacing * upsample)
    ky = np.fft.rfftfreq(m, d=spacing * upsample)
    k2 = kx[:, None] ** 2 + ky[None, :] ** 2
    amp = (k2 + (1.0 / cutoff) ** 2) ** (-beta / 2)
    amp[0, 0] = 0.0
    spec = ((rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape)) * amp).astype(np.complex64)
    field = np.fft.irfft2(spec, s=(m, m)).astype(np.float32)
    if upsample > 1:
        field = upsample_periodic(field, upsample)
    field -= field.mean(dtype=np.float64)
    field /= field.std(dtype=np.float64)
    return field


def upsample_periodic(field: np.ndarray, factor: int) -> np.ndarray:
    """Bilinear upsampling of a periodic grid by an integer factor (sample ``k`` of the result lies at ``k / factor``
    in input cells)."""
    f = (np.arange(factor) / factor).astype(field.dtype)
    out = field
    for axis in (0, 1):
        a = np.moveaxis(out, axis, 0)
        b = np.roll(a, -1, axis=0)
        up = a[:, None] * (1 - f)[None, :, None] + b[:, None] * f[None, :, None]
        out = np.moveaxis(up.reshape(-1, *a.shape[1:]), 0, axis)
    return out


def smooth_periodic_1d(values: np.ndarray, sigma_cells: float) -> np.ndarray:
    """Gaussian smoothing of a periodic 1-D signal (FFT convolution)."""
    n = len(values)
    k = np.fft.rfftfreq(n)
    kernel = np.exp(-2.0 * (np.pi * k * sigma_cells) ** 2)
    return np.fft.irfft(np.fft.rfft(values) * kernel, n=n)


def blur_periodic_2d(field: np.ndarray, sigma_cells: float) -> np.ndarray:
    """Gaussian blur of a periodic 2-D field (FFT convolution)."""
    n0, n1 = field.shape
    k0 = np.fft.fftfreq(n0)[:, None]
    k1 = np.fft.rfftfreq(n1)[None, :]
    kernel = np.exp(-2.0 * (np.pi * sigma_cells) ** 2 * (k0**2 + k1**2))
    return np.fft.irfft2(np.fft.rfft2(field) * kernel, s=field.shape)


def max_filter_periodic(field: np.ndarray, radius: int) -> np.ndarray:
    """Max over the ``(2 radius + 1)^2`` neighbourhood of every cell of a periodic grid."""
    out = field.copy()
    for axis in (0, 1):
        acc = out.copy()
        for s in range(1, radius + 1):
            acc = np.maximum(acc, np.roll(out, s, axis=axis))
            acc = np.maximum(acc, np.roll(out, -s, axis=axis))
        out = acc
    return out


def bilinear_periodic(field: np.ndarray, x: np.ndarray, y: np.ndarray, spacing: float) -> np.ndarray:
    """Sample a periodic grid (cell ``[i, j]`` at ``(i * spacing, j * spacing)``) bilinearly at points ``(x, y)``."""
    n0, n1 = field.shape
    gx = np.asarray(x, dtype=np.float64) / spacing
    gy = np.asarray(y, dtype=np.float64) / spacing
    i0 = np.floor(gx)
    j0 = np.floor(gy)
    fx = gx - i0
    fy = gy - j0
    i0 = i0.astype(np.int64) % n0
    j0 = j0.astype(np.int64) % n1
    i1 = (i0 + 1) % n0
    j1 = (j0 + 1) % n1
    return (
        field[i0, j0] * (1 - fx) * (1 - fy)
        + field[i1, j0] * fx * (1 - fy)
        + field[i0, j1] * (1 - fx) * fy
        + field[i1, j1] * fx * fy
    )


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 at ``e0`` to 1 at ``e1`` (float32 in, float32 out; float64 otherwise)."""
    x = np.asarray(x)
    dt = np.float32 if x.dtype == np.float32 else np.float64
    t = (x - dt(e0)) * dt(1.0 / (e1 - e0))
    np.clip(t, 0.0, 1.0, out=t)
    return t * t * (dt(3.0) - dt(2.0) * t)
