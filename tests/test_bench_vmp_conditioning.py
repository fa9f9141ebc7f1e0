"""bench/vmp_conditioning.py: the equal-frames joint MAE compares two policies on the frames both track."""

from __future__ import annotations

import math

import pytest
import torch
from conftest import load_bench
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.state import Trajectories
from mocap_vmp.metrics import joint_mae_deg


@pytest.fixture(scope="module")
def vc():
    return load_bench("vmp_conditioning")


def _unit(q: torch.Tensor) -> torch.Tensor:
    return q / q.norm(dim=-1, keepdim=True)


def _traj(amp, T: int, lengths: list[int], seed: int) -> Trajectories:
    g = torch.Generator().manual_seed(seed)
    N, B = len(lengths), amp.num_bodies
    rot = _unit(torch.randn(T, N, B, 4, generator=g))
    ref = _unit(torch.randn(T, N, B, 4, generator=torch.Generator().manual_seed(99)))
    mask = torch.arange(T)[:, None] < torch.tensor(lengths)[None, :]
    pos = torch.zeros(T, N, B, 3)
    return Trajectories(pos, pos.clone(), 30.0, mask, rot, ref)


def test_equal_frames_uses_the_common_frames(vc, amp):
    a = _traj(amp, 12, [12, 5, 8], seed=0)
    b = _traj(amp, 9, [3, 9, 8], seed=1)
    e_a, e_b, frames = vc.equal_frames_joint_mae(a, b, amp)
    assert frames == [3, 5, 8]
    # each equals the protocol metric of that policy with its episodes cut to the common frames
    common = torch.arange(9)[:, None] < torch.tensor([3, 5, 8])[None, :]
    for tr, got in ((a, e_a), (b, e_b)):
        cut = Trajectories(tr.sim[:9], tr.ref[:9], 30.0, common, tr.sim_rot[:9], tr.ref_rot[:9])
        torch.testing.assert_close(torch.tensor(got), joint_mae_deg(cut, amp).float(), rtol=1e-5, atol=1e-5)
    # and it differs from the per-policy (own frames) metric where the episode lengths differ
    assert abs(e_a[0] - float(joint_mae_deg(a, amp)[0])) > 1e-3
    # symmetric in its arguments
    e_b2, e_a2, frames2 = vc.equal_frames_joint_mae(b, a, amp)
    assert frames2 == frames
    torch.testing.assert_close(torch.tensor(e_a2), torch.tensor(e_a))
    torch.testing.assert_close(torch.tensor(e_b2), torch.tensor(e_b))


@given(st.integers(1, 40), st.data())
@settings(max_examples=60, deadline=None)
def test_sign_test_is_a_binomial_tail(vc, n, data):
    k = data.draw(st.integers(0, n))
    p = vc.sign_test_p(k, n)
    assert 0.0 < p <= 1.0
    assert vc.sign_test_p(0, n) == pytest.approx(1.0)
    assert vc.sign_test_p(n, n) == pytest.approx(0.5**n)
    if k < n:  # a larger count is rarer, by exactly the mass at k
        assert vc.sign_test_p(k + 1, n) == pytest.approx(p - math.comb(n, k) / 2**n)
    # symmetry of Binomial(n, 1/2): P(X >= k) + P(X >= n - k + 1) = 1
    assert p + (vc.sign_test_p(n - k + 1, n) if k >= 1 else 0.0) == pytest.approx(1.0)


def test_sign_test_known_value_and_bad_input(vc):
    assert vc.sign_test_p(12, 15) == pytest.approx(576 / 32768)
    with pytest.raises(ValueError):
        vc.sign_test_p(16, 15)
