"""95% intervals of the numbers mocap reports (issue 63): what a re-run on another machine should land
in. Physics is chaotic: the last bits of a CPU's float path decide a trajectory, so a number is
reproducible bit-exactly on the same machine and build only; elsewhere it is reproducible within the
interval of the episodes, clips or rollouts it averages.

* :func:`wilson`: a share of ``k`` successes in ``n`` trials (Wilson score interval, which stays
  inside [0, 1] and is not empty at 0 or n);
* :func:`bootstrap_mean`: the mean of a few values (percentile bootstrap of the mean, a fixed seed so
  that the interval itself is reproducible);
* :func:`normal_mean`: a mean known only by its std over ``n`` effective samples (mean ± 1.96 std / √n).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

Z95 = 1.959963984540054


def wilson(k: float, n: int) -> tuple[float, float] | None:
    """95% Wilson score interval of the share ``k / n`` (None when n = 0)."""
    if n <= 0:
        return None
    p = min(max(k / n, 0.0), 1.0)
    centre = (p + Z95**2 / (2 * n)) / (1 + Z95**2 / n)
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n)) / (1 + Z95**2 / n)
    lo = 0.0 if p <= 0.0 else max(0.0, centre - half)  # exactly 0 and 1 at the ends (not rounding residue)
    hi = 1.0 if p >= 1.0 else min(1.0, centre + half)
    return lo, hi


def bootstrap_mean(values: Sequence[float], resamples: int = 2000, seed: int = 0) -> tuple[float, float] | None:
    """95% percentile-bootstrap interval of the mean of the finite ``values`` (None for fewer than two)."""
    data = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64)
    if len(data) < 2:
        return None
    rng = np.random.default_rng(seed)
    means = data[rng.integers(0, len(data), size=(resamples, len(data)))].mean(1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def normal_mean(mean: float, std: float, n: int) -> tuple[float, float] | None:
    """mean ± 1.96 std / √n (None when it cannot be formed)."""
    if n < 2 or not (math.isfinite(mean) and math.isfinite(std)):
        return None
    half = Z95 * std / math.sqrt(n)
    return mean - half, mean + half


def inside(value: float, interval: Sequence[float], slack: float = 1e-9) -> bool:
    """``value`` within ``[lo, hi]`` (a relative ``slack`` for the last bits of the bounds themselves)."""
    lo, hi = float(interval[0]), float(interval[1])
    pad = slack * max(1.0, abs(lo), abs(hi))
    return math.isfinite(value) and lo - pad <= value <= hi + pad


__all__ = ["Z95", "bootstrap_mean", "inside", "normal_mean", "wilson"]
