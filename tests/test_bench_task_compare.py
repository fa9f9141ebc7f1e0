"""bench/task_compare.py: the curve binning, the final values and the seed statistics it reports."""

from __future__ import annotations

import json
import shutil

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


def test_cell_json_names_tasks_and_latents_with_underscores(tc, tmp_path):
    cell = tmp_path / "point_goal_hybrid_rvq_s2"
    cell.mkdir()
    (cell / "cell.json").write_text(json.dumps({"task": "point_goal", "latent": "hybrid_rvq", "seed": 2}))
    (cell / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in _rows(10)) + "\n")
    (cell / "stages.json").write_text(json.dumps([{"stage": "task", "checkpoint": "policy.pt"}]))
    out = tmp_path / "res"
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out)]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    c = data["cells"]["point_goal_hybrid_rvq_s2"]
    assert (c["task"], c["latent"], c["seed"]) == ("point_goal", "hybrid_rvq", 2)
    assert "point_goal/hybrid_rvq" in data["groups"]


def test_collect_with_task_eval_evaluates_the_deterministic_policy(tc, tmp_path, monkeypatch):
    from mocap.testing import invoke

    spec = tmp_path / "spec.yaml"
    spec.write_text(
        "spec_version: 1\nname: tiny\nseed: 0\nhumanoid: {name: amp}\nmotions: {name: deepmimic, params: {clips: [walk]}}\n"
        "simulator: {name: mujoco, params: {threads: 1}}\nlatent: {name: scratch}\ntask:\n  name: speed\n  trainer:\n    name: ppo\n"
        "    params: {num_envs: 2, horizon: 8, total_env_steps: 32, epochs: 1, minibatch_size: 16, torch_threads: 1, actor_hidden: [16], critic_hidden: [16]}\n"
    )
    runs = tmp_path / "runs"
    cell = runs / "speed_scratch_s0"
    assert invoke(["run", spec, "--out", cell]).exit_code == 0
    (cell / "cell.json").write_text(json.dumps({"task": "speed", "latent": "scratch", "seed": 0}))
    out = tmp_path / "res"
    assert tc.main(["collect", "--out", str(runs), "--json", str(out), "--task-eval", "2", "--task-eval-seconds", "0.5"]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    ev = data["cells"]["speed_scratch_s0"]["task_eval"]
    assert ev["steps"] == 30 and ev["num_envs"] == 2 and ev["speed_error"] >= 0.0  # 2 envs x 15 control steps
    assert data["groups"]["speed/scratch"]["task_eval"]["speed_error"]["mean"] == pytest.approx(ev["speed_error"])
    md = out.with_suffix(".md").read_text()
    assert "Deterministic policy (`mocap task-eval`, mean action, 2 envs x 0.5 s)" in md and "| scratch | 1 |" in md
    # a second collect reuses the evaluation while the policy and the protocol match, and redoes it otherwise
    import mocap.task_eval as te

    calls, original = [], te.evaluate_task
    monkeypatch.setattr(te, "evaluate_task", lambda *a, **k: calls.append(k) or original(*a, **k))
    again = ["collect", "--out", str(runs), "--json", str(out), "--task-eval-seconds", "0.5", "--task-eval"]
    assert tc.main([*again, "2"]) == 0
    assert calls == [] and json.loads(out.with_suffix(".json").read_text())["cells"]["speed_scratch_s0"]["task_eval"] == ev
    assert tc.main([*again, "3"]) == 0
    assert len(calls) == 1 and json.loads(out.with_suffix(".json").read_text())["cells"]["speed_scratch_s0"]["task_eval"]["num_envs"] == 3
    cache = cell / "task_eval_cache.json"
    cache.write_text(cache.read_text().replace(json.loads(cache.read_text())["key"]["policy_sha256"], "0" * 64))  # another policy
    assert tc.main([*again, "3"]) == 0
    assert len(calls) == 2
    assert tc.main([*again, "3", "--task-eval-start-clips", "walk"]) == 0  # other start clips: evaluated again
    assert len(calls) == 3 and calls[-1]["start_clips"] == ["walk"]
    assert tc.main([*again, "3", "--task-eval-start-clips", "walk"]) == 0  # and then reused
    assert len(calls) == 3


def test_include_unfinished_labels_a_stopped_cell(tc, tmp_path):
    cell = tmp_path / "reach_pulse_s0"
    cell.mkdir()
    (cell / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in _rows(10)) + "\n")  # no stages.json: stopped
    out = tmp_path / "res"
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out)]) == 2  # nothing finished
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out), "--include-unfinished", "--task-eval", "2"]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    c = data["cells"]["reach_pulse_s0"]
    assert c["latent"] == "pulse (stopped at 0.0M)" and c["finished"] is False and "task_eval" not in c


def test_cut_at_keeps_the_first_steps_and_says_where_the_run_ended(tc):
    rows = _rows(20)  # env steps 100 .. 2000, one iteration = 100
    kept, where = tc.cut_at(rows, 1000)
    assert [r["env_steps"] for r in kept] == [100.0 * (i + 1) for i in range(10)] and where == "past"
    assert tc.cut_at(rows, 2000)[1] == "at" and tc.cut_at(rows, 2050)[1] == "at"  # within one iteration
    assert tc.cut_at(rows, 2200)[1] == "short"
    assert tc.cut_at(rows, None) == (rows, "at")


def test_collect_at_steps_compares_seeds_at_equal_steps(tc, tmp_path, monkeypatch):
    # seed 0 ran 4000 steps (its curve rises on after 2000), seeds 1 and 2 ran 2000; seed 3 stopped at 1000
    for seed, n in ((0, 40), (1, 20), (2, 20), (3, 10)):
        cell = tmp_path / f"speed_pulse_s{seed}"
        cell.mkdir()
        (cell / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in _rows(n)) + "\n")
        (cell / "stages.json").write_text(json.dumps([{"stage": "task", "checkpoint": "policy.pt"}]))
        (cell / "cell.json").write_text(json.dumps({"task": "speed", "latent": "pulse", "seed": seed}))
    out = tmp_path / "res"
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out), "--at-steps", "2000"]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    assert data["at_steps"] == 2000 and sorted(data["groups"]["speed/pulse"]["seeds"]) == [0, 1, 2]
    # seed 0's final value is its rows 18, 19 of 20 kept (the last 10%), not its rows 36..39
    s0 = data["cells"]["speed_pulse_s0"]["final"]["episode/normalized_return"]
    assert s0 == pytest.approx((18 / 40 + 19 / 40) / 2)
    assert data["cells"]["speed_pulse_s0"]["final"]["env_steps"] == 2000.0
    assert "at 0.002M env steps" in out.with_suffix(".md").read_text()
    # only the policies saved at 2000 steps are evaluated (seed 0's is the policy at 4000)
    evaluated = []
    monkeypatch.setattr(tc, "_task_eval", lambda cell, n, s, clips: evaluated.append((cell.name, clips)) or {"num_envs": n, "seconds": s, "speed_error": 1.0})
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out), "--at-steps", "2000", "--task-eval", "2"]) == 0
    assert sorted(evaluated) == [("speed_pulse_s1", None), ("speed_pulse_s2", None)]
    assert "| pulse | 2 |" in out.with_suffix(".md").read_text()  # the deterministic table counts the seeds it evaluated
    evaluated.clear()
    args = ["collect", "--out", str(tmp_path), "--json", str(out), "--at-steps", "2000", "--task-eval", "2", "--task-eval-start-clips", "walk, run"]
    assert tc.main(args) == 0
    assert sorted(evaluated) == [("speed_pulse_s1", ["walk", "run"]), ("speed_pulse_s2", ["walk", "run"])]
    assert "episodes start from walk, run" in out.with_suffix(".md").read_text()
    assert json.loads(out.with_suffix(".json").read_text())["task_eval_start_clips"] == ["walk", "run"]


def test_parse_at_steps_reads_a_default_and_per_task_budgets(tc):
    assert tc.parse_at_steps(None) == {}
    assert tc.parse_at_steps(["7000000", "strike=5e6"]) == {"*": 7_000_000, "strike": 5_000_000}
    for bad in ("strike=", "x", "speed=-3", "0"):
        with pytest.raises(ValueError, match="--at-steps"):
            tc.parse_at_steps([bad])


def _cell(root, task: str, latent: str, seed: int, n: int, value: float = 0.0) -> None:
    cell = root / f"{task}_{latent}_s{seed}"
    cell.mkdir()
    rows = [{**r, "eval/success_rate": value, "eval/speed_error": value} for r in _rows(n)]
    (cell / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    (cell / "stages.json").write_text(json.dumps([{"stage": "task", "checkpoint": "policy.pt"}]))
    (cell / "cell.json").write_text(json.dumps({"task": task, "latent": latent, "seed": seed}))


def test_collect_cuts_each_task_at_its_own_budget(tc, tmp_path, capsys):
    _cell(tmp_path, "speed", "pulse", 0, 40)  # 4000 steps
    _cell(tmp_path, "reach", "pulse", 0, 20)  # 2000 steps
    out = tmp_path / "res"
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out), "--at-steps", "3000", "--at-steps", "reach=1000"]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    assert data["cells"]["speed_pulse_s0"]["final"]["env_steps"] == 3000.0
    assert data["cells"]["reach_pulse_s0"]["final"]["env_steps"] == 1000.0
    assert data["at_steps"] == 3000 and data["at_steps_per_task"] == {"reach": 1000}
    md = out.with_suffix(".md").read_text()
    assert "## reach at 0.001M env steps" in md and "## speed at 0.003M env steps" in md and "equal env steps per task" in md
    # without reach's own budget, reach (2000 steps) is short of 3000 and left out
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out), "--at-steps", "3000"]) == 0
    assert list(json.loads(out.with_suffix(".json").read_text())["cells"]) == ["speed_pulse_s0"]
    assert "skipped reach_pulse_s0" in capsys.readouterr().out
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out), "--at-steps", "reach=lots"]) == 2
    assert "error: --at-steps 'reach=lots'" in capsys.readouterr().err


def test_summary_names_the_best_latent_per_task_in_the_metric_direction(tc, tmp_path):
    for seed in (0, 1):
        _cell(tmp_path, "speed", "pulse", seed, 20, value=1.0 + seed)  # speed error 1.5 on average: worse
        _cell(tmp_path, "speed", "scratch", seed, 20, value=0.5)
        _cell(tmp_path, "reach", "pulse", seed, 20, value=0.6)  # success 0.6: better
        _cell(tmp_path, "reach", "scratch", seed, 20, value=0.2)
    out = tmp_path / "res"
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out)]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    table = tc.summary(data["groups"])
    assert table["speed"]["best"] == "scratch" and table["speed"]["lower_is_better"]
    assert table["reach"]["best"] == "pulse" and not table["reach"]["lower_is_better"]
    assert table["speed"]["values"]["pulse"]["mean"] == pytest.approx(1.5) and table["speed"]["values"]["pulse"]["source"] == "training"
    # the deterministic evaluation, where every latent of a task has one, is the source
    groups = data["groups"]
    groups["speed/pulse"]["task_eval"] = {"speed_error": {"mean": 0.1, "std": 0.0, "n": 2}}
    assert tc.summary(groups)["speed"]["best"] == "scratch"  # scratch has no evaluation: training values for both
    groups["speed/scratch"]["task_eval"] = {"speed_error": {"mean": 0.9, "std": 0.0, "n": 2}}
    assert tc.summary(groups)["speed"]["best"] == "pulse" and tc.summary(groups)["speed"]["values"]["pulse"]["source"] == "deterministic"
    md = out.with_suffix(".md").read_text()
    assert "| speed | speed_error (lower is better) | pulse: 1.5 ± 0.71 (2, training); scratch: 0.5 ± 0 (2, training) | scratch |" in md


def test_merge_keeps_earlier_cells_at_the_same_budget_and_replaces_recollected_ones(tc, tmp_path, capsys):
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir(), second.mkdir()
    _cell(first, "speed", "pulse", 0, 30, value=1.0)
    _cell(first, "speed", "scratch", 0, 30, value=0.5)
    earlier = tmp_path / "earlier"
    assert tc.main(["collect", "--out", str(first), "--json", str(earlier), "--at-steps", "2000"]) == 0
    shutil.rmtree(first)  # the earlier run directories are gone; only the JSON is left
    _cell(second, "speed", "hybrid_rvq", 0, 30, value=2.0)
    _cell(second, "speed", "scratch", 0, 30, value=0.25)  # collected again: replaces the earlier scratch cell
    out = tmp_path / "res"
    args = ["collect", "--out", str(second), "--json", str(out), "--at-steps", "2000", "--merge", str(earlier.with_suffix(".json"))]
    assert tc.main(args) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    assert sorted(data["cells"]) == ["speed_hybrid_rvq_s0", "speed_pulse_s0", "speed_scratch_s0"]
    assert data["groups"]["speed/scratch"]["final"]["eval/speed_error"]["mean"] == pytest.approx(0.25)
    assert data["groups"]["speed/pulse"]["final"]["eval/speed_error"]["mean"] == pytest.approx(1.0)
    assert data["merged_from"][-1]["cells"] == ["speed_pulse_s0"] and "--at-steps 2000" in data["merged_from"][-1]["command"]
    assert "scratch: 0.25" in out.with_suffix(".md").read_text()
    # a different budget for a task the earlier cells share is refused, naming the file
    args[args.index("2000")] = "1000"
    assert tc.main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {earlier.with_suffix('.json')}") and "speed cells are at 2000" in err
    (tmp_path / "bad.json").write_text("[1, 2]")
    assert tc.main([*args[:-1], str(tmp_path / "bad.json")]) == 2
    assert "not a task_compare JSON" in capsys.readouterr().err


def test_collect_skips_folders_that_are_not_cells(tc, tmp_path, capsys):
    """A run folder also holds artifact stores (`artifacts_train2`); collect read every folder's name as
    <task>_<latent>_s<seed> and ended in a ValueError traceback on one that is not."""
    _cell(tmp_path, "speed", "pulse", 0, 10)
    (tmp_path / "artifacts_train2").mkdir()
    (tmp_path / "logs").mkdir()
    out = tmp_path / "res"
    assert tc.main(["collect", "--out", str(tmp_path), "--json", str(out)]) == 0
    assert set(json.loads(out.with_suffix(".json").read_text())["cells"]) == {"speed_pulse_s0"}
    printed = capsys.readouterr().out
    assert "skipped artifacts_train2: not a cell" in printed and "skipped logs: not a cell" in printed
