"""Reference velocities of packed clips: PHC's official code's central differences and Gaussian smoothing.

The motion library's default derives velocities by forward differences (:mod:`mocap.motion.library`).
PHC's paper says only "finite differences" (§3.1); its code computes linear velocities with
``np.gradient`` along time (central differences inside a clip, one-sided at its ends) and angular
velocities from ``q_{t+1} q_t^{-1}``, then smooths both with a Gaussian filter of σ = 2 frames
(``scipy.ndimage.gaussian_filter1d``, ``mode="nearest"``). :func:`central_differences` and
:func:`gaussian_smooth` are those two steps on the library's packed (all clips, frame order)
tensors, clip by clip: nothing leaks from one clip into the next.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def _check(x: Tensor, starts: Tensor, lengths: Tensor) -> None:
    if starts.shape != lengths.shape or int(lengths.sum()) != x.shape[0]:
        raise ValueError("starts/lengths must describe the packed frames of x")


def central_differences(x: Tensor, starts: Tensor, lengths: Tensor, fps: Tensor) -> Tensor:
    """``np.gradient(x, axis=0) * fps`` within each clip: ``(x[i+1] - x[i-1]) / 2`` inside, one-sided
    differences at the clip's first and last frames, 0 for a one-frame clip. ``x``: (F, ...) packed
    frames; ``starts``, ``lengths``, ``fps``: (C,) per clip."""
    _check(x, starts, lengths)
    out = torch.zeros_like(x)
    for s, n, f in zip(starts.tolist(), lengths.tolist(), fps.tolist()):
        if n < 2:
            continue
        c = x[s : s + n]
        g = torch.empty_like(c)
        g[0], g[-1] = c[1] - c[0], c[-1] - c[-2]
        if n > 2:
            g[1:-1] = (c[2:] - c[:-2]) / 2.0
        out[s : s + n] = g * f
    return out


def gaussian_kernel(sigma: float, truncate: float = 4.0) -> Tensor:
    """The normalized 1-D Gaussian of ``scipy.ndimage.gaussian_filter1d``: radius ``int(truncate σ + 0.5)``."""
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ValueError(f"sigma must be a positive number of frames, got {sigma!r}")
    radius = int(truncate * sigma + 0.5)
    k = torch.arange(-radius, radius + 1, dtype=torch.float64)
    w = torch.exp(-0.5 * (k / sigma) ** 2)
    return w / w.sum()


def gaussian_smooth(x: Tensor, starts: Tensor, lengths: Tensor, sigma: float) -> Tensor:
    """Each clip's frames filtered along time with :func:`gaussian_kernel` (``sigma`` frames), the
    clip's first/last frame repeated beyond its ends (``mode="nearest"``). Constants are kept."""
    _check(x, starts, lengths)
    w = gaussian_kernel(sigma).to(x.dtype)
    r = (len(w) - 1) // 2
    out = torch.empty_like(x)
    for s, n in zip(starts.tolist(), lengths.tolist()):
        c = x[s : s + n]
        idx = torch.clamp(torch.arange(-r, n + r), 0, n - 1)
        padded = c[idx]  # (n + 2r, ...)
        windows = padded.unfold(0, len(w), 1)  # (n, ..., 2r + 1)
        out[s : s + n] = (windows * w).sum(-1)
    return out


__all__ = ["central_differences", "gaussian_kernel", "gaussian_smooth"]
