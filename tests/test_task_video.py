"""A trained task run reopened (mocap.task_run): `mocap render RUN_DIR` (mocap.task_video), `mocap task-eval
RUN_DIR` (mocap.task_eval), and the tasks' video markers."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from mocap.plugins import get_plugins
from mocap.task_video import task_stage
from mocap.testing import invoke

SPEC = """\
spec_version: 1
name: strike-video
seed: 0
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk]}}
simulator: {name: mujoco, params: {threads: 1}}
latent: {name: scratch}
task:
  name: strike
  trainer:
    name: ppo
    params: {num_envs: 2, horizon: 8, total_env_steps: 32, epochs: 1, minibatch_size: 16, torch_threads: 1, actor_hidden: [16], critic_hidden: [16]}
"""


@pytest.fixture(scope="module")
def amp():
    return get_plugins().get("humanoid", "amp").build({})


@pytest.fixture(scope="module")
def task_run(tmp_path_factory) -> Path:
    """A finished (tiny) strike run through scratch."""
    tmp = tmp_path_factory.mktemp("task_run")
    spec = tmp / "spec.yaml"
    spec.write_text(SPEC)
    run = tmp / "run"
    assert invoke(["run", spec, "--out", run]).exit_code == 0
    return run


def test_render_a_task_run(task_run: Path, tmp_path: Path):
    run = task_run
    assert task_stage(run)["stage"] == "task"
    out = tmp_path / "strike.gif"
    result = invoke(["render", run, "--seconds", "0.2", "--width", "64", "--height", "48", "--out", out])
    assert result.exit_code == 0, result.output
    assert "task strike through scratch" in result.stdout and "6 frames" in result.stdout
    import imageio.v3 as iio

    frames = iio.imread(out, index=None)
    assert frames.shape[0] == 6 and frames.shape[1:3] == (48, 64)


def test_task_eval_counts_every_env_step_and_is_deterministic(task_run: Path, tmp_path: Path):
    out = tmp_path / "eval.json"
    result = invoke(["task-eval", task_run, "--envs", "3", "--seconds", "1", "--json", out])
    assert result.exit_code == 0, result.output
    assert "task strike through scratch" in result.stdout and "| `hit_rate` |" in result.stdout
    r = json.loads(out.read_text())
    assert r["task"] == "strike" and r["latent"] == "scratch" and r["num_envs"] == 3
    assert r["env_steps"] == 90 and r["steps"] == 90  # 3 envs x 30 control steps, each counted by the task once
    assert r["seconds"] == pytest.approx(1.0)
    assert 0.0 <= r["terminated_share"] <= 1.0 and r["envs_never_terminated"] in (0.0, 1 / 3, 2 / 3, 1.0)
    # an env that terminated ended an episode
    assert r["episodes_ended"] >= round(3 * (1.0 - r["envs_never_terminated"]))
    if r["episodes_ended"] == 0:
        assert math.isnan(r["episode_return"]) and r["envs_never_terminated"] == 1.0
    from mocap.task_eval import evaluate_task

    again = evaluate_task(task_run, num_envs=3, seconds=1.0)
    assert {k: v for k, v in again.items() if isinstance(v, float) and not math.isnan(v)} == {
        k: v for k, v in r.items() if isinstance(v, float) and not math.isnan(v)
    }
    # episodes restart at the episode length: 12 s of a 10 s episode ends at least one per env
    longer = evaluate_task(task_run, num_envs=2, seconds=12.0)
    assert longer["episodes_ended"] >= 2 and not math.isnan(longer["episode_length"]) and longer["episode_length"] <= 300


def test_an_exported_task_run_evaluates_and_renders_as_the_run(task_run: Path, tmp_path: Path):
    ck = tmp_path / "checkpoints" / "strike_tiny"
    assert invoke(["export", task_run, ck]).exit_code == 0
    assert (ck / "task_policy.pt").is_file() and "checkpoint: task_policy.pt" in (ck / "spec.yaml").read_text()
    from mocap.task_eval import evaluate_task
    from mocap.task_run import is_task_target

    assert is_task_target(ck) and is_task_target(task_run) and not is_task_target(tmp_path)
    a, b = evaluate_task(task_run, num_envs=2, seconds=0.5), evaluate_task(ck, num_envs=2, seconds=0.5)
    assert {k: v for k, v in a.items() if k != "policy"} == {k: v for k, v in b.items() if k != "policy"}  # same seed, same rollout
    result = invoke(["render", ck, "--seconds", "0.1", "--width", "64", "--height", "48", "--out", tmp_path / "s.gif"])
    assert result.exit_code == 0 and "task strike through scratch" in result.stdout, result.output


def test_task_eval_errors_are_one_line(task_run: Path, tmp_path: Path):
    result = invoke(["task-eval", tmp_path])
    assert result.exit_code == 2 and "no finished task stage" in result.stderr and "Traceback" not in result.stderr
    result = invoke(["task-eval", task_run, "--envs", "0"])
    assert result.exit_code == 2 and "num_envs >= 1" in result.stderr


def test_task_eval_start_clips_replace_the_runs_motion_set(task_run: Path, tmp_path: Path):
    from mocap.task_run import open_task_run

    for clips, expected in ((None, ["walk"]), (["run", "jump"], ["run", "jump"])):
        run = open_task_run(task_run, 2, start_clips=clips)
        try:
            assert run.env.library.clip_names == expected
        finally:
            run.close()
    out = tmp_path / "eval.json"
    result = invoke(["task-eval", task_run, "--envs", "2", "--seconds", "0.2", "--start-clips", "run, jump", "--json", out])
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text())["start_clips"] == ["run", "jump"]
    result = invoke(["task-eval", task_run, "--start-clips", "runn"])
    assert result.exit_code == 2 and "unknown DeepMimic clip" in result.stderr and "Traceback" not in result.stderr
    result = invoke(["task-eval", task_run, "--start-clips", " , "])
    assert result.exit_code == 2 and "at least one clip" in result.stderr


def test_task_stage_of_other_directories(tmp_path: Path):
    assert task_stage(tmp_path) is None
    (tmp_path / "stages.json").write_text(json.dumps([{"stage": "imitator", "checkpoint": "x.pt"}]))
    assert task_stage(tmp_path) is None
    (tmp_path / "stages.json").write_text("not json")
    assert task_stage(tmp_path) is None


def test_speed_and_reach_markers(amp):
    from mocap_tasks.reach import ReachParams, make_reach
    from mocap_tasks.speed import SpeedParams, make_speed

    speed = make_speed(SpeedParams(), skeleton=amp, num_envs=3)
    speed.prev_root_pos[1] = torch.tensor([2.0, -1.0, 0.9], dtype=torch.float64)
    speed.target_dir[1] = torch.tensor([math.cos(0.7), math.sin(0.7)], dtype=torch.float64)
    speed.target_speed[1] = 3.0
    ((pos, rgba, radius),) = speed.markers(1)
    assert np.allclose(pos[:2], [2.0 + math.cos(0.7), -1.0 + math.sin(0.7)]) and len(rgba) == 4
    assert radius == pytest.approx(0.04 + 0.02 * 3.0)
    reach = make_reach(ReachParams(), skeleton=amp, num_envs=2)
    reach.target[0] = torch.tensor([0.3, 0.4, 1.2], dtype=torch.float64)
    ((pos, _, _),) = reach.markers(0)
    assert np.allclose(pos, [0.3, 0.4, 1.2])


def test_strike_markers_show_the_target_top(amp):
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator, TargetParams
    from mocap_tasks.strike import StrikeParams, make_strike

    task = make_strike(StrikeParams(seed=1), skeleton=amp, num_envs=2)
    sim = MujocoSimulator(MujocoParams(threads=1, target=TargetParams(**task.sim_overrides["target"])), skeleton=amp, num_envs=2, seed=0)
    try:
        task.attach(sim)
        task.reset(torch.arange(2), sim.state)
        centre, top = task.markers(1)
        t = sim.target_state()
        assert np.allclose(centre[0], t.pos[1].double().numpy(), atol=1e-6)
        # upright after reset: the top is straight above the centre, half the height up
        assert np.allclose(top[0] - centre[0], [0.0, 0.0, task.params.half_size[2]], atol=1e-4)
    finally:
        sim.close()


def test_eval_suite_evaluates_the_task_stage(tmp_path: Path):
    """``eval_suite``'s ``task`` part: the deterministic policy's metrics under ``task_eval/`` and a video."""
    spec = tmp_path / "spec.yaml"
    suite = "eval:\n  trainer:\n    name: eval_suite\n    params: {imitation: null, generation: null, task: {num_envs: 3, seconds: 0.5, video_seconds: 0.2}}\n"
    spec.write_text(SPEC + suite)
    run = tmp_path / "run"
    result = invoke(["run", spec, "--out", run])
    assert result.exit_code == 0, result.output
    stages = {s["stage"]: s for s in json.loads((run / "stages.json").read_text())}
    metrics = stages["eval"]["metrics"]
    assert metrics["task_eval/env_steps"] == 45 and metrics["task_eval/steps"] == 45  # 3 envs x 15 control steps
    assert 0.0 <= metrics["task_eval/reward"] <= 1.0 and "task_eval/video" not in metrics
    assert "| mean reward | `reward` |" in (run / "task_eval.md").read_text() and (run / "task.mp4").stat().st_size > 0
    # the same numbers as `mocap task-eval` of the run with the eval stage's seed
    from mocap.task_eval import evaluate_task

    again = evaluate_task(run, num_envs=3, seconds=0.5, seed=stages["eval"]["seed"])
    assert again["steps"] == metrics["task_eval/steps"] and again["reward"] == pytest.approx(metrics["task_eval/reward"])
