"""Failure-driven start times within a clip (mocap.start_sampling; issue 22's first lever)."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.start_sampling import AdaptiveStartSampler, StartSamplingParams, expected_bins

ADAPTIVE = StartSamplingParams(mode="adaptive", bin_s=1.0, floor=0.2, decay=0.5, lookback=1)


def test_bins_per_clip_and_uniform_before_any_failure():
    s = AdaptiveStartSampler(torch.tensor([3.5, 1.0, 0.2]), ADAPTIVE)
    assert s.num_bins.tolist() == [4, 1, 1] == [expected_bins(d, 1.0) for d in (3.5, 1.0, 0.2)]
    torch.testing.assert_close(s.probabilities(0), torch.full((4,), 0.25, dtype=torch.float64))


@settings(max_examples=40, deadline=None)
@given(fails=st.lists(st.floats(0.0, 3.49), min_size=1, max_size=20), floor=st.floats(0.0, 1.0))
def test_probabilities_are_a_floor_mix_and_follow_failures(fails, floor):
    s = AdaptiveStartSampler(torch.tensor([3.5]), StartSamplingParams(mode="adaptive", floor=floor, decay=1.0, lookback=1))
    s.record_failures(torch.zeros(len(fails), dtype=torch.long), torch.tensor(fails, dtype=torch.float64))
    p = s.probabilities(0)
    assert float(p.sum()) == pytest.approx(1.0)
    assert bool((p >= floor / 4 - 1e-12).all())
    f = torch.zeros(4, dtype=torch.float64)
    for t in fails:
        f[int(t)] += 1
    shifted = f.clone()
    shifted[:-1] += f[1:]  # a failure in bin b also weighs bin b - 1 (look-back 1)
    torch.testing.assert_close(p, (1 - floor) * shifted / shifted.sum() + floor / 4)


def test_decay_and_wrapping_past_the_end():
    s = AdaptiveStartSampler(torch.tensor([2.0]), ADAPTIVE)
    s.record_failures(torch.tensor([0]), torch.tensor([0.5], dtype=torch.float64))
    s.record_failures(torch.tensor([0]), torch.tensor([3.5], dtype=torch.float64))  # 3.5 s of a 2 s loop: bin 1
    torch.testing.assert_close(s.counts, torch.tensor([0.5, 1.0], dtype=torch.float64))


def test_starts_come_mostly_from_before_and_at_the_failures():
    s = AdaptiveStartSampler(torch.tensor([6.0]), StartSamplingParams(mode="adaptive", floor=0.1, decay=1.0, lookback=0))
    s.record_failures(torch.zeros(50, dtype=torch.long), torch.full((50,), 4.5, dtype=torch.float64))
    t = s.sample_times(torch.zeros(4000, dtype=torch.long), torch.Generator().manual_seed(0))
    assert bool(((t >= 0) & (t <= 6.0)).all())
    share = float(((t >= 4.0) & (t < 5.0)).double().mean())
    assert share == pytest.approx(0.9 + 0.1 / 6, abs=0.03)


def test_state_round_trip_and_a_mismatch_is_refused():
    s = AdaptiveStartSampler(torch.tensor([2.0, 3.0]), ADAPTIVE)
    s.record_failures(torch.tensor([1, 1]), torch.tensor([0.2, 2.5], dtype=torch.float64))
    t = AdaptiveStartSampler(torch.tensor([2.0, 3.0]), ADAPTIVE)
    t.load_state_dict(s.state_dict())
    torch.testing.assert_close(t.counts, s.counts)
    with pytest.raises(ValueError, match="another motion set"):
        AdaptiveStartSampler(torch.tensor([2.0]), ADAPTIVE).load_state_dict(s.state_dict())


def test_the_imitation_env_counts_failures_by_time_and_resumes_them(amp):
    from test_phc import make_env

    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource

    clips = DeepMimicSource(DeepMimicParams(clips=["walk", "kick"])).load(amp)
    env = make_env(amp, clips, n=8, seed=1, start_sampling={"mode": "adaptive"})
    env.reset()
    failed = 0
    for _ in range(40):
        res = env.step(2.0 * torch.ones(8, amp.num_dofs))  # large residuals: episodes fail
        failed += int(res.terminated.sum())
    assert failed > 0 and float(env.start_sampler.counts.sum()) > 0
    state = env.state_dict()
    assert "start_counts" in state
    env2 = make_env(amp, clips, n=8, seed=1, start_sampling={"mode": "adaptive"})
    env2.reset()
    env2.load_state_dict(state)
    torch.testing.assert_close(env2.start_sampler.counts, env.start_sampler.counts)
