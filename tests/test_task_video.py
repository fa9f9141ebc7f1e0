"""`mocap render RUN_DIR` of a trained task run (mocap.task_video) and the tasks' video markers."""

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


def test_render_a_task_run(tmp_path: Path):
    spec = tmp_path / "spec.yaml"
    spec.write_text(SPEC)
    run = tmp_path / "run"
    assert invoke(["run", spec, "--out", run]).exit_code == 0
    assert task_stage(run)["stage"] == "task"
    out = tmp_path / "strike.gif"
    result = invoke(["render", run, "--seconds", "0.2", "--width", "64", "--height", "48", "--out", out])
    assert result.exit_code == 0, result.output
    assert "task strike through scratch" in result.stdout and "6 frames" in result.stdout
    import imageio.v3 as iio

    frames = iio.imread(out, index=None)
    assert frames.shape[0] == 6 and frames.shape[1:3] == (48, 64)


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
