"""bench/imitator_lineage.py: runs chained at their cut points, both result formats, bad cuts refused."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import load_bench
from hypothesis import given
from hypothesis import strategies as st


@pytest.fixture(scope="module")
def lineage():
    return load_bench("imitator_lineage")


def _tts(steps_minutes_clips: list[tuple[int, float, int]]) -> dict:
    points = [{"env_steps": s, "minutes": m, "clips_tracked": c, "mpjpe_g_succ_mm": 80.0 + c, "mpjpe_g_all_mm": 140.0} for s, m, c in steps_minutes_clips]
    return {"points": points}


def test_parse_segment(lineage):
    assert lineage.parse_segment("v7=a/b.json@14024704") == ("v7", Path("a/b.json"), 14024704)
    assert lineage.parse_segment("v3=a/b.json") == ("v3", Path("a/b.json"), None)
    with pytest.raises(ValueError, match="NAME=FILE"):
        lineage.parse_segment("a/b.json")


def test_both_formats_read_alike(lineage):
    start = {"env_steps": 0, "wall_s": 0.0, "succeeded": 0, "mpjpe_g_succ": None, "mpjpe_g": 400.0}
    later = {"env_steps": 100, "wall_s": 120.0, "succeeded": 3, "mpjpe_g_succ": 90.0, "mpjpe_g": 200.0}
    curve = {"points": [start, later]}
    rows = lineage.run_points(curve)
    assert rows[1] == {"env_steps": 100.0, "minutes": 2.0, "clips": 3.0, "mpjpe_g_succ_mm": 90.0, "mpjpe_g_all_mm": 200.0}
    assert rows[0]["mpjpe_g_succ_mm"] != rows[0]["mpjpe_g_succ_mm"]  # None -> nan


def test_children_start_at_the_cut_and_drop_the_dropped_branch(lineage, tmp_path: Path):
    a = tmp_path / "a.json"
    b = tmp_path / "b.json"
    c = tmp_path / "c.json"
    a.write_text(json.dumps(_tts([(0, 0.0, 0), (10, 5.0, 4), (20, 10.0, 6)])))
    b.write_text(json.dumps(_tts([(0, 0.0, 6), (5, 2.0, 7), (8, 3.0, 9), (12, 4.0, 8)])))  # cut at 8: the 12 point is a dropped branch
    c.write_text(json.dumps(_tts([(4, 1.0, 10)])))
    out = tmp_path / "lin"
    assert lineage.main(["--segment", f"a={a}", "--segment", f"b={b}@8", "--segment", f"c={c}", "--out", str(out), "--no-plot"]) == 0
    result = json.loads(out.with_suffix(".json").read_text())
    got = [(r["segment"], r["env_steps"], r["minutes"], r["clips"]) for r in result["points"]]
    assert got == [("a", 0, 0, 0), ("a", 10, 5, 4), ("a", 20, 10, 6), ("b", 25, 12, 7), ("b", 28, 13, 9), ("c", 32, 14, 10)]
    assert result["final"]["run_env_steps"] == 4 and result["best_clips"] == 10


def test_a_cut_without_a_point_there_is_refused(lineage):
    pts = lineage.run_points(_tts([(5, 1.0, 1), (10, 2.0, 2)]))
    with pytest.raises(ValueError, match="no point at exactly 7"):
        lineage.stitch([("x", pts, 7)])


@given(st.lists(st.lists(st.integers(1, 10**6), min_size=1, max_size=6, unique=True), min_size=1, max_size=5))
def test_cumulative_steps_are_increasing_and_sum_the_segments(lineage, runs):
    segments = []
    for i, steps in enumerate(runs):
        steps = sorted(steps)
        segments.append((f"s{i}", lineage.run_points(_tts([(s, s / 1000.0, 1) for s in steps])), None))
    rows = lineage.stitch(segments)
    cumulative = [r["env_steps"] for r in rows]
    assert all(b > a for a, b in zip(cumulative, cumulative[1:]))
    assert cumulative[-1] == sum(max(s) for s in runs)
    assert rows[-1]["minutes"] == pytest.approx(sum(max(s) for s in runs) / 1000.0)
