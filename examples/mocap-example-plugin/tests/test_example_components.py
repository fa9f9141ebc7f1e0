"""The example plugin's task and latent space keep mocap's contracts (mocap.testing), and the task
runs end to end through ``mocap run`` with the built-in ``scratch`` latent."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest
import torch

from mocap.observations import proprioception_and_goal
from mocap.rotations import heading_angle
from mocap.state import Observations
from mocap.testing import check_latent_space, check_task, fake_sim_state, invoke

# fixtures here rather than in a conftest.py, whose module name would clash with mocap's own tests'
PACKAGE = Path(__file__).resolve().parents[1]


@pytest.fixture()
def plugin():
    """mocap's plugin set with this plugin registered through the same loader as installed ones.

    Without installing the package, its folder is on ``sys.path`` for the test only: left there, a
    ``*.egg-info`` folder a local ``pip install`` wrote next to it would make it look installed to
    every later plugin load in the process."""
    from mocap.plugins import get_plugins
    from mocap.testing import use_plugins

    if "face_heading" in get_plugins().names("task"):  # the package is installed: its entry point registered it
        yield get_plugins()
        return
    sys.path.insert(0, str(PACKAGE))
    try:
        import mocap_example

        with use_plugins(("example_under_test", mocap_example), entry_points=True) as pset:
            yield pset
    finally:
        sys.path.remove(str(PACKAGE))


@pytest.fixture(scope="module")
def amp():
    from mocap.plugins import get_plugins

    return get_plugins().get("humanoid", "amp").build(None)


def test_face_heading_keeps_the_task_contract(plugin, amp):
    task = plugin.get("task", "face_heading").build({"change_steps": 2}, skeleton=amp, num_envs=4)
    assert "state_dict round-trip" in check_task(task, amp, num_envs=4)


def test_face_heading_rewards_facing_the_target(plugin, amp):
    task = plugin.get("task", "face_heading").build(None, skeleton=amp, num_envs=4)
    state = fake_sim_state(amp, 4)
    task.reset(torch.arange(4), state)
    task.target[:] = heading_angle(state.root_rot)  # facing the target already
    assert torch.allclose(task.reward(state, torch.zeros(4, amp.num_dofs)), torch.ones(4), atol=1e-5)
    assert torch.allclose(task.observe(state), torch.tensor([[1.0, 0.0]]).expand(4, 2), atol=1e-5)
    task.target[:] = heading_angle(state.root_rot) + math.pi / 2  # a quarter turn away: reward cos(90 deg) = 0
    assert torch.allclose(task.reward(state, torch.zeros(4, amp.num_dofs)), torch.zeros(4), atol=1e-5)
    assert task.terminated(fake_sim_state(amp, 4, height=0.3)).all() and not task.terminated(state).any()
    assert set(task.metrics()) == {"heading_error_deg", "facing_rate", "fall_rate"}


def test_tiny_ae_keeps_the_latent_contract_and_loads_its_checkpoint(plugin, amp, tmp_path):
    from mocap.distill_files import save_latent
    from mocap.errors import UserError

    proprio, goal = proprioception_and_goal(fake_sim_state(amp, 5), fake_sim_state(amp, 5, seed=1))
    obs = Observations(proprio, goal)
    comp = plugin.get("latent", "tiny_ae")
    latent = comp.build({"latent_dim": 6}, skeleton=amp, checkpoint=None)
    assert "random_action" in check_latent_space(latent, obs, action_dim=amp.num_dofs)
    latent.update_normalizers(obs)
    save_latent(tmp_path / "latent.pt", latent)
    loaded = comp.build({"latent_dim": 6}, skeleton=amp, checkpoint=tmp_path / "latent.pt")
    with torch.no_grad():
        assert torch.equal(latent.encoder(obs).mean, loaded.encoder(obs).mean)
    with pytest.raises(UserError, match="latent_dim"):
        comp.build({"latent_dim": 7}, skeleton=amp, checkpoint=tmp_path / "latent.pt")


SPEC = """\
spec_version: 1
name: face-heading-scratch
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk]}}
simulator: {name: mujoco}
latent: {name: scratch}
task:
  name: face_heading
  params: {change_steps: 50, episode_steps: 60}
  trainer:
    name: ppo
    params: {num_envs: 4, horizon: 8, total_env_steps: 256, epochs: 1, minibatch_size: 32,
             actor_hidden: [16], critic_hidden: [16], torch_threads: 1}
"""


def test_face_heading_runs_end_to_end(plugin, tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text(SPEC)
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "h"])
    assert result.exit_code == 0, result.output
    stages = {s["stage"]: s for s in json.loads((tmp_path / "runs" / "h" / "stages.json").read_text())}
    assert "eval/heading_error_deg" in stages["task"]["metrics"]  # the task's metrics() reach the summary
    assert "heading error (deg)" in (tmp_path / "runs" / "h" / "report.md").read_text()  # with its declared unit
