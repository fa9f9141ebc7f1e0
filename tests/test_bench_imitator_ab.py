"""bench/imitator_ab.py: arms side by side; the training tail averages only the last iterations of the imitator stage."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import load_bench


@pytest.fixture(scope="module")
def ab():
    return load_bench("imitator_ab")


def _arm(tmp: Path, name: str, clips: int, lengths: list[float]) -> str:
    work = tmp / name
    (work / "runs" / "tts").mkdir(parents=True)
    rows = [{"stage": "imitator", "step": i + 1, "episode/length": v, "episode/success": 0.5, "lr": 2e-6, "approx_kl": 0.012} for i, v in enumerate(lengths)]
    rows.append({"stage": "eval", "step": 0, "episode/length": 1e9})  # another stage: ignored
    (work / "runs" / "tts" / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    point = {"minutes": 15.0, "env_steps": 2_000_000, "clips_tracked": clips, "clips_total": 15}
    point |= {"mpjpe_g_succ_mm": 80.0, "mpjpe_g_all_mm": 140.0, "tracked": ["walk"]}
    result = tmp / f"{name}.json"
    meta = {"spec": "s.yaml", "overrides": [f"x={name}"], "minutes": 15, "load_avg_at_end_of_training": [2.1, 2.0, 1.9]}
    result.write_text(json.dumps({**meta, "points": [point]}))
    return f"{name}={result}:{work}"


def test_arms_table_and_training_tail(ab, tmp_path: Path):
    out = tmp_path / "ab.json"
    start = tmp_path / "eval.json"
    aggregate = {"succeeded": 9, "total": 15, "mpjpe_g_succ": 87.0, "mpjpe_g": 147.0}
    start.write_text(json.dumps({"aggregate": aggregate, "clips": {"walk": {"success": True}, "spin": {"success": False}}}))
    lengths = [10.0] * 5 + [100.0] * 20  # only the last 20 iterations count
    assert ab.main(["--arm", _arm(tmp_path, "a", 9, lengths), "--arm", _arm(tmp_path, "b", 10, [50.0]), "--start", str(start), "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    a, b = result["arms"]
    assert a["training_last_20_iterations"]["episode/length"] == pytest.approx(100.0)
    assert a["training_last_20_iterations"]["iterations"] == 20
    assert b["training_last_20_iterations"]["episode/length"] == pytest.approx(50.0)
    assert result["start"]["clips_tracked"] == 9 and result["start"]["tracked"] == ["walk"]
    md = out.with_suffix(".md").read_text()
    assert "| a | `x=a` | 15.0 | 2.00M | 9/15 | 80.0 | 140.0 | 100.0 | 0.50 | 2.0e-06 | 0.012 | 2.10 |" in md
    assert "the same wall-clock budget" in md
    assert "Start: 9/15 clips, MPJPE-g 87.0 mm" in md
    assert out.with_suffix(".png").stat().st_size > 0


def test_an_arm_with_its_own_spec_names_it_and_the_summary_averages_the_snapshots(ab, tmp_path: Path):
    """An arm whose lever is a spec extending the table's is labelled with that spec; a thread-count
    override is not a lever; the summary row is the mean (and range) over the arm's snapshots."""
    base = tmp_path / "base.json"
    point = {"minutes": 5.0, "env_steps": 500_000, "clips_total": 15, "mpjpe_g_succ_mm": 80.0, "tracked": ["walk"]}
    pts = [point | {"clips_tracked": c, "mpjpe_g_all_mm": e} for c, e in ((9, 140.0), (11, 130.0), (10, 150.0))]
    base.write_text(json.dumps({"spec": "s.yaml", "overrides": ["imitator.trainer.params.torch_threads=1"], "env_steps_budget": 1, "points": pts}))
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"spec": "s_contacts.yaml", "overrides": ["seed=1"], "env_steps_budget": 1, "points": pts[:1]}))
    out = tmp_path / "ab.json"
    assert ab.main(["--arm", f"base={base}", "--arm", f"other={other}", "--out", str(out)]) == 0
    md = out.with_suffix(".md").read_text()
    assert "| base | `(the spec as is)` | 3 | 10.00 (9-11) | 140.0 (130.0-150.0) |" in md
    assert "| other | `spec s_contacts.yaml; seed=1` | 1 | 9.00 (9-9) | 140.0 (140.0-140.0) |" in md
    assert "# Imitator A/B: s.yaml" in md and "the same env-step budget" in md


def test_max_env_steps_compares_arms_over_the_same_range_and_marks_an_unfinished_arm(ab, tmp_path: Path):
    """An arm that ran longer is cut to the common range before averaging; an interrupted arm says so."""
    pt = {"minutes": 5.0, "clips_total": 15, "mpjpe_g_succ_mm": 80.0, "mpjpe_g_all_mm": 140.0, "tracked": ["walk"]}
    long_pts = [pt | {"env_steps": s, "clips_tracked": c} for s, c in ((1_000_000, 9), (2_000_000, 11), (3_000_000, 5))]
    long = tmp_path / "long.json"
    long.write_text(json.dumps({"spec": "s.yaml", "overrides": [], "env_steps_budget": 3, "points": long_pts}))
    short = tmp_path / "short.json"
    short.write_text(json.dumps({"spec": "s.yaml", "overrides": ["g=1"], "env_steps_budget": 3, "training_finished": False, "points": long_pts[:2]}))
    out = tmp_path / "ab.json"
    assert ab.main(["--arm", f"long={long}", "--arm", f"short={short}", "--max-env-steps", "2000000", "--out", str(out)]) == 0
    md = out.with_suffix(".md").read_text()
    assert "| long | `(the spec as is)` | 2 | 10.00 (9-11) |" in md  # the 3M snapshot (5 clips) is left out
    assert "short: the training did not finish" in md and "long: the training did not finish" not in md
    assert json.loads(out.read_text())["max_env_steps"] == 2_000_000
    with pytest.raises(SystemExit):
        ab.main(["--arm", f"long={long}", "--max-env-steps", "10", "--out", str(out)])


def test_the_training_tail_is_cut_at_max_env_steps_too(ab, tmp_path: Path):
    """With ``max_env_steps`` the last iterations are the last ones at or below it, not the run's end."""
    work = tmp_path / "w"
    (work / "runs" / "tts").mkdir(parents=True)
    rows = [{"stage": "imitator", "env_steps": 1000 * (i + 1), "episode/length": 10.0 if i < 30 else 99.0} for i in range(40)]
    (work / "runs" / "tts" / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    assert ab.training_tail(work)["episode/length"] == pytest.approx((10 * 10 + 10 * 99) / 20)
    assert ab.training_tail(work, max_env_steps=30_000)["episode/length"] == pytest.approx(10.0)


def test_a_curriculum_arm_names_each_phase_and_its_length(ab):
    phases = [
        {"spec": "specs/imitator/curriculum_hard_v8.yaml", "overrides": [], "env_steps": 4_000_000},
        {"spec": "s.yaml", "overrides": ["imitator.trainer.params.init_policy=/w/p.pt", "imitator.trainer.params.torch_threads=1"], "env_steps": 3_000_000},
    ]
    arm = {"spec": "s.yaml", "overrides": [], "phases": phases}
    lever = ab._lever(arm, "s.yaml")
    assert lever == "spec specs/imitator/curriculum_hard_v8.yaml for 4.00M then imitator.trainer.params.init_policy=/w/p.pt for 3.00M"
    assert ab._lever({**arm, "phases": phases[:1]}, "s.yaml") == "(the spec as is)"  # one phase: the arm's own lever
