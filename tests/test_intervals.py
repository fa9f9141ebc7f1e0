"""The 95% intervals of reported numbers (``mocap.intervals``, issue 63 item 1), and the intervals the
imitation and generation evaluations write beside their aggregates."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.generation_eval import generation_intervals, pairwise_distances, pairwise_diversity
from mocap.imitation_eval import aggregate_intervals
from mocap.intervals import bootstrap_mean, inside, normal_mean, wilson

FAST = settings(max_examples=60, deadline=None, derandomize=True)


@FAST
@given(n=st.integers(1, 500), frac=st.floats(0, 1))
def test_wilson_holds_the_share_stays_in_the_unit_interval_and_narrows_with_n(n: int, frac: float) -> None:
    k = round(frac * n)
    lo, hi = wilson(k, n)  # type: ignore[misc]
    assert 0.0 <= lo <= k / n <= hi <= 1.0 and hi > lo
    lo4, hi4 = wilson(4 * k, 4 * n)  # type: ignore[misc]
    assert hi4 - lo4 < hi - lo
    assert wilson(0, 0) is None


def test_wilson_on_hand_numbers() -> None:
    """14 of 15 (the imitator's clips): about [0.70, 0.99]; 0 of 10: [0, 0.28]."""
    lo, hi = wilson(14, 15)  # type: ignore[misc]
    assert lo == pytest.approx(0.7018, abs=1e-4) and hi == pytest.approx(0.9881, abs=1e-4)
    assert wilson(0, 10)[0] == 0.0 and wilson(0, 10)[1] == pytest.approx(0.2775, abs=1e-4)  # type: ignore[index]


@FAST
@given(values=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=20), shift=st.floats(-100, 100))
def test_bootstrap_holds_the_mean_and_moves_with_the_data(values: list[float], shift: float) -> None:
    lo, hi = bootstrap_mean(values)  # type: ignore[misc]
    assert lo - 1e-6 <= float(np.mean(values)) <= hi + 1e-6
    lo2, hi2 = bootstrap_mean([v + shift for v in values])  # type: ignore[misc]
    assert lo2 == pytest.approx(lo + shift, abs=1e-6) and hi2 == pytest.approx(hi + shift, abs=1e-6)
    assert bootstrap_mean([1.0, math.nan]) is None  # one finite value: no interval


def test_normal_mean_and_inside() -> None:
    lo, hi = normal_mean(10.0, 4.0, 16)  # type: ignore[misc]
    assert lo == pytest.approx(10 - 1.96 * 1.0, abs=1e-3) and hi == pytest.approx(10 + 1.96, abs=1e-3)
    assert normal_mean(1.0, math.nan, 10) is None and normal_mean(1.0, 1.0, 1) is None
    assert inside(5.0, [5.0, 6.0]) and inside(6.0, [5.0, 6.0]) and not inside(6.01, [5.0, 6.0]) and not inside(math.nan, [0, 1])


def test_imitation_intervals_are_over_the_clips_and_the_successful_ones() -> None:
    clips = {f"c{i}": {"mpjpe_g": float(10 * i), "success": i < 4, "tracked_s": 1.0} for i in range(6)}
    aggregate = {"success_rate": 4 / 6, "succeeded": 4, "total": 6, "fps": 30.0, "tracked_s": 1.0, "mpjpe_g": 25.0, "mpjpe_g_succ": 15.0}
    ci = aggregate_intervals(aggregate, clips)
    assert ci["success_rate"] == pytest.approx(list(wilson(4, 6)))  # type: ignore[arg-type]
    assert ci["mpjpe_g"] == pytest.approx(list(bootstrap_mean([0, 10, 20, 30, 40, 50])))  # type: ignore[arg-type]
    assert ci["mpjpe_g_succ"] == pytest.approx(list(bootstrap_mean([0, 10, 20, 30])))  # type: ignore[arg-type]
    assert "total" not in ci and "fps" not in ci


def test_generation_intervals_hold_their_numbers() -> None:
    g = torch.Generator().manual_seed(0)
    traj = torch.randn(5, 12, 3, 3, generator=g, dtype=torch.float64)
    dist = pairwise_distances(traj)
    assert torch.allclose(dist, dist.T) and float(dist.diagonal().abs().max()) == 0.0
    assert float(dist[np.triu_indices(12, 1)].mean()) == pytest.approx(pairwise_diversity(traj), rel=1e-9)
    falls = [0.5, None, 1.5, None, None, 2.0, None, None, None, 0.2, None, None]
    result = {
        "num_rollouts": 12,
        "fall_rate": 4 / 12,
        "down_at_end": 2 / 12,
        "filtered": 0.25,
        "fall_time_s_per_rollout": falls,
        "match_distance": 50.0,
        "match_distance_std": 12.0,
    }
    survival = [f if f is not None else 10.0 for f in falls]
    ci = generation_intervals(result, survival, dist)
    assert ci["fall_rate"] == pytest.approx(list(wilson(4, 12)))  # type: ignore[arg-type]
    assert inside(np.mean([0.5, 1.5, 2.0, 0.2]), ci["time_to_fall_s"]) and inside(np.mean(survival), ci["survival_s"])
    assert inside(pairwise_diversity(traj), ci["diversity_m"])
    assert ci["match_distance"] == pytest.approx([50 - 1.96 * 12 / math.sqrt(12), 50 + 1.96 * 12 / math.sqrt(12)], rel=1e-3)
