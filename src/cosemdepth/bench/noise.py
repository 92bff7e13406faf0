"""Run-to-run spread of repeated timings and a verdict that does not read noise as a difference (pure functions).

A benchmark repeats one step many times on a machine that other processes share; the repeats spread. Two paths are
only called faster/slower than each other when their interquartile ranges do not overlap: the middle half of one
run lies entirely below the middle half of the other. Otherwise the difference is "within noise".
"""

from __future__ import annotations

import statistics
from typing import Optional, Sequence


def quantile(values: Sequence[float], q: float) -> float:
    """Linear-interpolation quantile (``0 <= q <= 1``, numpy's default rule) of ``values`` (any order)."""
    v = sorted(values)
    if not v:
        raise ValueError("no values")
    pos = (len(v) - 1) * q
    lo = int(pos)
    hi = min(lo + 1, len(v) - 1)
    return v[lo] + (v[hi] - v[lo]) * (pos - lo)


def spread(values: Sequence[float]) -> dict:
    """``min``, ``q25``, ``median``, ``q75``, ``max`` of repeated measurements."""
    return {
        "min": min(values),
        "q25": quantile(values, 0.25),
        "median": statistics.median(values),
        "q75": quantile(values, 0.75),
        "max": max(values),
    }


def compare_times(a: Sequence[float], b: Sequence[float]) -> str:
    """``"faster"`` when ``a``'s interquartile range lies entirely below ``b``'s, ``"slower"`` when entirely above,
    else ``"within noise"`` (times: smaller is better)."""
    sa, sb = spread(a), spread(b)
    if sa["q75"] < sb["q25"]:
        return "faster"
    if sa["q25"] > sb["q75"]:
        return "slower"
    return "within noise"


def format_spread(s: dict, unit: str = "ms") -> str:
    """``"12.3 ms (min 11.9, IQR 12.1-12.8, max 14.0)"``."""
    return f"{s['median']:.1f} {unit} (min {s['min']:.1f}, IQR {s['q25']:.1f}-{s['q75']:.1f}, max {s['max']:.1f})"


def format_busy(fraction: Optional[float]) -> str:
    """A CPU busy fraction as ``"machine busy: 51 %"`` (``"machine busy: unknown"`` without /proc/stat)."""
    return "machine busy: unknown" if fraction is None else f"machine busy: {100 * fraction:.0f} %"
