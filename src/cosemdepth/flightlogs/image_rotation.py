"""The camera's rotation between two frames, measured from the images alone (for the clock offset of a video).

Model: a rotation-only homography. With the package's motion convention (``X_prev = R X_curr + t``, camera axes x
right, y down, z forward) and the translation neglected, the pixel ``x`` of the current frame shows what the previous
frame shows at ``pi(K R K^-1 x)``, so ``I_curr(x) = I_prev(pi(K R K^-1 x))``. :func:`frame_rotation` finds ``R``
(as a rotation vector) by Gauss-Newton on that photometric equation over an image pyramid (compositional updates
``R <- R exp([delta]x)``, Huber-weighted residuals; each level smoothed with a binomial filter so that central
differences give its gradients, and normalised to zero mean and unit variance to absorb exposure changes), started from the global shift that phase correlation finds at the coarsest level (pan and tilt:
a shift ``(dx, dy)`` is a rotation ``(-dy / f, dx / f, 0)`` near the image centre).

The translation's parallax biases the estimate (a sideways motion looks like a pan); the clock offset search only
needs the rotation's time course, which the bias does not shift. A pair is reported not ``ok`` when the images
cannot tell a rotation: too little texture for one of the three axes, too little overlap after warping, or no
convergence.

Images are ``[H, W]`` float arrays (gray, any scale), a few hundred pixels across at most: the measurement works
on a small picture (``frames(size=..., gray=True)`` of :class:`~cosemdepth.data.video.VideoReader`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Pyramid levels below the given size (each halves it); the coarsest takes the phase correlation.
LEVELS = 2
#: The smallest side (pixels) of a pyramid level.
MIN_LEVEL_PX = 16
#: Gauss-Newton iterations per level at most.
ITERATIONS = 12
#: Gauss-Newton stops when an update moves the picture by less than this (pixels at the level).
STEP_PX = 0.005
#: The Huber threshold on normalised residuals.
HUBER = 0.5
#: A pair is ok when at least this fraction of the pixels stays inside the previous frame after warping.
MIN_OVERLAP = 0.4
#: ... the Gauss-Newton normal matrix's smallest eigenvalue is at least this fraction of its largest (every axis of
#: rotation changes the picture: straight stripes, say, do not show a rotation along them) ...
MIN_CONDITIONING = 0.05
#: ... and the RMS residual after alignment (in units of the images' standard deviation; two unrelated images give
#: about 1.4) is at most this.
MAX_RESIDUAL = 1.0


@dataclass(frozen=True)
class FrameRotation:
    """``rotvec`` [3] rotation vector of ``R`` (radians, camera axes), ``ok`` (the images determine it),
    ``residual`` (RMS normalised photometric residual after alignment), ``overlap`` (fraction of pixels seen by
    both frames)."""

    rotvec: np.ndarray
    ok: bool
    residual: float
    overlap: float


def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues: ``[..., 3]`` rotation vectors (radians) -> ``[..., 3, 3]`` rotation matrices."""
    v = np.asarray(v, dtype=np.float64)
    theta = np.linalg.norm(v, axis=-1)[..., None, None]
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24, (1 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def matrix_to_rotvec(r: np.ndarray) -> np.ndarray:
    """``[..., 3, 3]`` rotation matrices -> ``[..., 3]`` rotation vectors (angle in [0, pi])."""
    r = np.asarray(r, dtype=np.float64)
    cos = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    theta = np.arccos(cos)
    w = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    sin = np.sin(theta)
    small = sin < 1e-6
    scale = np.where(small, 0.5 + theta**2 / 12, theta / (2 * np.where(small, 1.0, sin)))
    out = w * scale[..., None]
    near_pi = (theta > np.pi / 2) & small
    if np.any(near_pi):  # theta ~ pi: the axis from the symmetric part
        for idx in zip(*np.nonzero(near_pi)) if near_pi.ndim else [()]:
            m = r[idx]
            axis = np.sqrt(np.clip((np.diag(m) + 1) / 2, 0, None))
            j = int(np.argmax(axis))
            axis = (m[j] + m[:, j]) / 2 / axis[j] if axis[j] > 0 else axis
            out[idx] = axis / np.linalg.norm(axis) * theta[idx]
    return out


def _normalise(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img, dtype=np.float64)
    s = img.std()
    return (img - img.mean()) / (s if s > 1e-12 else 1.0)


def _downsample(img: np.ndarray) -> np.ndarray:
    """2x2 box average (an odd last row/column is dropped)."""
    h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
    x = img[:h, :w]
    return 0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])


def _blur(img: np.ndarray) -> np.ndarray:
    """Binomial [1, 2, 1] / 4 smoothing along both axes (edges replicated): the central differences of the
    gradient then hold for the picture's finest detail too."""
    p = np.pad(img, 1, mode="edge")
    x = 0.25 * p[:, :-2] + 0.5 * p[:, 1:-1] + 0.25 * p[:, 2:]
    return 0.25 * x[:-2] + 0.5 * x[1:-1] + 0.25 * x[2:]


def _gradients(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central differences (one-sided at the borders): ``(d/dx, d/dy)``."""
    return np.gradient(img, axis=1), np.gradient(img, axis=0)


def _sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` at pixel-centre coordinates ``(x, y)`` (pixel ``(i, j)`` centred at ``(j, i)``);
    coordinates are clamped to the image (callers mask points outside)."""
    h, w = img.shape
    x = np.clip(x, 0, w - 1.000001)
    y = np.clip(y, 0, h - 1.000001)
    x0 = np.floor(x).astype(np.intp)
    y0 = np.floor(y).astype(np.intp)
    ax, ay = x - x0, y - y0
    i00 = img[y0, x0]
    i01 = img[y0, x0 + 1]
    i10 = img[y0 + 1, x0]
    i11 = img[y0 + 1, x0 + 1]
    return (i00 * (1 - ax) + i01 * ax) * (1 - ay) + (i10 * (1 - ax) + i11 * ax) * ay


def phase_correlation(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The shift ``(dx, dy)`` in pixels with ``b(x) ~ a(x + d)`` (sub-pixel: a parabola through the peak), for
    ``[H, W]`` arrays of one size; a Hann window tapers the borders."""
    h, w = a.shape
    win = np.outer(np.hanning(h), np.hanning(w))
    fa = np.fft.rfft2(_normalise(a) * win)
    fb = np.fft.rfft2(_normalise(b) * win)
    cross = fa * np.conj(fb)
    cross /= np.maximum(np.abs(cross), 1e-12)
    corr = np.fft.irfft2(cross, s=(h, w))
    iy, ix = np.unravel_index(int(np.argmax(corr)), corr.shape)

    def peak(c_m, c_0, c_p):
        den = c_m - 2 * c_0 + c_p
        return 0.0 if abs(den) < 1e-12 else 0.5 * (c_m - c_p) / den

    sx = peak(corr[iy, (ix - 1) % w], corr[iy, ix], corr[iy, (ix + 1) % w])
    sy = peak(corr[(iy - 1) % h, ix], corr[iy, ix], corr[(iy + 1) % h, ix])
    dx = (ix + sx + w / 2) % w - w / 2
    dy = (iy + sy + h / 2) % h - h / 2
    return float(dx), float(dy)


def _align(prev: np.ndarray, curr: np.ndarray, f: float, r: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """Gauss-Newton refinement of ``R`` at one level: ``(R, rms residual, overlap, conditioning)``."""
    h, w = curr.shape
    cx, cy = (w - 1) / 2, (h - 1) / 2  # pixel-centre coordinates of the optical centre (a centred camera)
    gx_img, gy_img = _gradients(prev)
    jj, ii = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    p = np.stack([(jj - cx) / f, (ii - cy) / f, np.ones_like(jj)], -1).reshape(-1, 3)  # rays of the current frame
    target = curr.reshape(-1)
    margin = 1.0
    rms, overlap, cond = np.inf, 0.0, 0.0
    for _ in range(ITERATIONS):
        q = p @ r.T
        qz = q[:, 2]
        front = qz > 1e-6
        qz = np.where(front, qz, 1.0)
        u = f * q[:, 0] / qz + cx
        v = f * q[:, 1] / qz + cy
        inside = front & (u >= margin) & (u <= w - 1 - margin) & (v >= margin) & (v <= h - 1 - margin)
        overlap = float(inside.mean())
        if overlap < 0.05:
            break
        u, v, q, qz = u[inside], v[inside], q[inside], qz[inside]
        res = _sample(prev, u, v) - target[inside]
        gx = _sample(gx_img, u, v)
        gy = _sample(gy_img, u, v)
        # d pi / d q (2x3) times d q / d delta = -R [p]x, whose column k is -(R p) x (R e_k) = -q x r_k
        qx_, qy_ = q[:, 0:1], q[:, 1:2]
        dqx = qz[:, None] * r[1] - qy_ * r[2]  # -(q x r_k): rows of the matrix of columns r_k
        dqy = qx_ * r[2] - qz[:, None] * r[0]
        dqz = qy_ * r[0] - qx_ * r[1]
        iz = 1.0 / qz[:, None]
        jx = f * iz * (dqx - qx_ * iz * dqz)
        jy = f * iz * (dqy - qy_ * iz * dqz)
        jac = gx[:, None] * jx + gy[:, None] * jy  # [n, 3]
        a = np.abs(res)
        wts = np.where(a <= HUBER, 1.0, HUBER / np.maximum(a, 1e-12))
        hess = (jac * wts[:, None]).T @ jac
        grad = (jac * wts[:, None]).T @ res
        rms = float(np.sqrt(np.mean(res**2)))
        ev = np.linalg.eigvalsh(hess)
        cond = float(ev[0] / max(ev[-1], 1e-30))
        try:
            delta = -np.linalg.solve(hess + 1e-9 * np.eye(3) * np.trace(hess), grad)
        except np.linalg.LinAlgError:
            break
        r = r @ rotvec_to_matrix(delta)
        if np.linalg.norm(delta) * f < STEP_PX:
            break
    return r, rms, overlap, cond


def frame_rotation(prev: np.ndarray, curr: np.ndarray, focal_px: float) -> FrameRotation:
    """The rotation ``R`` with ``X_prev = R X_curr`` between two ``[H, W]`` gray frames of a centred pinhole camera
    of focal length ``focal_px`` (pixels at this size), as a rotation vector in camera axes (x right, y down,
    z forward); see the module docstring."""
    prev = _normalise(np.asarray(prev, dtype=np.float64).squeeze())
    curr = _normalise(np.asarray(curr, dtype=np.float64).squeeze())
    if prev.shape != curr.shape or prev.ndim != 2:
        raise ValueError(f"frame_rotation needs two [H, W] images of one size, got {prev.shape} and {curr.shape}")
    pyramid = [(prev, curr, float(focal_px))]
    for _ in range(LEVELS):
        a, b, f = pyramid[-1]
        if min(a.shape) < 2 * MIN_LEVEL_PX:
            break
        pyramid.append((_downsample(a), _downsample(b), f / 2))
    pyramid = [(_normalise(_blur(a)), _normalise(_blur(b)), f) for a, b, f in pyramid]
    a, b, f = pyramid[-1]
    dx, dy = phase_correlation(a, b)
    r = rotvec_to_matrix(np.array([-np.arctan2(dy, f), np.arctan2(dx, f), 0.0]))
    rms = overlap = cond = 0.0
    for a, b, f in reversed(pyramid):
        r, rms, overlap, cond = _align(a, b, f, r)
    ok = bool(overlap >= MIN_OVERLAP and cond >= MIN_CONDITIONING and rms <= MAX_RESIDUAL)
    return FrameRotation(matrix_to_rotvec(r), ok, rms, overlap)


__all__ = [
    "FrameRotation",
    "frame_rotation",
    "matrix_to_rotvec",
    "phase_correlation",
    "rotvec_to_matrix",
]
