"""VMP stage II (plugin ``latent_vmp``): the tracking env's reward terms on random features
(tracking and smoothness errors, the raw terms and weights of the paper and exp reward forms and
their Eq. 5 total through :class:`mocap.episodes.RewardTerms`), moved from ``test_vmp_track.py``."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from test_vmp_track import f64

torch.set_num_threads(1)

from mocap.episodes import RewardTerms
from mocap_vmp.features import FeatureLayout
from mocap_vmp.tracking import (
    REWARD_TERMS,
    VmpRewardWeights,
    smoothness_errors,
    tracking_errors,
    vmp_reward_terms,
    vmp_reward_weights,
)

LAYOUT = FeatureLayout(4, ("a", "b"))  # F = 25 + 8 - 12 + 6 = 1 + 6 + 6 + 4 + 4 + 6 = 27


def _random_features(gen: torch.Generator, n: int) -> torch.Tensor:
    x = torch.randn(n, LAYOUT.dim, generator=gen, dtype=f64)
    q = torch.randn(n, 4, generator=gen, dtype=f64)
    q = q / q.norm(dim=-1, keepdim=True)
    from mocap.rotations import matrix_to_sixd, quat_to_matrix

    x[:, LAYOUT.theta] = matrix_to_sixd(quat_to_matrix(q))
    return x


def _reward(track, smooth, w, form="paper", dims=None, k=2.0):
    """(total, raw terms, weights) as the env computes them."""
    terms = vmp_reward_terms(track, smooth, form, dims, k)
    weights = vmp_reward_weights(w, form)
    total, info = RewardTerms(weights)(terms)
    assert all(torch.equal(info[f"reward/{n}"], v) for n, v in terms.items())
    return total, terms, weights


# --------------------------------------------------------------------------------- reward terms
@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 5), k=st.floats(0.1, 10.0))
def test_tracking_errors_zero_iff_equal_nonnegative_and_quadratic(seed, n, k):
    gen = torch.Generator().manual_seed(seed)
    a, b = _random_features(gen, n), _random_features(gen, n)
    same = tracking_errors(a, a.clone(), LAYOUT)
    assert set(same) == {"h", "theta", "v", "q", "qd", "p"}
    for e in same.values():
        assert torch.allclose(e, torch.zeros(n, dtype=f64), atol=1e-12)
    diff = tracking_errors(a, b, LAYOUT)
    assert all(bool((e >= 0).all()) for e in diff.values())
    assert bool((diff["theta"] <= 8.0 + 1e-9).all())  # ||R1 - R2||_F^2 = 4 (1 - cos phi) <= 8
    # the Euclidean groups scale quadratically with the difference (theta is a rotation distance)
    c = a.clone()
    c[:, :1] += k * (b[:, :1] - a[:, :1])
    c[:, 7:] = a[:, 7:] + k * (b[:, 7:] - a[:, 7:])
    scaled = tracking_errors(a, c, LAYOUT)
    for g in ("h", "v", "q", "qd", "p"):
        torch.testing.assert_close(scaled[g], k * k * diff[g], rtol=1e-9, atol=1e-9)
    # theta: a rotation by phi about any axis gives 4 (1 - cos phi)
    phi = float(k) % math.pi
    from mocap.rotations import matrix_to_sixd, sixd_to_matrix

    R = sixd_to_matrix(a[:, LAYOUT.theta])
    Rz = torch.tensor(
        [
            [math.cos(phi), -math.sin(phi), 0.0],
            [math.sin(phi), math.cos(phi), 0.0],
            [0.0, 0.0, 1.0],
        ],
        dtype=f64,
    )
    d = a.clone()
    d[:, LAYOUT.theta] = matrix_to_sixd(R @ Rz)
    torch.testing.assert_close(
        tracking_errors(a, d, LAYOUT)["theta"],
        torch.full((n,), 4 * (1 - math.cos(phi)), dtype=f64),
        rtol=1e-9,
        atol=1e-9,
    )


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    slope=st.floats(-2, 2),
    c=st.floats(-3, 3),
    s=st.floats(0.1, 5),
)
def test_smoothness_terms(seed, slope, c, s):
    gen = torch.Generator().manual_seed(seed)
    a = torch.randn(4, 6, generator=gen, dtype=f64)
    tau = torch.randn(4, 6, generator=gen, dtype=f64) * 50
    zero = torch.zeros_like(tau)
    # constant actions, no torque: no penalty
    const = smoothness_errors(a, a, a, zero)
    assert all(torch.equal(v, torch.zeros(4, dtype=f64)) for v in const.values())
    # actions linear in time: no acceleration penalty, rate = |slope|^2 * D
    lin = smoothness_errors(c + 2 * slope + a * 0, c + slope + a * 0, c + a * 0, zero)
    torch.testing.assert_close(lin["dda"], torch.zeros(4, dtype=f64), atol=1e-12, rtol=0)
    torch.testing.assert_close(lin["da"], torch.full((4,), 6 * slope * slope, dtype=f64), rtol=1e-9, atol=1e-12)
    # quadratic scaling of every term
    b, b2 = (
        torch.randn(4, 6, generator=gen, dtype=f64),
        torch.randn(4, 6, generator=gen, dtype=f64),
    )
    e1, e2 = (
        smoothness_errors(a, b, b2, tau),
        smoothness_errors(s * a, s * b, s * b2, s * tau),
    )
    for k in ("da", "dda", "tau"):
        torch.testing.assert_close(e2[k], s * s * e1[k], rtol=1e-9, atol=1e-9)
        assert bool((e1[k] >= 0).all())


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.floats(0.0, 4.0), alive=st.floats(-10, 10))
def test_reward_eq5_total_raw_terms_weights_and_linearity(seed, scale, alive):
    gen = torch.Generator().manual_seed(seed)
    a, b = _random_features(gen, 3), _random_features(gen, 3)
    track = tracking_errors(a, b, LAYOUT)
    act = torch.randn(3, 3, 5, generator=gen, dtype=f64)
    smooth = smoothness_errors(act[0], act[1], act[2], torch.randn(3, 5, generator=gen, dtype=f64))
    w = VmpRewardWeights()
    total, terms, weights = _reward(track, smooth, w)
    # paper weights, [T1] humanoid column
    assert (w.h, w.theta, w.v, w.q, w.qd, w.p, w.alive, w.da, w.dda, w.tau) == (
        0.5,
        1.0,
        1.0,
        1.0,
        0.1,
        1.0,
        6.0,
        0.1,
        0.01,
        1e-5,
    )
    # the declared terms, in the order they are summed: alive, track/<g>, smooth/<s>
    assert tuple(terms) == tuple(weights) == REWARD_TERMS
    assert REWARD_TERMS == ("alive", *(f"track/{g}" for g in track), "smooth/da", "smooth/dda", "smooth/tau")
    # raw terms: 1, the squared errors e_g, the squared norms e_s; weights c_alive, -c_g, -c_s
    assert torch.equal(terms["alive"], torch.ones(3, dtype=f64))
    for g, e in track.items():
        assert torch.equal(terms[f"track/{g}"], e) and weights[f"track/{g}"] == -getattr(w, g)
    for s_, e in smooth.items():
        assert torch.equal(terms[f"smooth/{s_}"], e) and weights[f"smooth/{s_}"] == -getattr(w, s_)
    assert weights["alive"] == 6.0
    # Eq. 5: r = -sum_g c_g e_g + c_alive - sum_s c_s e_s
    eq5 = w.alive - sum(getattr(w, g) * e for g, e in track.items()) - sum(getattr(w, s_) * e for s_, e in smooth.items())
    torch.testing.assert_close(total, eq5, rtol=1e-12, atol=1e-9)
    assert total.dtype == f64 and bool((total <= w.alive + 1e-12).all())
    # zero errors: exactly the alive bonus
    zt = {k: torch.zeros(3, dtype=f64) for k in track}
    zs = {k: torch.zeros(3, dtype=f64) for k in smooth}
    assert torch.equal(_reward(zt, zs, w)[0], torch.full((3,), 6.0, dtype=f64))
    # linear in the weight vector (alive included)
    ws = VmpRewardWeights(**{k: v * scale for k, v in w.model_dump().items()})
    torch.testing.assert_close(_reward(track, smooth, ws)[0], scale * total, rtol=1e-9, atol=1e-6)
    wa = VmpRewardWeights(alive=alive)
    torch.testing.assert_close(
        _reward(track, smooth, wa)[0] - total,
        torch.full((3,), alive - 6.0, dtype=f64),
    )
    # one weight at a time: only that term moves
    for g in ("h", "theta", "v", "q", "qd", "p"):
        wg = VmpRewardWeights(**{**w.model_dump(), g: getattr(w, g) + 1.0})
        torch.testing.assert_close(_reward(track, smooth, wg)[0] - total, -track[g], rtol=1e-9, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.floats(0.1, 10.0), grow=st.floats(0.0, 5.0))
def test_exp_reward_bounds_zero_error_and_monotone(seed, k, grow):
    gen = torch.Generator().manual_seed(seed)
    a, b = _random_features(gen, 3), _random_features(gen, 3)
    track = tracking_errors(a, b, LAYOUT)
    dims = {g: sl.stop - sl.start for g, sl in LAYOUT.slices.items() if g in track}
    act = torch.randn(3, 3, 5, generator=gen, dtype=f64)
    smooth = smoothness_errors(act[0], act[1], act[2], torch.randn(3, 5, generator=gen, dtype=f64))
    w = VmpRewardWeights()
    total, terms, weights = _reward(track, smooth, w, "exp", dims, k)
    # each tracking term the kernel exp(-k e / n) in (0, 1], weighted +c_g
    for g, e in track.items():
        v = terms[f"track/{g}"]
        assert bool((v > 0).all()) and bool((v <= 1.0).all()) and weights[f"track/{g}"] == getattr(w, g)
        torch.testing.assert_close(v, torch.exp(-k * e / dims[g]))
    best = w.alive + w.h + w.theta + w.v + w.q + w.qd + w.p
    eq5 = w.alive + sum(getattr(w, g) * torch.exp(-k * e / dims[g]) for g, e in track.items()) - sum(getattr(w, s_) * e for s_, e in smooth.items())
    torch.testing.assert_close(total, eq5, rtol=1e-12, atol=1e-9)
    # the smoothness terms, the alive bonus and their weights are the paper form's
    _, paper_terms, paper_weights = _reward(track, smooth, w)
    for key in ("alive", "smooth/da", "smooth/dda", "smooth/tau"):
        assert torch.equal(terms[key], paper_terms[key]) and weights[key] == paper_weights[key]
    # zero tracking and smoothness errors: the maximum, alive + sum of the tracking weights
    zt = {g: torch.zeros(3, dtype=f64) for g in track}
    zs = {s_: torch.zeros(3, dtype=f64) for s_ in smooth}
    torch.testing.assert_close(_reward(zt, zs, w, "exp", dims, k)[0], torch.full((3,), best, dtype=f64))
    assert bool((total <= best + 1e-9).all())
    # a larger error in one group never raises the reward
    for g in track:
        more = {**track, g: track[g] + grow}
        assert bool((_reward(more, smooth, w, "exp", dims, k)[0] <= total + 1e-12).all())


def test_reward_form_and_dims_are_checked():
    z = {g: torch.zeros(2, dtype=f64) for g in ("h", "theta", "v", "q", "qd", "p")}
    zs = {s_: torch.zeros(2, dtype=f64) for s_ in ("da", "dda", "tau")}
    with pytest.raises(ValueError, match="needs the feature dimensions"):
        vmp_reward_terms(z, zs, "exp")
    with pytest.raises(ValueError, match="unknown reward_form"):
        vmp_reward_weights(VmpRewardWeights(), "linear")
