"""Sample efficiency (``mocap.sample_efficiency``, issue 61 item 2): steps to a share of the best final
value, the area under the curve and bootstrap intervals, as properties and in a comparison."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.matrix import Cell, comparison
from mocap.intervals import bootstrap_mean as bootstrap_ci
from mocap.sample_efficiency import auc, efficiency, read_curve, steps_to, trailing_mean

FAST = settings(max_examples=40, deadline=None, derandomize=True)


def linear(total: float, points: int = 101, top: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    steps = np.linspace(0.0, total, points)
    return steps, top * steps / total


@FAST
@given(total=st.floats(1e3, 1e8), frac=st.floats(0.05, 0.95))
def test_a_linear_curve_reaches_a_share_at_that_share_of_its_steps_and_has_auc_one_half(total: float, frac: float) -> None:
    curve = linear(total, points=1001)
    got = steps_to(curve, frac, window=1)
    grid = total / 1000
    assert got is not None and frac * total - 1e-9 * total <= got <= frac * total + grid * (1 + 1e-6)  # the first point at or past it
    assert auc(curve, total) == pytest.approx(0.5, rel=1e-9)
    assert steps_to(curve, 1.01, window=1) is None  # never reached


@FAST
@given(seed=st.integers(0, 10_000), speed=st.floats(1.1, 5.0), window=st.integers(1, 7))
def test_a_faster_learner_reaches_every_threshold_no_later_and_has_the_larger_auc(seed: int, speed: float, window: int) -> None:
    """The same noisy curve compressed in steps by ``speed``: thresholds come no later, AUC is larger."""
    rng = np.random.default_rng(seed)
    steps = np.linspace(0.0, 1e6, 200)
    values = 1 - np.exp(-steps / 2e5) + 0.02 * rng.standard_normal(200)
    slow = (steps, values)
    fast = (steps, np.interp(steps * speed, steps, values))  # reaches at step s what slow reaches at speed * s
    for target in (0.3, 0.5, 0.8):
        a, b = steps_to(fast, target, window), steps_to(slow, target, window)
        if b is not None:
            assert a is not None and a <= b
    assert auc(fast, 1e6) > auc(slow, 1e6)


@FAST
@given(values=st.lists(st.floats(-10, 10), min_size=1, max_size=30), window=st.integers(1, 10))
def test_trailing_mean_is_the_mean_of_the_last_window_points(values: list[float], window: int) -> None:
    got = trailing_mean(np.asarray(values), window)
    for i in range(len(values)):
        assert got[i] == pytest.approx(np.mean(values[max(0, i - window + 1) : i + 1]), abs=1e-9)


@FAST
@given(values=st.lists(st.floats(-5, 5), min_size=2, max_size=8), shift=st.floats(-3, 3))
def test_bootstrap_interval_holds_the_mean_and_shifts_with_the_data(values: list[float], shift: float) -> None:
    lo, hi = bootstrap_ci(values)  # type: ignore[misc]
    mean = float(np.mean(values))
    assert min(values) - 1e-9 <= lo <= mean + 1e-9 <= hi + 2e-9 <= max(values) + 3e-9
    lo2, hi2 = bootstrap_ci([v + shift for v in values])  # type: ignore[misc]
    assert lo2 == pytest.approx(lo + shift, abs=1e-9) and hi2 == pytest.approx(hi + shift, abs=1e-9)
    assert bootstrap_ci([1.5] * 4) == (1.5, 1.5) and bootstrap_ci([2.0]) is None


def test_efficiency_uses_the_best_final_value_among_cells_and_says_who_never_reached() -> None:
    total = 1e6
    fast = [linear(total / 2, top=1.0), linear(total / 2, top=1.0)]  # reaches 1.0 at 0.5M, then logs end
    fast = [(np.concatenate([s, s[-1] + np.linspace(1e4, total / 2, 50)]), np.concatenate([v, np.ones(50)])) for s, v in fast]
    slow = [linear(total, top=0.6), linear(total, top=0.7)]
    table = efficiency({"fast": fast, "slow": slow}, window=1)
    assert table["best_final"] == pytest.approx(1.0) and table["budget"] == pytest.approx(total)
    f, s = table["cells"]["fast"], table["cells"]["slow"]
    assert f["steps_to_50"]["mean"] == pytest.approx(0.25e6, rel=0.02) and f["steps_to_50"]["reached"] == 2
    assert s["steps_to_80"]["reached"] == 0 and math.isnan(s["steps_to_80"]["mean"])  # 0.6 and 0.7 < 0.8
    assert f["auc"]["mean"] > s["auc"]["mean"]


def _metrics(path: Path, values: list[float], step: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = [{"stage": "task", "step": i + 1, "env_steps": step * (i + 1), "episode/normalized_return": v} for i, v in enumerate(values)]
    rows.insert(1, {"stage": "imitator", "step": 1, "env_steps": 5.0, "episode/normalized_return": 99.0})  # another stage
    path.write_text("\n".join(json.dumps(r) for r in rows) + "\n{truncated")


def test_comparison_reports_sample_efficiency_per_cell(tmp_path: Path) -> None:
    cells = []
    for latent, rate in (("pulse", 0.2), ("scratch", 0.05)):
        for seed in (0, 1, 2):
            name = f"latent-{latent}_seed-{seed}"
            _metrics(tmp_path / name / "metrics.jsonl", [min(1.0, rate * (i + 1)) for i in range(30)], 1e5)
            (tmp_path / name / "stages.json").write_text(json.dumps([{"stage": "task", "metrics": {"episode/return": 1.0}}]))
            cells.append(Cell(name, {"latent": latent, "seed": str(seed)}, {}))
    assert len(read_curve(tmp_path / cells[0].name / "metrics.jsonl")[0]) == 30  # the imitator row and the cut line are skipped
    data = comparison(cells, tmp_path)
    eff = data["efficiency"]["cells"]
    assert eff["latent=pulse"]["steps_to_80"]["mean"] < eff["latent=scratch"]["steps_to_80"]["mean"]
    assert eff["latent=pulse"]["auc"]["mean"] > eff["latent=scratch"]["auc"]["mean"]
    md = (tmp_path / "comparison.md").read_text()
    assert "## Sample efficiency" in md and "| latent=pulse |" in md
