"""bench/generation_noise.py: the per-start-clip split of generation falls adds up to the aggregate."""

from __future__ import annotations

import math

import pytest
from conftest import load_bench
from hypothesis import given, settings
from hypothesis import strategies as st


@pytest.fixture(scope="module")
def gn():
    return load_bench("generation_noise")


rollout = st.tuples(st.sampled_from(["walk", "run", "roll"]), st.one_of(st.none(), st.floats(0.0, 10.0)))


@given(st.lists(rollout, min_size=1, max_size=40))
@settings(max_examples=60, deadline=None)
def test_split_by_start_clip_adds_up(gn, rollouts):
    clips = [c for c, _ in rollouts]
    times = [t for _, t in rollouts]
    split = gn.by_start_clip(clips, times)
    assert set(split) == set(clips)
    assert sum(v["rollouts"] for v in split.values()) == len(rollouts)
    falls = sum(v["fall_rate"] * v["rollouts"] for v in split.values())
    assert falls == pytest.approx(sum(t is not None for t in times))
    for name, v in split.items():
        mine = [t for c, t in rollouts if c == name and t is not None]
        if mine:
            assert v["time_to_fall_s"] == pytest.approx(sum(mine) / len(mine))
        else:
            assert math.isnan(v["time_to_fall_s"]) and v["fall_rate"] == 0.0


def test_split_known_case(gn):
    split = gn.by_start_clip(["walk", "walk", "roll"], [None, 2.0, 1.0])
    assert split == {"roll": {"rollouts": 1, "fall_rate": 1.0, "time_to_fall_s": 1.0}, "walk": {"rollouts": 2, "fall_rate": 0.5, "time_to_fall_s": 2.0}}
