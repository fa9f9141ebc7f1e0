"""bench/clip_failures.py: per-clip training failure rates and sampling shares from a PPO checkpoint's env state, beside the evaluation."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from conftest import load_bench

from mocap.checkpoint import save_checkpoint


@pytest.fixture(scope="module")
def cf():
    return load_bench("clip_failures")


def _env(names, episodes, failures, weights):
    f64 = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    return {"clip_names": names, "episodes_per_clip": f64(episodes), "failures_per_clip": f64(failures), "weights": f64(weights)}


def test_rows_are_failure_rates_and_normalized_sampling_shares(cf):
    env = _env(["walk", "jump", "new"], [100, 40, 0], [25, 40, 0], [1.0, 3.0, 0.0])
    evaluation = {"clips": {"walk": {"success": True, "mpjpe_g": 47.0}, "jump": {"success": False, "mpjpe_g": 300.0}}}
    rows = cf.clip_rows(env, {"walk": True, "jump": True, "new": False}, evaluation)
    assert [r["training_failure_rate"] for r in rows] == [0.25, 1.0, None]  # no episodes: no rate
    assert [r["sampling_weight"] for r in rows] == [0.25, 0.75, 0.0]
    assert rows[1]["eval_success"] is False and "eval_success" not in rows[2]
    md = cf.render(rows, "x")
    assert "| walk | True | 100 | 0.25 | 0.250 | yes | 47.0 |" in md and "| new | False | 0 | - | 0.000 | - | - |" in md


def test_main_reads_a_ppo_checkpoint_and_refuses_one_without_clip_counts(cf, tmp_path: Path):
    ck = tmp_path / "ppo.pt"
    save_checkpoint(ck, {"format": "test", "env_steps": 123, "env": _env(["walk", "kick"], [10, 10], [1, 5], [1.0, 1.0])})
    out = tmp_path / "cf.json"
    assert cf.main([str(ck), "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["env_steps"] == 123 and [r["loops"] for r in result["clips"]] == [True, False]  # the bundled walk loops, kick does not
    assert out.with_suffix(".md").exists()
    bad = tmp_path / "other.pt"
    save_checkpoint(bad, {"format": "test", "env": {"clip_names": []}})
    with pytest.raises(SystemExit, match="no imitation env state"):
        cf.main([str(bad), "--out", str(out)])
