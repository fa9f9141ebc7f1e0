"""Hierarchical control (``mocap.hierarchy``): the task env over any latent space, the ``scratch``
baseline, and the ``task`` stage trained by PPO through the pipeline."""

from __future__ import annotations

import json
import types
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, ConfigDict
from test_distill import teacher_file, walk  # noqa: F401  (fixtures)

from mocap.hierarchy import ScratchParams
from mocap.task_env import ScratchLatent, TaskEnv
from mocap.hooks import hookimpl
from mocap.interfaces import Box, Task
from mocap.motion.library import MotionLibrary
from mocap.testing import invoke, use_plugins


class UprightParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    episode_steps: int = 20


class Upright(Task):
    """A throw-away task: keep the root high; goal = a constant; fails when the root drops below 0.5 m."""

    goal_dim = 2
    max_reward = 1.0

    def __init__(self, params: UprightParams, num_envs: int):
        self.episode_steps = params.episode_steps
        self.resets = 0
        self.sum_height, self.count = 0.0, 0

    def reset(self, env_ids, state):
        self.resets += len(env_ids)

    def observe(self, state):
        return torch.ones(state.root_pos.shape[0], 2)

    def reward(self, state, actions):
        h = state.root_pos[:, 2].float()
        self.sum_height += float(h.sum())
        self.count += h.numel()
        return torch.exp(-4.0 * (h - 0.9).clamp_min(-1.0).square())

    def terminated(self, state):
        return state.root_pos[:, 2] < 0.5

    def metrics(self):
        out = {"root_height": self.sum_height / max(self.count, 1)}
        self.sum_height, self.count = 0.0, 0
        return out


upright_plugin = types.SimpleNamespace(
    register_tasks=hookimpl(
        lambda register: register(
            "upright",
            lambda params, *, skeleton, num_envs, device="cpu": Upright(params, num_envs),
            params=UprightParams,
            description="test task",
        )
    )
)


def _env(amp, walk, latent, n=3, mapping=None):  # noqa: F811
    from mocap_sim_mujoco.simulator import MujocoSimulator

    lib = MotionLibrary(walk, amp)
    sim = MujocoSimulator(skeleton=amp, num_envs=n, seed=0)
    return TaskEnv(Upright(UprightParams(), n), latent, mapping or (lambda obs, out: out), lib, sim, seed=1)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=4))
def test_scratch_maps_the_unit_box_onto_the_joint_ranges(amp, values):
    latent = ScratchLatent(ScratchParams(), amp)
    lo = torch.tensor([h.range[0] for h in amp.hinges])
    hi = torch.tensor([h.range[1] for h in amp.hinges])
    a = torch.tensor(values).repeat(amp.num_dofs)[: amp.num_dofs].unsqueeze(0)
    q = latent.decoder(None, latent.to_latent(None, a))
    assert torch.all(q >= lo - 1e-5) and torch.all(q <= hi + 1e-5)
    ones = latent.decoder(None, latent.to_latent(None, torch.ones(1, amp.num_dofs) * 7))  # clamped to +1
    assert torch.allclose(ones[0], hi) and torch.allclose(latent.decoder(None, -torch.ones(1, amp.num_dofs))[0], lo)
    assert latent.task_action_space == Box((amp.num_dofs,), -1.0, 1.0)


def test_task_env_steps_resets_and_reports(amp, walk):  # noqa: F811
    latent = ScratchLatent(ScratchParams(), amp)
    env = _env(amp, walk, latent)
    obs = env.reset()
    assert obs.shape == (3, env.proprio_dim + 2) and env.obs_dim == obs.shape[1]
    finished = 0
    for _ in range(25):
        out = env.step(torch.zeros(3, amp.num_dofs))
        assert out.reward.shape == (3,) and torch.all((out.reward > 0) & (out.reward <= 1))
        if out.episodes:
            finished += len(out.episodes["return"])
            n = out.episodes["normalized_return"]
            assert torch.all((n > 0) & (n <= 1)) and torch.allclose(n, out.episodes["return"] / 20)
        assert not torch.any(out.terminated & out.truncated)
    assert finished >= 3  # every env hit the 20-step limit or fell at least once
    assert "root_height" in env.after_iteration(0, None)
    env.close()


def test_task_env_resume_is_exact(amp, walk):  # noqa: F811
    latent = ScratchLatent(ScratchParams(), amp)
    a, b = _env(amp, walk, latent), _env(amp, walk, latent)
    a.reset()
    g = torch.Generator().manual_seed(0)
    acts = [torch.rand(3, amp.num_dofs, generator=g) * 2 - 1 for _ in range(30)]
    for act in acts[:10]:
        a.step(act)
    b.load_state_dict(a.state_dict())
    for act in acts[10:]:
        ra, rb = a.step(act), b.step(act)
        assert torch.equal(ra.obs, rb.obs) and torch.equal(ra.reward, rb.reward)
    a.close(), b.close()


def test_task_env_resumes_on_a_simulator_without_a_physics_state(amp, walk):  # noqa: F811
    """A simulator whose ``get_physics_state`` gives None (the interface default) is saved as its
    HumanoidState fields and restored with ``reset`` (the task env used to save only 6 of the 10
    fields and could not rebuild the state)."""
    from mocap_sim_mujoco.simulator import MujocoSimulator

    class Kinematic(MujocoSimulator):
        def get_physics_state(self):
            return None

    latent = ScratchLatent(ScratchParams(), amp)
    envs = [
        TaskEnv(Upright(UprightParams(), 3), latent, lambda obs, out: out, MotionLibrary(walk, amp), Kinematic(skeleton=amp, num_envs=3, seed=0), seed=1)
        for _ in range(2)
    ]
    a, b = envs
    a.reset()
    for _ in range(5):
        a.step(torch.zeros(3, amp.num_dofs))
    sd = a.state_dict()
    assert "physics" not in sd and set(sd["sim_state"]) >= {"root_pos", "body_pos", "body_ang_vel"}
    b.reset()
    b.load_state_dict(sd)
    assert torch.allclose(b.sim.state.root_pos, a.sim.state.root_pos, atol=1e-6)
    a.close(), b.close()


def test_a_reference_dependent_decoder_is_refused(amp, walk, teacher_file):  # noqa: F811
    from mocap_phc.imitator import PHCParams, make_phc

    teacher = make_phc(PHCParams(action="residual"), skeleton=amp, checkpoint=teacher_file)
    env = _env(amp, walk, ScratchLatent(ScratchParams(), amp), mapping=teacher.to_pd_targets)
    env.reset()
    with pytest.raises(ValueError, match="reference"):
        env.pd_targets(env.sim.state, torch.zeros(3, amp.num_dofs))
    env.close()


def _task_spec(latent: str, teacher: Path | None = None) -> str:
    latent_section = "latent: {name: scratch}"
    imitator = ""
    if latent == "pulse":
        imitator = f"imitator: {{name: phc, params: {{action: residual}}, checkpoint: {teacher}}}\n"
        latent_section = (
            "latent:\n  name: pulse\n  params: {latent_dim: 4, encoder_hidden: [16], prior_hidden: [16], decoder_hidden: [16]}\n"
            "  trainer: {name: distill, params: {num_envs: 2, horizon: 4, total_env_steps: 16, minibatch_envs: 2, eval_every: 0, "
            "act_with: teacher, label: pd_targets}}"
        )
    return f"""\
spec_version: 1
name: task_{latent}
device: cpu
humanoid: {{name: amp}}
motions: {{name: deepmimic, params: {{clips: [walk]}}}}
simulator: {{name: mujoco}}
{imitator}{latent_section}
task:
  name: upright
  trainer: {{name: ppo, params: {{num_envs: 4, horizon: 8, total_env_steps: 64, minibatch_size: 16, epochs: 1, \
actor_hidden: [16], critic_hidden: [16], torch_threads: 1}}}}
"""


@pytest.mark.parametrize("latent", ["scratch", "pulse"])
def test_task_stage_trains_with_ppo_through_any_latent(latent, teacher_file, tmp_path):  # noqa: F811
    spec = tmp_path / "spec.yaml"
    spec.write_text(_task_spec(latent, teacher_file))
    with use_plugins(("upright", upright_plugin)):
        result = invoke(["run", spec, "--out", tmp_path / "runs" / "t"])
    assert result.exit_code == 0, result.output
    stages = {s["stage"]: s for s in json.loads((tmp_path / "runs" / "t" / "stages.json").read_text())}
    assert stages["task"]["checkpoint"].endswith("policy.pt")
    rows = [json.loads(line) for line in (tmp_path / "runs" / "t" / "metrics.jsonl").read_text().splitlines()]
    task_rows = [r for r in rows if r.get("stage") == "task" or "eval/root_height" in r]
    assert any("eval/root_height" in r for r in task_rows), rows[-1]
    # the task's own metrics reach the stage summary and report.md, not only metrics.jsonl
    assert "eval/root_height" in stages["task"]["metrics"]
    assert "root_height" in (tmp_path / "runs" / "t" / "report.md").read_text()


def test_task_without_latent_is_a_clear_error(tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text(_task_spec("scratch").replace("latent: {name: scratch}\n", ""))
    with use_plugins(("upright", upright_plugin)):
        result = invoke(["run", spec, "--out", tmp_path / "runs" / "t"])
    assert result.exit_code == 2 and "Traceback" not in result.output and "scratch" in result.stderr


def test_task_env_with_goals_resumes_exactly(amp, walk):  # noqa: F811
    """A goal task (speed: target speed and direction, redrawn on reset) resumes bit-exactly: its
    goals and generator are part of the env's state (they were not: a resumed stage drew new goals)."""
    from mocap_sim_mujoco.simulator import MujocoSimulator
    from mocap_tasks.speed import SpeedParams, make_speed

    def env():  # type: ignore[no-untyped-def]
        sim = MujocoSimulator(skeleton=amp, num_envs=3, seed=0)
        task = make_speed(SpeedParams(change_steps=(3, 5)), skeleton=amp, num_envs=3, seed=5)
        return TaskEnv(task, ScratchLatent(ScratchParams(), amp), lambda obs, out: out, MotionLibrary(walk, amp), sim, seed=1)

    a, b = env(), env()
    a.reset()
    g = torch.Generator().manual_seed(0)
    acts = [torch.rand(3, amp.num_dofs, generator=g) * 2 - 1 for _ in range(20)]
    for act in acts[:8]:
        a.step(act)
    b.load_state_dict(a.state_dict())
    for act in acts[8:]:  # goals change every 3-4 steps: new ones come from the restored generator
        ra, rb = a.step(act), b.step(act)
        assert torch.equal(ra.obs, rb.obs) and torch.equal(ra.reward, rb.reward)
    a.close(), b.close()


def test_task_env_zeroes_the_reward_of_an_unstable_step_and_logs_the_terms(amp, walk):  # noqa: F811
    """The episode layer (mocap.episodes): the task's reward is the term ``task`` (logged unweighted
    as ``reward/task``), 0 on a numerically unstable step, and termination is ``task`` OR ``unstable``
    (logged as ``terminated/<name>``); the episode's return leaves the unstable step's reward out."""
    from dataclasses import replace

    from mocap_sim_mujoco.simulator import MujocoSimulator

    class Shaky(MujocoSimulator):
        calls = 0

        def step(self, targets):  # type: ignore[no-untyped-def]
            s = super().step(targets)
            self.calls += 1
            if self.calls == 4:  # env 1 blows up on the 4th step
                s = replace(s, unstable=torch.tensor([False, True, False]))
            return s

    sim = Shaky(skeleton=amp, num_envs=3, seed=0)
    env = TaskEnv(Upright(UprightParams(), 3), ScratchLatent(ScratchParams(), amp), lambda obs, out: out, MotionLibrary(walk, amp), sim, seed=1)
    env.reset()
    rewards = []
    for k in range(4):
        out = env.step(torch.zeros(3, amp.num_dofs))
        assert set(out.info) == {"reward/task", "terminated/task", "terminated/unstable"}
        assert torch.equal(out.terminated, out.info["terminated/task"].bool() | out.info["terminated/unstable"].bool())
        rewards.append(out.reward.clone())
        if k < 3:
            assert torch.equal(out.info["terminated/unstable"], torch.zeros(3)) and torch.equal(out.reward, out.info["reward/task"])
    assert torch.equal(out.info["terminated/unstable"], torch.tensor([0.0, 1.0, 0.0]))
    assert float(out.reward[1]) == 0.0 and float(out.info["reward/task"][1]) > 0  # the term is logged as it was
    assert torch.equal(out.reward[[0, 2]], out.info["reward/task"][[0, 2]])
    assert bool(out.terminated[1]) and not bool(out.truncated[1])
    done = (out.terminated | out.truncated).nonzero().squeeze(-1).tolist()
    i = done.index(1)
    assert float(out.episodes["success"][i]) == 0.0 and float(out.episodes["length"][i]) == 4.0
    expected = sum(float(r[1]) for r in rewards[:3])
    assert float(out.episodes["return"][i]) == pytest.approx(expected, rel=1e-6)
    assert int(env.book.steps[1]) == 0  # reset
    env.close()


def test_task_env_resumes_from_a_state_dict_with_float32_returns(amp, walk):  # noqa: F811
    """Returns are float64 now (the episode layer's EpisodeBook); a state dict written before (with
    ``ep_return`` float32) still loads and continues like the running env."""
    latent = ScratchLatent(ScratchParams(), amp)
    a, b = _env(amp, walk, latent), _env(amp, walk, latent)
    a.reset()
    g = torch.Generator().manual_seed(0)
    acts = [torch.rand(3, amp.num_dofs, generator=g) * 2 - 1 for _ in range(25)]
    for act in acts[:6]:
        a.step(act)
    sd = a.state_dict()
    assert set(sd) >= {"steps", "ep_return"} and sd["ep_return"].dtype == torch.float64
    b.load_state_dict({**sd, "ep_return": sd["ep_return"].float()})  # the old format
    assert b.book.returns.dtype == torch.float64 and torch.equal(b.book.steps, a.book.steps)
    for act in acts[6:]:
        ra, rb = a.step(act), b.step(act)
        assert torch.equal(ra.obs, rb.obs) and torch.equal(ra.reward, rb.reward) and torch.equal(ra.terminated, rb.terminated)
        assert set(ra.episodes) == set(rb.episodes) and torch.equal(ra.episodes.get("length", torch.zeros(0)), rb.episodes.get("length", torch.zeros(0)))
        torch.testing.assert_close(ra.episodes.get("return", torch.zeros(0)), rb.episodes.get("return", torch.zeros(0)))
    a.close(), b.close()
