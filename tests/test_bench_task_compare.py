"""bench/task_compare.py: the curve binning, the final values and the seed statistics it reports."""

from __future__ import annotations

import json

import pytest
from conftest import load_bench


@pytest.fixture(scope="module")
def tc():
    return load_bench("task_compare")


def _rows(n: int, offset: float = 0.0) -> list[dict]:
    return [{"stage": "task", "env_steps": 100.0 * (i + 1), "time": float(i), "episode/normalized_return": offset + i / n, "eval/x": 2.0 * i} for i in range(n)]


def test_summarize_bins_and_final_values(tc):
    out = tc.summarize(_rows(100), bins=10)
    assert len(out["curve"]) == 10 and out["curve"][-1]["env_steps"] == 10000.0
    # bin b holds rows 10b..10b+9: the mean of i/100 over them
    assert out["curve"][3]["episode/normalized_return"] == pytest.approx(sum(range(30, 40)) / 10 / 100)
    # final: the last 10% of the rows (90..99)
    assert out["final"]["episode/normalized_return"] == pytest.approx(sum(range(90, 100)) / 10 / 100)
    assert out["final"]["eval/x"] == pytest.approx(2.0 * sum(range(90, 100)) / 10)
    assert out["wall_s"] == 99.0


def test_collect_groups_seeds_and_skips_unfinished_cells(tc, tmp_path):
    for seed, offset in ((0, 0.0), (1, 0.5)):
        cell = tmp_path / f"speed_pulse_s{seed}"
        cell.mkdir()
        (cell / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in _rows(20, offset)) + "\n")
        (cell / "stages.json").write_text(json.dumps([{"stage": "task", "checkpoint": "policy.pt"}]))
    running = tmp_path / "speed_scratch_s0"
    running.mkdir()
    (running / "metrics.jsonl").write_text(json.dumps(_rows(3)[0]) + "\n")
    out = tmp_path / "res"
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out)]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    assert set(data["cells"]) == {"speed_pulse_s0", "speed_pulse_s1"}
    f = data["groups"]["speed/pulse"]["final"]["episode/normalized_return"]
    last = (18 / 20 + 19 / 20) / 2  # the last 10% of 20 rows: rows 18 and 19
    assert f["n"] == 2 and f["mean"] == pytest.approx(last + 0.25) and f["std"] == pytest.approx(0.5 / 2**0.5)
    assert "| pulse | 2 |" in out.with_suffix(".md").read_text() and out.with_suffix(".png").is_file()
