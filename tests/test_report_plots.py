"""PNG plots in reports: a run's learning curves (report.md) and, for comparisons, learning curves
with a seed band and final-metric bars (comparison.md); the seed-band aggregation numerically."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mocap.matrix import Cell, comparison
from mocap.report import (
    COMPARISON_CURVES,
    COMPARISON_FINAL,
    learning_curves,
    read_metrics,
    seed_band,
    write_learning_curves,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _write_metrics(path: Path, seed: float = 0.0, steps: int = 6, step_size: int = 100) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = []
    for i in range(1, steps + 1):
        lines.append(
            {
                "stage": "imitator",
                "step": i,
                "time": 0.0,
                "env_steps": float(i * step_size),
                "episode/return": i + seed,
                "episode/success": min(1.0, 0.1 * i),
                "loss/total": 1.0 / i,
                "lr": 3e-4,
            }
        )
    for i in range(1, 4):
        lines.append({"stage": "latent", "step": i, "time": 0.0, "env_steps": float(i * 50), "loss/total": 2.0 / i + seed})
    lines.append({"stage": "eval", "step": 0, "time": 0.0, "success_rate": 0.5 + 0.1 * seed})
    path.write_text("".join(json.dumps(r) + "\n" for r in lines) + '{"stage": "imitator", "st')  # last line cut by a crash


def _is_png(path: Path) -> bool:
    data = path.read_bytes()
    return len(data) > 1000 and data.startswith(PNG_MAGIC)


def test_learning_curves_per_stage_from_metrics_jsonl(tmp_path: Path):
    _write_metrics(tmp_path / "metrics.jsonl")
    records = read_metrics(tmp_path / "metrics.jsonl")
    assert len(records) == 10  # the cut line is skipped
    curves = learning_curves(records)
    assert set(curves) == {"imitator", "latent"}  # eval has a single point: no curve
    assert set(curves["imitator"]) == {"episode/return", "episode/success", "loss/total"}
    xs, ys = curves["imitator"]["episode/return"]
    assert xs == [100.0 * i for i in range(1, 7)] and ys == [float(i) for i in range(1, 7)]
    assert curves["latent"]["loss/total"][1] == pytest.approx([2.0, 1.0, 2.0 / 3])
    png = write_learning_curves(tmp_path / "metrics.jsonl", tmp_path / "learning_curves.png")
    assert png is not None and _is_png(png)
    assert write_learning_curves(tmp_path / "missing.jsonl", tmp_path / "none.png") is None
    assert not (tmp_path / "none.png").exists()


def test_seed_band_is_the_mean_and_std_over_seeds():
    # same x: exact per-x mean and population std
    x = [0.0, 10.0, 20.0]
    a, b, c = [1.0, 2.0, 3.0], [3.0, 2.0, 7.0], [2.0, 2.0, 2.0]
    gx, mean, std = seed_band([(x, a), (x, b), (x, c)])
    assert gx == x
    assert mean == pytest.approx([2.0, 2.0, 4.0])
    assert std == pytest.approx([math.sqrt(2 / 3), 0.0, math.sqrt(((3 - 4) ** 2 + (7 - 4) ** 2 + (2 - 4) ** 2) / 3)])
    assert std == pytest.approx(np.std(np.array([a, b, c]), axis=0).tolist())
    # different x: interpolated onto the union of x inside the range every seed covers
    gx, mean, std = seed_band([([0.0, 10.0, 20.0], [0.0, 10.0, 20.0]), ([5.0, 15.0, 25.0], [0.0, 0.0, 0.0])])
    assert gx == [5.0, 10.0, 15.0, 20.0]
    assert mean == pytest.approx([2.5, 5.0, 7.5, 10.0]) and std == pytest.approx([2.5, 5.0, 7.5, 10.0])
    # one seed: zero band; disjoint curves: nothing
    assert seed_band([([1.0, 2.0], [4.0, 5.0])]) == ([1.0, 2.0], [4.0, 5.0], [0.0, 0.0])
    assert seed_band([([0.0, 1.0], [0.0, 0.0]), ([2.0, 3.0], [0.0, 0.0])]) == ([], [], [])


def test_comparison_writes_and_embeds_curves_with_seed_band_and_bars(tmp_path: Path):
    cells = []
    for latent in ("pulse", "hybrid"):
        for seed in (0, 1):
            name = f"latent-{latent}_seed-{seed}"
            _write_metrics(tmp_path / name / "metrics.jsonl", seed=seed + (2 if latent == "hybrid" else 0))
            stages = [{"stage": "eval", "metrics": {"success_rate": 0.2 * (seed + 1), "mpjpe_g": 30.0 + seed}}]
            (tmp_path / name / "stages.json").write_text(json.dumps(stages))
            cells.append(Cell(name, {"latent": latent, "seed": str(seed)}, {}))
    data = comparison(cells, tmp_path)
    assert data["plots"] == [COMPARISON_CURVES, COMPARISON_FINAL]
    for name in data["plots"]:
        assert _is_png(tmp_path / name)
    md = (tmp_path / "comparison.md").read_text()
    assert f"]({COMPARISON_CURVES})" in md and f"]({COMPARISON_FINAL})" in md
    assert data["groups"]["latent=pulse"]["eval/success_rate"]["mean"] == pytest.approx(0.3)


def test_run_report_embeds_its_learning_curves(tmp_path: Path, monkeypatch):
    """A real (tiny) pipeline run: report.md embeds learning_curves.png (the toy trainer logs
    ``value``, made a curve key here)."""
    from toy_plugins import TOY_SPEC, toy

    import mocap.report as report
    from mocap.testing import invoke, use_plugins

    monkeypatch.setattr(report, "CURVE_KEYS", ("value",))
    spec = tmp_path / "toy.yaml"
    spec.write_text(TOY_SPEC)
    with use_plugins(("toy", toy)):
        result = invoke(["run", spec, "--out", tmp_path / "run"])
    assert result.exit_code == 0, result.output
    run = tmp_path / "run"
    assert set(learning_curves(read_metrics(run / "metrics.jsonl"))) == {"imitator", "latent"}
    assert _is_png(run / "learning_curves.png")
    report_md = (run / "report.md").read_text()
    assert "## Learning curves" in report_md and "![learning curves](learning_curves.png)" in report_md
    # `mocap report RUN` rewrites it from the run directory alone
    (run / "report.md").unlink()
    (run / "learning_curves.png").unlink()
    with use_plugins(("toy", toy)):
        again = invoke(["report", run])
    assert again.exit_code == 0, again.output
    assert "## Stages" in (run / "report.md").read_text() and "| imitator |" in (run / "report.md").read_text()
    assert "![learning curves](learning_curves.png)" in (run / "report.md").read_text() and _is_png(run / "learning_curves.png")
    with use_plugins(("toy", toy)):
        bad = invoke(["report", tmp_path / "nothing"])
    assert bad.exit_code == 2 and "not a directory" in (bad.output + (bad.stderr or ""))


def test_report_says_when_matplotlib_is_missing(tmp_path: Path, monkeypatch):
    import builtins

    import mocap.report as report

    real_import = builtins.__import__

    def no_matplotlib(name, *args, **kwargs):
        if name.startswith("matplotlib"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    _write_metrics(tmp_path / "metrics.jsonl")
    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    with pytest.raises(report.PlotsUnavailable, match="matplotlib is not installed"):
        write_learning_curves(tmp_path / "metrics.jsonl", tmp_path / "learning_curves.png")
    cells = [Cell("seed-0", {"seed": "0"}, {})]
    (tmp_path / "seed-0").mkdir()
    _write_metrics(tmp_path / "seed-0" / "metrics.jsonl")
    data = comparison(cells, tmp_path)
    assert data["plots"] == [] and "matplotlib is not installed" in (tmp_path / "comparison.md").read_text()
