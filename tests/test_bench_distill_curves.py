"""bench/distill_curves.py: eval points from a run's metrics.jsonl, shifted by --offset for a continued run."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import distill_curves  # noqa: E402


def _run(path: Path, rows: list[dict]) -> Path:
    path.mkdir(parents=True)
    (path / "metrics.jsonl").write_text("".join(json.dumps({"stage": "latent", **r}) + "\n" for r in rows))
    (path / "spec.yaml").write_text("latent:\n  name: pulse\n")
    return path


def test_offset_shifts_a_continued_run_and_must_match_the_runs(tmp_path, capsys):
    a = _run(tmp_path / "a", [{"step": 1, "env_steps": 100, "loss/action": 1.0, "eval/success_rate": 0.5, "eval/mpjpe_g": 90.0}])
    b = _run(tmp_path / "b", [{"step": 1, "env_steps": 50, "loss/action": 0.5}, {"step": 2, "env_steps": 60, "eval/success_rate": 0.8, "eval/mpjpe_g": 80.0}])
    out = tmp_path / "curves"
    assert distill_curves.main([str(a), str(b), "--offset", "0", "1000", "--out", str(out)]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    first, second = data["runs"]
    assert first["evals"][0]["env_steps"] == 100 and second["evals"] == [
        {"iteration": 2, "env_steps": 1060.0, "success_rate": 0.8, "mpjpe_g": 80.0, "mpjpe_g_succ": None}
    ]
    assert second["action_loss"][0]["env_steps"] == 1050 and second["offset"] == 1000 and out.with_suffix(".png").is_file()
    with pytest.raises(SystemExit):
        distill_curves.main([str(a), str(b), "--offset", "5", "--out", str(out)])
    assert "one value per run" in capsys.readouterr().err
