"""Tests of the downstream tasks ``terrain``, ``point_goal``, ``inbetween`` and ``generation``
(``mocap_tasks``) and of the task-env hooks they use (``start_state``, ``attach_motions``,
``prior_rollout``).

Pinned: reward bounds and maxima (hypothesis), heading invariance of the goal observations
(hypothesis), trajectory / keyframe sampling, metric definitions on hand-made states, the
generation task's prior rollout (and its refusal of ``scratch``), and per task a couple of PPO
iterations with ``scratch`` and with a (tiny, untrained) PULSE latent. The terrain task's own tests are
in ``test_tasks_terrain.py``."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_tasks import Z, random_state, standing, yaw_world

torch.set_num_threads(1)

import mocap_tasks.plugin
from mocap.rotations import quat_apply, quat_from_axis_angle
from mocap.state import SimState
from mocap_tasks.generation import GenerationTaskParams, make_generation
from mocap_tasks.inbetween import (
    InbetweenParams,
    inbetween_reward,
    keyframe_goal,
    make_inbetween,
    time_encoding,
)
from mocap_tasks.point_goal import PointGoalParams, make_point_goal, point_goal_reward
from mocap_tasks.terrain import TerrainTaskParams, make_terrain

F64 = torch.float64
SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
seeds = st.integers(0, 2**32 - 1)
yaws = st.floats(-math.pi, math.pi)
shifts = st.tuples(st.floats(-20, 20), st.floats(-20, 20))


def rot_z(yaw: float, v: torch.Tensor) -> torch.Tensor:
    q = quat_from_axis_angle(Z, torch.tensor(yaw, dtype=F64))
    return quat_apply(q.expand(*v.shape[:-1], 4), v)


def as_sim_state(frames, contact: bool = False) -> SimState:
    """A SimState equal to reference ``frames`` (no contacts)."""
    n, b = frames.body_pos.shape[:2]
    return SimState(
        root_pos=frames.root_pos.double(),
        root_rot=frames.root_rot.double(),
        root_lin_vel=frames.root_lin_vel.double(),
        root_ang_vel=frames.root_ang_vel.double(),
        dof_pos=frames.dof_pos.double(),
        dof_vel=frames.dof_vel.double(),
        body_pos=frames.body_pos.double(),
        body_rot=frames.body_rot.double(),
        body_lin_vel=frames.body_lin_vel.double(),
        body_ang_vel=frames.body_ang_vel.double(),
        contact_forces=torch.zeros(n, b, 3, dtype=F64),
        body_contact=torch.full((n, b), contact),
        unstable=torch.zeros(n, dtype=torch.bool),
        dof_force=torch.zeros(n, frames.dof_pos.shape[1], dtype=F64),
    )


@pytest.fixture(scope="module")
def punch_lib(amp):
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary

    return MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["punch", "walk"])).load(amp), amp)


# ---------------------------------------------------------------------------------- registry
def test_plugin_registers_the_four_tasks(amp):
    from mocap.testing import use_plugins

    with use_plugins(("tasks", mocap_tasks.plugin)) as pset:
        for name, goal in (("terrain", 20 + 32 * 32), ("point_goal", 2), ("inbetween", 2 * amp.num_bodies * 7), ("generation", 0)):
            task = pset.get("task", name).build({}, skeleton=amp, num_envs=2)
            assert task.goal_dim == goal and task.max_reward == 1.0
        assert pset.get("task", "terrain").build({}, skeleton=amp, num_envs=1).sim_overrides["terrain"]["kind"] == "stairs"


# -------------------------------------------------------------------------------- point goal
@SETTINGS
@given(
    seed=seeds,
    direction=st.sampled_from(["toward_target", "paper"]),
    radius=st.floats(0.0, 1.0),
)
def test_point_goal_reward_bounds_arrival_and_direction(seed, direction, radius):
    g = torch.Generator().manual_seed(seed)
    root = torch.randn(16, 2, generator=g, dtype=F64) * 5
    target = torch.randn(16, 2, generator=g, dtype=F64) * 5
    vel = torch.randn(16, 2, generator=g, dtype=F64) * 2
    kw = {"arrive_radius": radius, "direction": direction}
    r = point_goal_reward(root, vel, target, **kw)
    assert torch.all((r > 0) & (r <= 1))
    dist = torch.linalg.vector_norm(target - root, dim=-1)
    assert torch.all(r[dist <= radius] == 1)
    d_hat = (target - root) / dist[:, None]
    sign = 1.0 if direction == "toward_target" else -1.0
    fast = point_goal_reward(root, sign * 1.5 * d_hat, target, **kw)  # faster than u along d: r_speed = 1
    slow_away = point_goal_reward(root, -sign * 1.5 * d_hat, target, **kw)
    r_pos = torch.exp(-0.5 * dist**2)
    far = dist > radius
    assert torch.allclose(fast[far], 0.7 * r_pos[far] + 0.3)
    assert torch.all(fast >= slow_away)


def test_point_goal_reward_value():
    r = point_goal_reward(torch.zeros(1, 2, dtype=F64), torch.tensor([[0.4, 3.0]], dtype=F64), torch.tensor([[2.0, 0.0]], dtype=F64))
    assert float(r[0]) == pytest.approx(0.7 * math.exp(-0.5 * 4) + 0.3 * math.exp(-(0.6**2)))
    paper = point_goal_reward(torch.zeros(1, 2, dtype=F64), torch.tensor([[0.4, 3.0]], dtype=F64), torch.tensor([[2.0, 0.0]], dtype=F64), direction="paper")
    assert float(paper[0]) == pytest.approx(0.7 * math.exp(-0.5 * 4) + 0.3 * math.exp(-(1.4**2)))


@SETTINGS
@given(seed=seeds, yaw=yaws, shift=shifts)
def test_point_goal_observation_is_heading_invariant(amp, seed, yaw, shift):
    tasks = [make_point_goal(PointGoalParams(), skeleton=amp, num_envs=4, seed=seed) for _ in range(2)]
    state = random_state(np.random.default_rng(seed % 2**32), 4, amp.num_bodies)
    sh = torch.tensor([shift[0], shift[1], 0.0], dtype=F64)
    moved = yaw_world(state, yaw, sh)
    tasks[0].reset(torch.arange(4), state)
    tasks[1].reset(torch.arange(4), moved)
    assert torch.allclose(tasks[1].anchor_xy, moved.root_pos[:, :2])  # drawn around the start position
    t3 = torch.cat((tasks[0].target, torch.zeros(4, 1, dtype=F64)), -1)
    tasks[1].target = (rot_z(yaw, t3) + sh)[:, :2]  # the same target in the moved world
    a, b = tasks[0].observe(state), tasks[1].observe(moved)
    assert a.shape == (4, 2) and torch.allclose(a, b, atol=1e-8)


def test_point_goal_sampling_schedule_termination_and_metrics(amp):
    p = PointGoalParams(radius=3.0, change_steps=4, arrive_radius=0.5)
    task = make_point_goal(p, skeleton=amp, num_envs=2, seed=5)
    state = standing(2, amp.num_bodies, xy=(1.0, -2.0))
    task.reset(torch.arange(2), state)
    assert torch.all(torch.linalg.vector_norm(task.target - torch.tensor([1.0, -2.0], dtype=F64), dim=-1) <= 3.0)
    first = task.target.clone()
    # env 0 sits on its target from the 2nd step; env 1 never gets there
    task.target[0] = torch.tensor([5.0, 5.0], dtype=F64)
    task.target[1] = torch.tensor([1.0, 2.0], dtype=F64)  # 4 m away
    for k in range(4):
        s = state
        if k >= 1:
            s = replace(state, root_pos=state.root_pos.clone())
            s.root_pos[0, :2] = torch.tensor([5.0, 5.2], dtype=F64)
        r = task.reward(s, None)
        if k >= 1:
            assert float(r[0]) == 1.0
        task.step(s)
    assert not torch.equal(task.target, first)  # redrawn after 4 steps, around the start point
    assert torch.all(torch.linalg.vector_norm(task.target - torch.tensor([1.0, -2.0], dtype=F64), dim=-1) <= 3.0)
    m = task.metrics()
    assert m["goals"] == 2 and m["success_rate"] == 0.5 and m["time_to_reach"] == pytest.approx(2 / 30)
    assert m["final_distance"] == pytest.approx((0.2 + 4.0) / 2) and m["steps"] == 8
    assert m["closest_distance"] == pytest.approx((0.2 + 4.0) / 2)  # env 0 was 5.83 m away at its first step
    low = replace(state, body_pos=state.body_pos.clone())
    low.body_pos[1, task.head_index, 2] = 0.3
    assert task.terminated(low).tolist() == [False, True]


# --------------------------------------------------------------------------------- inbetween
@SETTINGS
@given(tta=st.lists(st.integers(0, 500), min_size=1, max_size=8), dim=st.integers(1, 40))
def test_time_encoding_bounded_deterministic_and_sinusoidal(tta, dim):
    t = torch.tensor(tta)
    e = time_encoding(t, dim)
    assert e.shape == (len(tta), dim) and torch.all(e.abs() <= 1)
    assert torch.equal(e, time_encoding(t.clone(), dim))
    assert torch.allclose(e[:, 0], torch.sin(t.double()))
    if dim >= 2:
        assert torch.allclose(e[:, 1], torch.cos(t.double()))
    if dim >= 4:
        assert torch.allclose(e[:, 2], torch.sin(t.double() / 10000 ** (2 / dim)))


@SETTINGS
@given(seed=seeds, root_only=st.booleans())
def test_inbetween_reward_is_one_on_the_reference_and_decreases_with_errors(amp, seed, root_only):
    ref = random_state(np.random.default_rng(seed % 2**32), 3, amp.num_bodies, amp.num_dofs)
    ee = torch.tensor([5, 8, 11, 14])
    r = inbetween_reward(ref, ref, ee, root_only=root_only)
    assert torch.allclose(r, torch.ones(3, dtype=F64))
    off = replace(ref, root_pos=ref.root_pos + 0.1, dof_pos=ref.dof_pos + 0.2, body_pos=ref.body_pos + 0.05)
    worse = replace(ref, root_pos=ref.root_pos + 0.3, dof_pos=ref.dof_pos + 0.4, body_pos=ref.body_pos + 0.1)
    r1, r2 = inbetween_reward(off, ref, ee, root_only=root_only), inbetween_reward(worse, ref, ee, root_only=root_only)
    assert torch.all((r2 > 0) & (r2 < r1) & (r1 < 1))
    e_root = math.exp(-10 * 3 * 0.1**2)
    if root_only:
        assert torch.allclose(r1, torch.full((3,), e_root, dtype=F64))
    else:
        expect = 0.1 * e_root + 0.65 * math.exp(-2 * amp.num_dofs * 0.04) + 0.1 + 0.15 * math.exp(-40 * 4 * 3 * 0.05**2)
        assert torch.allclose(r1, torch.full((3,), expect, dtype=F64))


@SETTINGS
@given(seed=seeds, yaw=yaws, shift=shifts)
def test_keyframe_goal_is_heading_invariant_and_zero_at_the_keyframe(amp, seed, yaw, shift):
    rng = np.random.default_rng(seed % 2**32)
    s, k = random_state(rng, 3, amp.num_bodies), random_state(rng, 3, amp.num_bodies)
    sh = torch.tensor([shift[0], shift[1], 0.0], dtype=F64)
    s2, k2 = yaw_world(s, yaw, sh), yaw_world(k, yaw, sh)
    a = keyframe_goal(s.root_rot, s.body_pos, s.body_rot, k.body_pos, k.body_rot)
    b = keyframe_goal(s2.root_rot, s2.body_pos, s2.body_rot, k2.body_pos, k2.body_rot)
    assert a.shape == (3, amp.num_bodies * 7) and torch.allclose(a, b, atol=1e-8)
    zero = keyframe_goal(s.root_rot, s.body_pos, s.body_rot, s.body_pos, s.body_rot)
    B = amp.num_bodies
    assert torch.allclose(zero[:, : 3 * B], torch.zeros(3, 3 * B, dtype=F64), atol=1e-12)
    ident = zero[:, 3 * B :].reshape(3, B, 4)
    assert torch.allclose(ident, torch.tensor([1.0, 0, 0, 0], dtype=F64).expand(3, B, 4), atol=1e-9)


@SETTINGS
@given(seed=seeds, yaw=yaws, shift=shifts, concat=st.booleans(), root=st.booleans())
def test_inbetween_task_observation_is_heading_invariant(amp, seed, yaw, shift, concat, root):
    p = InbetweenParams(time_encoding="concat" if concat else "add", keyframe="root" if root else "full_body", sequence_steps=20)
    tasks = [make_inbetween(p, skeleton=amp, num_envs=2, seed=seed) for _ in range(2)]
    rng = np.random.default_rng(seed % 2**32)
    state, keys = random_state(rng, 2, amp.num_bodies), random_state(rng, 2, amp.num_bodies)
    sh = torch.tensor([shift[0], shift[1], 0.0], dtype=F64)
    for t, s_k in ((tasks[0], keys), (tasks[1], yaw_world(keys, yaw, sh))):
        t.key_steps[:] = torch.tensor([0, 3, 9, 14, 20])
        pos, rot = (s_k.root_pos[:, None], s_k.root_rot[:, None]) if root else (s_k.body_pos, s_k.body_rot)
        t.key_pos[:] = pos[:, None].expand(-1, 5, -1, -1)
        t.key_rot[:] = rot[:, None].expand(-1, 5, -1, -1)
        t.progress[:] = torch.tensor([2, 9])
    a, b = tasks[0].observe(state), tasks[1].observe(yaw_world(state, yaw, sh))
    assert a.shape == (2, tasks[0].goal_dim) and torch.allclose(a, b, atol=1e-7)
    assert tasks[0].interval()[1].tolist() == [1, 3]


def test_inbetween_window_keyframes_metrics_and_termination(amp, punch_lib):
    T, K = 30, 5
    task = make_inbetween(InbetweenParams(sequence_steps=T, num_keyframes=K), skeleton=amp, num_envs=2, seed=2)
    task.attach_motions(punch_lib)
    frames = punch_lib.frames(torch.tensor([0, 1]), torch.tensor([1.9, 1.0]))  # punch (2.13 s, no loop), walk (loops)
    start = task.start_state(torch.arange(2), frames)
    assert float(start.times[0]) == pytest.approx(float(punch_lib.durations[0]) - T / 30, abs=1e-5)
    assert float(task.t0[1]) == pytest.approx(1.0, abs=1e-6)  # a looping clip keeps its time
    state = as_sim_state(start)
    task.reset(torch.arange(2), state)
    ks = task.key_steps
    assert torch.all(ks[:, 0] == 0) and torch.all(ks[:, -1] == T) and torch.all(ks[:, 1:] > ks[:, :-1])
    # the keyframes are the clip's frames at their steps
    ref = task.reference(torch.tensor([0]), ks[0, 2:3])
    assert torch.allclose(task.key_pos[0, 2], ref.body_pos[0].double(), atol=1e-6)
    # follow the ground truth exactly: reward 1, every keyframe hit with zero error
    for k in range(1, T + 1):
        gt = as_sim_state(task.reference(torch.arange(2), torch.full((2,), k)))
        r = task.reward(gt, None)
        assert torch.allclose(r, torch.ones(2, dtype=F64), atol=1e-6)
        assert not task.terminated(gt).any()
        task.step(gt)
    task.reset(torch.arange(2), state)
    m = task.metrics()
    assert m["episodes"] == 2 and m["success_rate"] == 1.0 and m["keyframe_success_rate"] == 1.0
    assert m["keyframe_gmpjpe_mm"] == pytest.approx(0.0, abs=1e-3) and m["full_gmpjpe_mm"] == pytest.approx(0.0, abs=1e-3)
    assert m["steps"] == 2 * T
    # one body 0.6 m off: terminated by the paper's 'any body' rule, not by the mean rule
    gt = as_sim_state(task.reference(torch.arange(2), torch.ones(2, dtype=torch.long)))
    gt.body_pos[0, 3, 0] += 0.6
    assert task.terminated(gt).tolist() == [True, False]
    mean_task = make_inbetween(InbetweenParams(sequence_steps=T, distance_reduce="mean"), skeleton=amp, num_envs=2)
    mean_task.attach_motions(punch_lib)
    mean_task.start_state(torch.arange(2), frames)
    assert not mean_task.terminated(gt).any()


def test_inbetween_keyframes_reward_mode(amp, punch_lib):
    T = 12
    task = make_inbetween(InbetweenParams(sequence_steps=T, num_keyframes=3, reward_target="keyframes"), skeleton=amp, num_envs=1, seed=0)
    assert task.max_reward == pytest.approx(2 / 12)
    task.attach_motions(punch_lib)
    start = task.start_state(torch.arange(1), punch_lib.frames(torch.tensor([0]), torch.tensor([0.2])))
    task.reset(torch.arange(1), as_sim_state(start))
    total = 0.0
    for k in range(1, T + 1):
        r = task.reward(as_sim_state(task.reference(torch.arange(1), torch.tensor([k]))), None)
        assert float(r[0]) == pytest.approx(1.0 if k in task.key_steps[0, 1:].tolist() else 0.0, abs=1e-6)
        total += float(r[0])
        task.step(None)
    assert total / (task.max_reward * T) == pytest.approx(1.0, abs=1e-5)


# -------------------------------------------------------------------------------- generation
def test_generation_task_reward_falls_and_diversity(amp):
    from mocap.generation_eval import in_start_frame, pairwise_diversity

    p = GenerationTaskParams(episode_steps=4, diversity_stride=2)
    task = make_generation(p, skeleton=amp, num_envs=3)
    assert task.goal_dim == 0 and task.prior_rollout and not task.fall.early_termination
    state = standing(3, amp.num_bodies)
    state = replace(state, body_contact=torch.zeros(3, amp.num_bodies, dtype=torch.bool))
    task.reset(torch.arange(3), state)
    g = torch.Generator().manual_seed(0)
    recorded = [state.body_pos.clone()]
    for k in range(1, 5):
        s = replace(state, body_pos=state.body_pos + 0.1 * k * torch.randn(3, 1, 3, generator=g, dtype=F64), body_contact=state.body_contact.clone())
        if k >= 2:  # env 1 is down (a hand on the ground below 0.15 m) from step 2 on; env 2 only at step 3
            s.body_pos[1, 5, 2] = 0.05
            s.body_contact[1, 5] = True
        if k == 3:
            s.body_pos[2, 5, 2] = 0.05
            s.body_contact[2, 5] = True
        r = task.reward(s, None)
        assert torch.equal(r, torch.zeros(3, dtype=r.dtype)) and observe_empty(task, s)
        assert not task.terminated(s).any()
        task.step(s)
        if k % 2 == 0:
            recorded.append(s.body_pos.clone())
    task.reset(torch.arange(3), state)
    m = task.metrics()
    assert m["episodes"] == 3 and m["fall_rate"] == pytest.approx(2 / 3)
    assert m["time_to_fall_s"] == pytest.approx((2 + 3) / 2 / 30) and m["survival_s"] == pytest.approx((4 + 2 + 3) / 3 / 30)
    assert m["down_at_end"] == pytest.approx(1 / 3) and m["steps"] == 12
    from mocap.generation_eval import heading_frame

    body = torch.stack(recorded).float()  # (3 frames, N, B, 3)
    origin, heading = heading_frame(state.root_pos.float(), state.root_rot.float())
    assert m["diversity_episodes"] == 3
    assert m["diversity_m"] == pytest.approx(pairwise_diversity(in_start_frame(body, origin, heading)), rel=1e-5)
    assert task.metrics() == {}


def observe_empty(task, s) -> bool:
    return task.observe(s).shape == (s.num_envs, 0)


def _tiny_pulse(amp):
    from mocap_pulse.latent import PulseParams, make_pulse

    torch.manual_seed(0)
    return make_pulse(PulseParams(latent_dim=4, encoder_hidden=[8], prior_hidden=[8], decoder_hidden=[8]), skeleton=amp)


def _env(amp, lib, task, latent, n, seed=0):
    from mocap.task_env import TaskEnv
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator

    sim = MujocoSimulator(MujocoParams.model_validate({"threads": 1, **task.sim_overrides}), skeleton=amp, num_envs=n, seed=0)
    return TaskEnv(task, latent, lambda obs, out: out, lib, sim, seed=seed)


def test_generation_refuses_scratch_and_ignores_the_policy_action(amp, punch_lib):
    from mocap.hierarchy import ScratchParams
    from mocap.task_env import ScratchLatent

    task = make_generation(GenerationTaskParams(episode_steps=5), skeleton=amp, num_envs=2)
    with pytest.raises(ValueError, match="scratch"):
        _env(amp, punch_lib, task, ScratchLatent(ScratchParams(), amp), 2)
    latent = _tiny_pulse(amp)
    envs = [_env(amp, punch_lib, make_generation(GenerationTaskParams(episode_steps=5), skeleton=amp, num_envs=2), latent, 2) for _ in range(2)]
    try:
        obs = [e.reset() for e in envs]
        assert torch.equal(obs[0], obs[1]) and obs[0].shape[1] == envs[0].proprio_dim
        g = torch.Generator().manual_seed(1)
        for _ in range(3):
            a, b = envs[0].step(torch.randn(2, 4, generator=g) * 5), envs[1].step(torch.zeros(2, 4))
            assert torch.equal(a.obs, b.obs) and torch.equal(a.reward, torch.zeros(2))
        sd = envs[0].state_dict()
        assert "prior_generator" in sd
    finally:
        for e in envs:
            e.close()


# ------------------------------------------------------------------------------ PPO smoke runs
def _smoke(tmp_path: Path, make_env):
    from mocap.rl.ppo import PPOParams, PPOTrainer
    from test_ppo import FakeContext

    params = PPOParams(num_envs=2, horizon=4, total_env_steps=16, epochs=1, minibatch_size=8, actor_hidden=[8], critic_hidden=[8], torch_threads=1)
    ctx = FakeContext(tmp_path, make_env)
    try:
        result = PPOTrainer(params).run(ctx)
    finally:
        ctx.log.close()
    assert result.checkpoint is not None and Path(result.checkpoint).is_file()
    import json

    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and all(math.isfinite(r["loss/total"]) for r in rows if "loss/total" in r)
    return rows


TASKS = {
    "terrain": lambda amp: make_terrain(TerrainTaskParams(terrain={"kind": "rough", "size": 4.0}, map_shape=(4, 4), episode_steps=6), skeleton=amp, num_envs=2),
    "point_goal": lambda amp: make_point_goal(PointGoalParams(episode_steps=6, change_steps=3), skeleton=amp, num_envs=2),
    "inbetween": lambda amp: make_inbetween(InbetweenParams(sequence_steps=6, num_keyframes=3), skeleton=amp, num_envs=2),
    "generation": lambda amp: make_generation(GenerationTaskParams(episode_steps=6, diversity_stride=2), skeleton=amp, num_envs=2),
}
METRIC = {"terrain": "eval/traj_error", "point_goal": "eval/distance", "inbetween": "eval/full_gmpjpe_mm", "generation": "eval/diversity_m"}


# generation with scratch is refused (test_generation_refuses_scratch_and_ignores_the_policy_action)
PAIRS = [(name, latent) for name in sorted(TASKS) for latent in ("scratch", "pulse") if (name, latent) != ("generation", "scratch")]


@pytest.mark.parametrize(("name", "latent"), PAIRS)
def test_ppo_smoke_run(amp, punch_lib, tmp_path, name, latent):
    from mocap.hierarchy import ScratchParams
    from mocap.task_env import ScratchLatent

    lat = ScratchLatent(ScratchParams(), amp) if latent == "scratch" else _tiny_pulse(amp)
    envs = []

    def make_env(n):
        envs.append(_env(amp, punch_lib, TASKS[name](amp), lat, n))
        return envs[-1]

    rows = _smoke(tmp_path, make_env)
    assert any(METRIC[name] in r for r in rows), rows[-1].keys()
    if name == "terrain":  # the start_state hook put every humanoid on the spawn square
        assert torch.all(envs[0].task.verts[:, 0].abs() <= 0.5 + 1e-6)


def test_generation_with_scratch_is_a_clear_error_in_a_spec(tmp_path):
    from mocap.testing import invoke

    spec = tmp_path / "spec.yaml"
    spec.write_text(
        "spec_version: 1\nname: gen_scratch\ndevice: cpu\nhumanoid: {name: amp}\n"
        "motions: {name: deepmimic, params: {clips: [walk]}}\nsimulator: {name: mujoco}\nlatent: {name: scratch}\n"
        "task:\n  name: generation\n  trainer: {name: ppo, params: {num_envs: 2, horizon: 4, total_env_steps: 8, "
        "minibatch_size: 8, epochs: 1, actor_hidden: [8], critic_hidden: [8], torch_threads: 1}}\n"
    )
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "g"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "task generation with latent scratch" in result.stderr and "no prior" in result.stderr
