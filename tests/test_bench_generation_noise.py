"""bench/generation_noise.py: the per-start-clip split of generation falls adds up to the aggregate."""

from __future__ import annotations

import pytest
from conftest import load_bench
from hypothesis import given, settings
from hypothesis import strategies as st


@pytest.fixture(scope="module")
def gn():
    return load_bench("generation_noise")


rollout = st.tuples(st.sampled_from(["walk", "run", "roll"]), st.one_of(st.none(), st.floats(0.0, 10.0)), st.booleans())


@given(st.lists(rollout, min_size=1, max_size=40))
@settings(max_examples=60, deadline=None)
def test_falls_by_start_clip_adds_up_to_the_aggregate(rollouts):
    from mocap.generation_eval import falls_by_start_clip

    clips, times, down = ([r[i] for r in rollouts] for i in range(3))
    rows = falls_by_start_clip(clips, times, down)
    assert list(rows) == sorted(set(clips))
    assert sum(r["rollouts"] for r in rows.values()) == len(rollouts)
    assert sum(r["falls"] for r in rows.values()) == sum(t is not None for t in times)
    assert sum(r["down_at_end"] for r in rows.values()) == sum(down)
    for name, r in rows.items():
        mine = [t for c, t, _ in rollouts if c == name and t is not None]
        if mine:
            assert r["time_to_fall_s"] == pytest.approx(sum(mine) / len(mine))
        else:
            assert r["time_to_fall_s"] is None and r["falls"] == 0


def test_render_markdown_names_the_start_sets_and_the_per_clip_falls(gn):
    record = {
        "checkpoint": "checkpoints/pulse_x", "starts": "walk,run", "noise_scale": 1.0, "num_rollouts": 3, "seconds": 10.0,
        "fall_rate": 1 / 3, "down_at_end": 0.0, "survival_s": 9.0, "diversity_m": 2.5, "coverage": 0.1,
        "falls_by_start_clip": {
            "run": {"rollouts": 1, "falls": 1, "down_at_end": 0, "time_to_fall_s": 1.25},
            "walk": {"rollouts": 2, "falls": 0, "down_at_end": 0, "time_to_fall_s": None},
        },
    }  # fmt: skip
    md = gn.render_markdown([record])
    assert "| pulse_x | walk,run | 1 | 0.333 | 0.000 | 9.00 | 2.50 | 0.100 |" in md
    assert "- pulse_x, starts walk,run, noise 1: run 1/1 at 1.2 s (0), walk 0/2 (0)" in md
