"""Tests of the downstream task ``strike`` (``mocap_tasks``), moved from ``test_tasks.py``.

Pinned: reward terms and bounds (hypothesis), the box placement on reset, heading invariance and
layout of the goal observation, forbidden-contact termination, metrics on hand-made states, and one
short run with the real MuJoCo simulator."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from test_tasks import F64, SETTINGS, Z, all_ids, random_state, seeds, standing, yaw_world

torch.set_num_threads(1)

from mocap.rotations import (
    heading_angle,
    quat_apply,
    quat_from_axis_angle,
    quat_mul,
    quat_normalize,
)
from mocap_tasks.strike import (
    StrikeParams,
    make_strike,
    strike_reward_code,
    strike_reward_paper,
    up_dot,
)


class FakeSim:
    """The parts of the MuJoCo simulator the strike task uses: a box per env (the declared
    ``mocap.interfaces.MovableTarget`` capability) and ground-only contacts."""

    dt = 1.0 / 30.0
    has_target = True

    def __init__(self, n: int, b: int):
        self.pos = torch.zeros(n, 3, dtype=F64)
        self.rot = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=F64).repeat(n, 1)
        self.lin_vel = torch.zeros(n, 3, dtype=F64)
        self.ang_vel = torch.zeros(n, 3, dtype=F64)
        self.ground_contact = torch.zeros(n, b, dtype=torch.bool)
        self.placed: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []

    def set_target(self, env_ids, pos, rot=None):
        self.pos[env_ids] = pos.to(F64)
        if rot is not None:
            self.rot[env_ids] = rot.to(F64)
        self.lin_vel[env_ids] = 0.0
        self.ang_vel[env_ids] = 0.0
        self.placed.append((env_ids.clone(), pos.clone(), rot.clone()))

    def target_state(self):
        return SimpleNamespace(
            pos=self.pos.clone(),
            rot=self.rot.clone(),
            lin_vel=self.lin_vel.clone(),
            ang_vel=self.ang_vel.clone(),
        )


# ------------------------------------------------------------------------------------- strike
def upright_rot(n: int, yaw: torch.Tensor | float = 0.0) -> torch.Tensor:
    return quat_from_axis_angle(Z.expand(n, 3), torch.as_tensor(yaw, dtype=F64).expand(n))


@SETTINGS
@given(seed=seeds)
def test_strike_reward_terms_and_bounds(seed):
    rng = np.random.default_rng(seed)
    n = 64
    rot = quat_normalize(torch.as_tensor(rng.standard_normal((n, 4))))
    pos = torch.as_tensor(rng.normal(0.0, 3.0, (n, 3)))
    root = torch.as_tensor(rng.normal(0.0, 3.0, (n, 3)))
    vel = torch.as_tensor(rng.normal(0.0, 2.0, (n, 2)))
    c = up_dot(rot)
    assert torch.allclose(c, quat_apply(rot, Z.expand(n, 3))[:, 2])
    paper = strike_reward_paper(rot)
    assert ((paper >= 0) & (paper <= 2)).all()
    assert torch.allclose(paper, 1 - c)
    code = strike_reward_code(pos, rot, root, vel)
    assert ((code >= 0) & (code <= 1)).all()
    assert torch.equal(code[c < 0.2], torch.ones(int((c < 0.2).sum()), dtype=F64))
    assert (code[c >= 0.2] <= 0.6 * 0.8 + 0.4 + 1e-12).all()


def test_strike_code_reward_values():
    up = upright_rot(4)
    tar = torch.tensor([[2.0, 0.0, 0.9]] * 4, dtype=F64)
    root = torch.zeros(4, 3, dtype=F64)
    vel = torch.tensor([[1.0, 0.0], [2.0, 0.5], [-1.0, 0.0], [0.5, 0.0]], dtype=F64)
    r = strike_reward_code(tar, up, root, vel)
    expected = [0.4, 0.4, 0.0, 0.4 * math.exp(-4.0 * 0.25)]
    assert torch.allclose(r, torch.tensor(expected, dtype=F64))
    tilted = quat_from_axis_angle(
        torch.tensor([1.0, 0.0, 0.0], dtype=F64).expand(4, 3),
        torch.full((4,), 0.5, dtype=F64),
    )
    r2 = strike_reward_code(tar, tilted, root, vel)
    assert torch.allclose(r2 - r, torch.full((4,), 0.6 * (1 - math.cos(0.5)), dtype=F64))
    lying = quat_from_axis_angle(
        torch.tensor([1.0, 0.0, 0.0], dtype=F64).expand(4, 3),
        torch.full((4,), math.pi / 2, dtype=F64),
    )
    assert torch.allclose(strike_reward_code(tar, lying, root, vel), torch.ones(4, dtype=F64))
    assert torch.allclose(strike_reward_paper(lying), torch.ones(4, dtype=F64))
    assert torch.allclose(strike_reward_paper(up), torch.zeros(4, dtype=F64))


def make_strike_fake(amp, n=3, **params):
    task = make_strike(StrikeParams(**params), skeleton=amp, num_envs=n)
    sim = FakeSim(n, amp.num_bodies)
    task.attach(sim)
    return task, sim


def test_strike_reset_places_the_box_reproducibly(amp):
    s = standing(256, amp.num_bodies, xy=(1.0, 2.0))
    task, sim = make_strike_fake(amp, 256, seed=4)
    task.reset(all_ids(256), s)
    d = (sim.pos[:, :2] - torch.tensor([1.0, 2.0], dtype=F64)).norm(dim=-1)
    assert ((d >= 1.5) & (d <= 5.0)).all()  # [P]
    assert torch.allclose(sim.pos[:, 2], torch.full((256,), 0.9, dtype=F64))
    assert torch.allclose(up_dot(sim.rot), torch.ones(256, dtype=F64))
    assert heading_angle(sim.rot).std() > 1.0  # random yaw
    task2, sim2 = make_strike_fake(amp, 256, seed=4)
    task2.reset(all_ids(256), s)
    assert torch.equal(sim.pos, sim2.pos) and torch.equal(sim.rot, sim2.rot)
    code, simc = make_strike_fake(amp, 256, distance=(0.5, 10.0), near_prob=0.5)  # [CODE]
    code.reset(all_ids(256), s)
    dc = (simc.pos[:, :2] - torch.tensor([1.0, 2.0], dtype=F64)).norm(dim=-1)
    assert ((dc >= 0.5) & (dc <= 10.0)).all() and 0.3 < float((dc <= 1.5).double().mean()) < 0.8
    assert task.sim_overrides["target"]["half_size"] == (0.2, 0.2, 0.9)
    assert task.sim_overrides["target"]["mass"] == pytest.approx(0.4 * 0.4 * 1.8 * 30.0)
    assert task.max_reward == 1.0 and make_strike(StrikeParams(reward="paper"), skeleton=amp, num_envs=1).max_reward == 2.0
    with pytest.raises(RuntimeError, match="attach"):
        make_strike(StrikeParams(), skeleton=amp, num_envs=1).reset(all_ids(1), standing(1, amp.num_bodies))


@SETTINGS
@given(
    seed=seeds,
    yaw=st.floats(-math.pi, math.pi),
    shift=st.tuples(st.floats(-20.0, 20.0), st.floats(-20.0, 20.0)),
)
def test_strike_observation_is_heading_invariant(amp, seed, yaw, shift):
    rng = np.random.default_rng(seed)
    n = 5
    s = random_state(rng, n, amp.num_bodies)
    task, sim = make_strike_fake(amp, n, seed=seed % 1000)
    task.reset(all_ids(n), s)
    sim.rot = quat_normalize(torch.as_tensor(rng.standard_normal((n, 4))))
    sim.lin_vel = torch.as_tensor(rng.normal(0, 1, (n, 3)))
    sim.ang_vel = torch.as_tensor(rng.normal(0, 1, (n, 3)))
    obs = task.observe(s)
    assert obs.shape == (n, 15)
    qz = quat_from_axis_angle(Z, torch.tensor(yaw, dtype=F64)).expand(n, 4)
    sh = torch.tensor([shift[0], shift[1], 0.0], dtype=F64)
    sim.pos = quat_apply(qz, sim.pos) + sh
    sim.rot = quat_mul(qz, sim.rot)
    sim.lin_vel, sim.ang_vel = quat_apply(qz, sim.lin_vel), quat_apply(qz, sim.ang_vel)
    assert torch.allclose(task.observe(yaw_world(s, yaw, sh)), obs, atol=1e-9)


def test_strike_observation_layout(amp):
    task, sim = make_strike_fake(amp, 1, random_yaw=False)
    s = standing(1, amp.num_bodies, yaw=math.pi / 2, xy=(1.0, 1.0))
    task.reset(all_ids(1), s)
    sim.pos[:] = torch.tensor([1.0, 3.0, 0.9], dtype=F64)  # 2 m straight ahead of the humanoid
    sim.lin_vel[:] = torch.tensor([0.0, 1.0, 0.0], dtype=F64)
    obs = task.observe(s)[0]
    assert torch.allclose(obs[:3], torch.tensor([2.0, 0.0, 0.9], dtype=F64), atol=1e-9)
    # tan_norm of a box turned by -90 deg relative to the heading: x axis -> -y, z axis up
    assert torch.allclose(obs[3:9], torch.tensor([0.0, -1.0, 0.0, 0.0, 0.0, 1.0], dtype=F64), atol=1e-9)
    assert torch.allclose(obs[9:12], torch.tensor([1.0, 0.0, 0.0], dtype=F64), atol=1e-9)


def test_strike_termination_rules(amp):
    B = amp.num_bodies
    hand, lower, foot, torso = (amp.body_index(x) for x in ("right_hand", "right_lower_arm", "left_foot", "torso"))
    s = standing(4, B)
    contact = torch.zeros(4, B, dtype=torch.bool)
    forces = torch.zeros(4, B, 3, dtype=F64)
    contact[0, hand] = True  # env 0: the hand hits the box: allowed
    contact[1, lower] = True  # env 1: the forearm hits it (allowed by the code's strike bodies)
    forces[1, lower, 0] = 80.0
    contact[2, foot] = True  # env 2: a kick (feet are exempt in the code's rule)
    forces[2, foot, 0] = 80.0
    contact[3, torso] = True  # env 3: the torso touches it lightly
    forces[3, torso, 0] = 10.0
    s = replace(s, body_contact=contact, contact_forces=forces)
    paper, sim = make_strike_fake(amp, 4)
    assert paper.terminated(s).tolist() == [False, True, True, True]
    code, _ = make_strike_fake(amp, 4, illegal_contact="code", strike_bodies=("right_hand", "right_lower_arm"))
    code.attach(sim)
    assert code.terminated(s).tolist() == [False, False, False, False]
    forces[3, torso, 0] = 60.0
    assert code.terminated(replace(s, contact_forces=forces)).tolist() == [
        False,
        False,
        False,
        True,
    ]
    off, _ = make_strike_fake(amp, 4, illegal_contact="off")
    off.attach(sim)
    assert not off.terminated(s).any()
    # a ground contact of the torso is a fall, whatever the rule
    sim.ground_contact[0, torso] = True
    contact[0, torso] = True
    assert off.terminated(replace(s, body_contact=contact)).tolist() == [
        True,
        False,
        False,
        False,
    ]


def test_strike_metrics_on_hand_made_states(amp):
    task, sim = make_strike_fake(amp, 2)
    s = standing(2, amp.num_bodies)
    task.reset(all_ids(2), s)
    lying = quat_from_axis_angle(torch.tensor([1.0, 0.0, 0.0], dtype=F64), torch.tensor(math.pi / 2, dtype=F64))
    for t in range(4):
        if t == 2:
            sim.rot[0] = lying  # env 0's box is knocked over on the 3rd step
        task.reward(s, None)
        task.terminated(s)
        task.step(s)
    contact = torch.zeros(2, amp.num_bodies, dtype=torch.bool)
    contact[1, amp.body_index("head")] = True
    task.terminated(replace(s, body_contact=contact))  # env 1: a forbidden contact
    task.reset(all_ids(2), s)
    m = task.metrics()
    assert m["episodes"] == 2 and m["steps"] == 8
    assert m["hit_rate"] == pytest.approx(0.5)
    assert m["time_to_hit"] == pytest.approx(3 / 30)
    assert m["illegal_contact_rate"] == pytest.approx(0.5)
    assert m["up_dot"] == pytest.approx((1 + 1 + 0 + 0 + 4 * 1) / 8)
    assert task.metrics() == {}


def test_strike_with_the_mujoco_simulator(amp):
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator, TargetParams

    task = make_strike(StrikeParams(seed=1), skeleton=amp, num_envs=2)
    sim = MujocoSimulator(
        MujocoParams(threads=1, target=TargetParams(**task.sim_overrides["target"])),
        skeleton=amp,
        num_envs=2,
        seed=0,
    )
    try:
        task.attach(sim)
        assert task.dt == pytest.approx(sim.dt)
        ids = torch.arange(2)
        state = sim.state
        task.reset(ids, state)
        t = sim.target_state()
        d = (t.pos[:, :2] - state.root_pos[:, :2]).norm(dim=-1)
        assert ((d >= 1.5 - 1e-5) & (d <= 5.0 + 1e-5)).all()
        assert not t.fallen.any()
        hold = state.dof_pos.clone()
        for _ in range(3):
            state = sim.step(hold)
            r = task.reward(state, hold)
            done = task.terminated(state)
            task.step(state)
            obs = task.observe(state)
            assert torch.isfinite(r).all() and ((r >= 0) & (r <= 1)).all()
            assert obs.shape == (2, 15) and torch.isfinite(obs).all()
            assert done.dtype == torch.bool and done.shape == (2,)
        m = task.metrics()
        assert m["steps"] == 6 and all(math.isfinite(v) for v in m.values())
    finally:
        sim.close()
