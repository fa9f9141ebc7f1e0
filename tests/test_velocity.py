"""Reference velocities: PHC's code's central differences + Gaussian smoothing (mocap.motion.velocity)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.motion.velocity import central_differences, gaussian_kernel, gaussian_smooth

clip_lengths = st.lists(st.integers(1, 25), min_size=1, max_size=4)


def _packed(lengths: list[int], seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    ln = torch.tensor(lengths)
    starts = torch.cumsum(ln, 0) - ln
    return torch.randn(int(ln.sum()), 2, 3, generator=g, dtype=torch.float64), starts, ln


@settings(max_examples=40, deadline=None)
@given(clip_lengths, st.integers(0, 10_000), st.floats(10.0, 120.0))
def test_central_differences_are_numpy_gradient_per_clip(lengths, seed, fps):
    x, starts, ln = _packed(lengths, seed)
    got = central_differences(x, starts, ln, torch.full((len(lengths),), fps, dtype=torch.float64))
    for s, n in zip(starts.tolist(), lengths):
        want = np.zeros((n, 2, 3)) if n < 2 else np.gradient(x[s : s + n].numpy(), axis=0) * fps
        np.testing.assert_allclose(got[s : s + n].numpy(), want, rtol=1e-12, atol=1e-12)


def _smooth_direct(c: np.ndarray, sigma: float) -> np.ndarray:
    """scipy's gaussian_filter1d(mode='nearest', truncate=4) written as an explicit sum."""
    r = int(4.0 * sigma + 0.5)
    w = np.array([math.exp(-0.5 * (k / sigma) ** 2) for k in range(-r, r + 1)])
    w /= w.sum()
    n = len(c)
    return np.stack([sum(w[k + r] * c[min(max(i + k, 0), n - 1)] for k in range(-r, r + 1)) for i in range(n)])


@settings(max_examples=30, deadline=None)
@given(clip_lengths, st.integers(0, 10_000), st.floats(0.3, 4.0))
def test_gaussian_smoothing_is_per_clip_with_nearest_edges(lengths, seed, sigma):
    x, starts, ln = _packed(lengths, seed)
    got = gaussian_smooth(x, starts, ln, sigma)
    for s, n in zip(starts.tolist(), lengths):
        np.testing.assert_allclose(got[s : s + n].numpy(), _smooth_direct(x[s : s + n].numpy(), sigma), atol=1e-12)
    const = torch.full_like(x, 3.25)
    torch.testing.assert_close(gaussian_smooth(const, starts, ln, sigma), const)  # constants are kept


def test_gaussian_kernel_is_normalized_and_rejects_bad_sigma():
    w = gaussian_kernel(2.0)
    assert len(w) == 2 * 8 + 1 and float(w.sum()) == pytest.approx(1.0) and int(w.argmax()) == 8
    with pytest.raises(ValueError, match="sigma"):
        gaussian_kernel(0.0)


def test_library_uses_the_sources_velocity_choice():
    """``velocities: central_smoothed`` on the motion source reaches the library: DoF velocities are
    the smoothed central differences of the DoFs, and differ from the forward differences."""
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins

    sk = get_plugins().get("humanoid", "amp").build(None)
    fwd = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk"])).load(sk), sk, dtype=torch.float64)
    ms = DeepMimicSource(DeepMimicParams(clips=["walk"], velocities="central_smoothed", velocity_sigma=2.0)).load(sk)
    assert ms.velocities == "central_smoothed"
    lib = MotionLibrary(ms, sk, dtype=torch.float64)
    starts, ln, fps = torch.tensor([0]), lib.num_frames.cpu(), lib.fps.cpu().double()
    want = gaussian_smooth(central_differences(lib.dof_pos, starts, ln, fps), starts, ln, 2.0)
    torch.testing.assert_close(lib.dof_vel, want)
    torch.testing.assert_close(lib.dof_pos, fwd.dof_pos)  # positions are untouched
    assert float((lib.dof_vel - fwd.dof_vel).abs().max()) > 1e-3
    with pytest.raises(ValueError, match="velocities"):
        MotionLibrary(ms, sk, velocities="backward")  # type: ignore[arg-type]
