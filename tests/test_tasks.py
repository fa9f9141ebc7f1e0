"""Tests of the downstream-task plugin (``mocap_tasks``): speed, reach and strike.

Pinned: reward bounds and maxima, heading invariance of the goal observations (hypothesis), metric
definitions on hand-made states, seeded goal sampling, fall / forbidden-contact termination, and one
short run of strike with the real MuJoCo simulator. The strike tests (and their ``FakeSim``) are in
``test_tasks_strike.py``."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

torch.set_num_threads(1)

import mocap_tasks
import mocap_tasks.plugin
from mocap.rotations import (
    quat_apply,
    quat_from_axis_angle,
    quat_mul,
    quat_normalize,
)
from mocap.state import SimState
from mocap_tasks.reach import ReachParams, make_reach, reach_reward
from mocap_tasks.speed import SpeedParams, make_speed, speed_reward
from mocap_tasks.strike import StrikeParams

F64 = torch.float64
SETTINGS = settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
seeds = st.integers(0, 2**32 - 1)
Z = torch.tensor([0.0, 0.0, 1.0], dtype=F64)


# ------------------------------------------------------------------------------------ helpers
def random_state(rng: np.random.Generator, n: int, b: int, d: int = 6) -> SimState:
    """Random bodies around a standing height; the root's x axis well away from vertical."""
    t = lambda a: torch.as_tensor(a, dtype=F64)
    yaw = t(rng.uniform(-math.pi, math.pi, n))
    tilt = t(rng.uniform(-0.5, 0.5, n))
    root_rot = quat_mul(
        quat_from_axis_angle(Z.expand(n, 3), yaw),
        quat_from_axis_angle(t(rng.standard_normal((n, 3))), tilt),
    )
    body_rot = quat_normalize(t(rng.standard_normal((n, b, 4))))
    body_rot[:, 0] = root_rot
    body_pos = t(rng.normal(0.0, 0.4, (n, b, 3)))
    body_pos[..., :2] += t(rng.normal(0.0, 3.0, (n, 1, 2)))
    body_pos[..., 2] += 1.0
    lin, ang = t(rng.normal(0.0, 2.0, (n, b, 3))), t(rng.normal(0.0, 3.0, (n, b, 3)))
    return SimState(
        root_pos=body_pos[:, 0].clone(),
        root_rot=root_rot,
        root_lin_vel=lin[:, 0].clone(),
        root_ang_vel=ang[:, 0].clone(),
        dof_pos=t(rng.normal(0.0, 1.0, (n, d))),
        dof_vel=t(rng.normal(0.0, 1.0, (n, d))),
        body_pos=body_pos,
        body_rot=body_rot,
        body_lin_vel=lin,
        body_ang_vel=ang,
        contact_forces=torch.zeros(n, b, 3, dtype=F64),
        body_contact=torch.zeros(n, b, dtype=torch.bool),
        unstable=torch.zeros(n, dtype=torch.bool),
        dof_force=torch.zeros(n, d, dtype=F64),
    )


def standing(n: int, b: int, yaw: float = 0.0, xy=(0.0, 0.0)) -> SimState:
    """Every body at the root (1 m high), facing ``yaw``, at rest."""
    s = random_state(np.random.default_rng(0), n, b)
    q = quat_from_axis_angle(Z, torch.tensor(yaw, dtype=F64)).expand(n, 4).clone()
    pos = torch.tensor([xy[0], xy[1], 1.0], dtype=F64).expand(n, 3).clone()
    zero = torch.zeros(n, 3, dtype=F64)
    return replace(
        s,
        root_pos=pos,
        root_rot=q,
        root_lin_vel=zero.clone(),
        root_ang_vel=zero.clone(),
        body_pos=pos[:, None].expand(n, b, 3).clone(),
        body_rot=q[:, None].expand(n, b, 4).clone(),
        body_lin_vel=torch.zeros(n, b, 3, dtype=F64),
        body_ang_vel=torch.zeros(n, b, 3, dtype=F64),
    )


def yaw_world(s: SimState, yaw: float, shift: torch.Tensor) -> SimState:
    """The same state seen in a world rotated by ``yaw`` about z and translated by ``shift``."""
    qz = quat_from_axis_angle(Z, torch.tensor(yaw, dtype=F64))
    rot = lambda v: quat_apply(qz.expand(*v.shape[:-1], 4), v)
    return replace(
        s,
        root_pos=rot(s.root_pos) + shift,
        root_rot=quat_mul(qz.expand(*s.root_rot.shape), s.root_rot),
        root_lin_vel=rot(s.root_lin_vel),
        root_ang_vel=rot(s.root_ang_vel),
        body_pos=rot(s.body_pos) + shift,
        body_rot=quat_mul(qz.expand(*s.body_rot.shape), s.body_rot),
        body_lin_vel=rot(s.body_lin_vel),
        body_ang_vel=rot(s.body_ang_vel),
    )


def all_ids(n: int) -> torch.Tensor:
    return torch.arange(n)


# ---------------------------------------------------------------------------------- registry
def test_plugin_registers_the_three_tasks(amp):
    from mocap.testing import use_plugins

    with use_plugins(("tasks", mocap_tasks.plugin)) as pset:
        dims = {}
        for name in ("speed", "reach", "strike"):
            task = pset.get("task", name).build({"seed": 3}, skeleton=amp, num_envs=4)
            assert isinstance(task, mocap_tasks.common.TaskBase)
            dims[name] = task.goal_dim
        with pytest.raises(ValidationError):
            pset.get("task", "reach").build({"coefficent": 4.0}, skeleton=amp, num_envs=4)
    assert dims == {"speed": 3, "reach": 3, "strike": 15}


def test_params_are_documented_and_strict():
    for model in (SpeedParams, ReachParams, StrikeParams):
        assert model.model_config.get("extra") == "forbid"
        for name, field in model.model_fields.items():
            assert field.description, f"{model.__name__}.{name} has no description"
    # every paper/code switch says which is which
    for model, name in (
        (ReachParams, "coefficient"),
        (StrikeParams, "reward"),
        (StrikeParams, "distance"),
        (SpeedParams, "velocity"),
    ):
        d = model.model_fields[name].description
        assert "[P]" in d and "[CODE]" in d
    with pytest.raises(ValidationError):
        SpeedParams(speed_range=(3.0, 1.0))
    with pytest.raises(ValidationError):
        ReachParams(change_steps=(0, 5))


# -------------------------------------------------------------------------------------- speed
@SETTINGS
@given(seed=seeds, v_star=st.floats(0.0, 5.0), angle=st.floats(-math.pi, math.pi))
def test_speed_reward_bounded_and_maximal_exactly_at_the_target_velocity(seed, v_star, angle):
    rng = np.random.default_rng(seed)
    d = torch.tensor([[math.cos(angle), math.sin(angle)]], dtype=F64)
    vs = torch.tensor([v_star], dtype=F64)
    best = speed_reward(vs[:, None] * d, d, vs)
    assert torch.allclose(best, torch.ones(1, dtype=F64), atol=0, rtol=0)
    v = torch.as_tensor(rng.normal(0.0, 3.0, (64, 2)))
    r = speed_reward(v, d.expand(64, 2), vs.expand(64))
    assert ((r > 0) & (r <= 1)).all()
    off = (v - vs * d).norm(dim=-1) > 1e-6
    assert (r[off] < 1).all()
    # the formula: along-error weight 1, tangent weight 0.1, scale 0.25
    along, tangent = (v * d).sum(-1), v[:, 1] * d[0, 0] - v[:, 0] * d[0, 1]
    assert torch.allclose(r, torch.exp(-0.25 * ((v_star - along) ** 2 + 0.1 * tangent**2)))


def test_speed_task_reward_uses_the_chosen_velocity(amp):
    B = amp.num_bodies
    task = make_speed(
        SpeedParams(direction="world_x", speed_range=(2.0, 2.0)),
        skeleton=amp,
        num_envs=2,
    )
    s0 = standing(2, B)
    task.reset(all_ids(2), s0)
    s1 = replace(s0, root_lin_vel=torch.tensor([[2.0, 0.0, 0.3], [0.0, 2.0, 0.0]], dtype=F64))
    r = task.reward(s1, torch.zeros(2, amp.num_dofs))
    assert r[0].item() == pytest.approx(1.0)
    assert r[1].item() == pytest.approx(math.exp(-0.25 * (4.0 + 0.1 * 4.0)))
    # [CODE] finite difference of the root position over dt (the step() hook stores the previous one)
    fd = make_speed(
        SpeedParams(direction="world_x", speed_range=(2.0, 2.0), velocity="finite_difference"),
        skeleton=amp,
        num_envs=2,
    )
    fd.reset(all_ids(2), s0)
    moved = replace(s0, root_pos=s0.root_pos + torch.tensor([2.0 / 30.0, 0.0, 0.0], dtype=F64))
    assert torch.allclose(fd.reward(moved, None), torch.ones(2, dtype=F64))
    fd.step(moved)
    assert torch.allclose(fd.reward(moved, None), torch.full((2,), math.exp(-0.25 * 4.0), dtype=F64))


def test_speed_goals_direction_modes_and_periodic_change(amp):
    B = amp.num_bodies
    s = standing(3, B, yaw=0.7)
    task = make_speed(SpeedParams(change_steps=(3, 3), seed=1), skeleton=amp, num_envs=3)
    task.reset(all_ids(3), s)
    assert torch.allclose(
        task.target_dir,
        torch.tensor([math.cos(0.7), math.sin(0.7)], dtype=F64).expand(3, 2),
    )
    # facing the target direction: the observed direction is +x of the heading frame
    obs = task.observe(s)
    assert torch.allclose(obs[:, :2], torch.tensor([1.0, 0.0], dtype=F64).expand(3, 2), atol=1e-9)
    assert torch.equal(obs[:, 2], task.target_speed)
    assert ((task.target_speed >= 0) & (task.target_speed <= 5)).all()
    first = task.target_speed.clone()
    task.step(s)
    task.step(s)
    assert torch.equal(task.target_speed, first)
    task.step(s)
    assert not torch.equal(task.target_speed, first)  # resampled after exactly 3 steps
    assert torch.allclose(task.target_dir[:, 0], torch.full((3,), math.cos(0.7), dtype=F64))  # direction kept
    wx = make_speed(SpeedParams(direction="world_x"), skeleton=amp, num_envs=3)
    wx.reset(all_ids(3), s)
    assert torch.equal(wx.target_dir, torch.tensor([[1.0, 0.0]] * 3, dtype=F64))
    rnd = make_speed(SpeedParams(direction="random", change_steps=(1, 1)), skeleton=amp, num_envs=3)
    rnd.reset(all_ids(3), s)
    d0 = rnd.target_dir.clone()
    assert torch.allclose(d0.norm(dim=-1), torch.ones(3, dtype=F64))
    rnd.step(s)
    assert not torch.equal(rnd.target_dir, d0)


def test_speed_metrics_on_hand_made_states(amp):
    B = amp.num_bodies
    task = make_speed(
        SpeedParams(direction="world_x", speed_range=(1.0, 1.0)),
        skeleton=amp,
        num_envs=2,
    )
    s = standing(2, B)
    task.reset(all_ids(2), s)
    # env 0: 1 m/s along +x facing +x; env 1: 1 m/s along +y facing +y
    q1 = quat_from_axis_angle(Z, torch.tensor(math.pi / 2, dtype=F64))
    rot = torch.stack((s.root_rot[0], q1))
    s = replace(
        s,
        root_rot=rot,
        root_lin_vel=torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=F64),
    )
    r = task.reward(s, None)
    m = task.metrics()
    assert m["steps"] == 2
    assert m["speed_error"] == pytest.approx(0.5)  # |1 - 1| and |1 - 0|
    assert m["tangent_speed"] == pytest.approx(0.5)
    assert m["velocity_error"] == pytest.approx(math.sqrt(2) / 2)
    assert m["heading_error"] == pytest.approx(math.pi / 4)
    assert m["reward"] == pytest.approx(float(r.mean()))
    assert task.metrics() == {}  # cleared


@SETTINGS
@given(
    seed=seeds,
    yaw=st.floats(-math.pi, math.pi),
    shift=st.tuples(*[st.floats(-20.0, 20.0)] * 3),
)
def test_speed_observation_is_heading_invariant(amp, seed, yaw, shift):
    s = random_state(np.random.default_rng(seed), 5, amp.num_bodies)
    task = make_speed(SpeedParams(direction="random", seed=seed % 1000), skeleton=amp, num_envs=5)
    task.reset(all_ids(5), s)
    obs = task.observe(s)
    s2 = yaw_world(s, yaw, torch.tensor(shift, dtype=F64))
    task.target_dir = torch.stack(
        (math.cos(yaw) * task.target_dir[:, 0] - math.sin(yaw) * task.target_dir[:, 1],
         math.sin(yaw) * task.target_dir[:, 0] + math.cos(yaw) * task.target_dir[:, 1]), dim=-1
    )  # fmt: skip
    assert torch.allclose(task.observe(s2), obs, atol=1e-9)
    # the reward is invariant too (root_lin_vel rotates with the world)
    task2 = make_speed(SpeedParams(direction="random", seed=seed % 1000), skeleton=amp, num_envs=5)
    task2.reset(all_ids(5), s)
    assert torch.allclose(task.reward(s2, None), task2.reward(s, None), atol=1e-9)


# -------------------------------------------------------------------------------------- reach
@SETTINGS
@given(seed=seeds, k=st.sampled_from([4.0, 5.0]))
def test_reach_reward_in_unit_interval_and_one_at_the_target(seed, k):
    rng = np.random.default_rng(seed)
    c = torch.as_tensor(rng.normal(0.0, 1.0, (32, 3)))
    hand = c + torch.as_tensor(rng.normal(0.0, 0.5, (32, 3)))
    r = reach_reward(hand, c, k)
    assert ((r > 0) & (r <= 1)).all()
    assert torch.equal(reach_reward(c, c, k), torch.ones(32, dtype=F64))
    assert torch.allclose(r, torch.exp(-k * ((hand - c) ** 2).sum(-1)))
    far = reach_reward(c + 2 * (hand - c), c, k)
    assert (far <= r).all()  # monotone in the distance


@SETTINGS
@given(seed=seeds, k=st.floats(0.5, 10.0), w=st.floats(0.01, 1.0), kf=st.floats(0.05, 2.0))
def test_reach_far_term_keeps_the_range_and_rewards_approach_from_far(seed, k, w, kf):
    rng = np.random.default_rng(seed)
    c = torch.as_tensor(rng.normal(0.0, 1.0, (32, 3)))
    hand = c + torch.as_tensor(rng.normal(0.0, 2.0, (32, 3)))
    r = reach_reward(hand, c, k, w, kf)
    assert ((r > 0) & (r <= 1)).all()
    assert torch.allclose(reach_reward(c, c, k, w, kf), torch.ones(32, dtype=F64))
    d2 = ((hand - c) ** 2).sum(-1)
    assert torch.allclose(r, (1 - w) * torch.exp(-k * d2) + w * torch.exp(-kf * d2))
    assert torch.equal(reach_reward(hand, c, k, 0.0, kf), reach_reward(hand, c, k))  # w = 0: the paper's
    assert (reach_reward(c + 2 * (hand - c), c, k, w, kf) <= r).all()
    # 3 m away the paper's term is ~0; the wide term still pays for 1 m of approach
    at = torch.tensor([[3.0, 0.0, 0.0], [2.0, 0.0, 0.0]], dtype=F64)
    gain = reach_reward(at[1:], torch.zeros(1, 3, dtype=F64), k, w, kf) - reach_reward(at[:1], torch.zeros(1, 3, dtype=F64), k, w, kf)
    assert gain.item() >= w * (math.exp(-4 * kf) - math.exp(-9 * kf)) * 0.999


@SETTINGS
@given(
    seed=seeds,
    k=st.floats(0.5, 10.0),
    w=st.floats(0.0, 0.6),
    m=st.floats(0.01, 0.4),
    km=st.floats(0.2, 3.0),
)
def test_reach_mid_term_is_the_weighted_sum_and_pays_for_approach_in_the_middle_band(seed, k, w, m, km):
    rng = np.random.default_rng(seed)
    c = torch.as_tensor(rng.normal(0.0, 1.0, (32, 3)))
    hand = c + torch.as_tensor(rng.normal(0.0, 1.5, (32, 3)))
    r = reach_reward(hand, c, k, w, 0.05, m, km)
    assert ((r > 0) & (r <= 1 + 1e-12)).all()
    assert torch.allclose(reach_reward(c, c, k, w, 0.05, m, km), torch.ones(32, dtype=F64))
    d2 = ((hand - c) ** 2).sum(-1)
    expected = (1 - w - m) * torch.exp(-k * d2) + m * torch.exp(-km * d2) + w * torch.exp(-0.05 * d2)
    assert torch.allclose(r, expected)
    assert torch.equal(reach_reward(hand, c, k, w, 0.05, 0.0, km), reach_reward(hand, c, k, w, 0.05))  # m = 0
    assert (reach_reward(c + 2 * (hand - c), c, k, w, 0.05, m, km) <= r + 1e-12).all()  # monotone
    # from 1 m to 0.5 m the middle term alone pays m (exp(-km/4) - exp(-km))
    at = torch.tensor([[1.0, 0.0, 0.0], [0.5, 0.0, 0.0]], dtype=F64)
    z = torch.zeros(1, 3, dtype=F64)
    gain = reach_reward(at[1:], z, k, w, 0.05, m, km) - reach_reward(at[:1], z, k, w, 0.05, m, km)
    assert gain.item() >= m * (math.exp(-km / 4) - math.exp(-km)) * 0.999


def test_reach_weights_over_one_are_refused():
    with pytest.raises(ValueError, match="far_weight \\+ mid_weight"):
        reach_reward(torch.zeros(1, 3), torch.ones(1, 3), 5.0, 0.7, 0.05, 0.4)
    with pytest.raises(ValueError, match="far_weight \\+ mid_weight"):
        ReachParams(far_weight=0.7, mid_weight=0.4)
    assert ReachParams(far_weight=0.7, mid_weight=0.3).mid_weight == 0.3  # = 1 is allowed


def test_reach_mid_weight_reaches_the_task_reward(amp):
    s = standing(1, amp.num_bodies)
    task = make_reach(ReachParams(far_weight=0.3, mid_weight=0.4, mid_coefficient=2.0), skeleton=amp, num_envs=1)
    task.reset(all_ids(1), s)
    task.target = s.body_pos[:, task.body_index] + torch.tensor([1.0, 0.0, 0.0], dtype=F64)
    expected = 0.3 * math.exp(-5.0) + 0.4 * math.exp(-2.0) + 0.3 * math.exp(-0.05)
    assert task.reward(s, None).item() == pytest.approx(expected)


def test_reach_far_weight_reaches_the_task_reward(amp):
    s = standing(1, amp.num_bodies)
    task = make_reach(ReachParams(far_weight=0.5, far_coefficient=0.5), skeleton=amp, num_envs=1)
    task.reset(all_ids(1), s)
    task.target = s.body_pos[:, task.body_index] + torch.tensor([2.0, 0.0, 0.0], dtype=F64)
    assert task.reward(s, None).item() == pytest.approx(0.5 * math.exp(-5.0 * 4) + 0.5 * math.exp(-0.5 * 4))


def test_reach_coefficient_switch_and_hand(amp, smpl):
    assert ReachParams().coefficient == 5.0  # [P]
    task = make_reach(ReachParams(coefficient=4.0), skeleton=amp, num_envs=1)
    assert amp.body_names[task.body_index] == "right_hand"
    assert smpl.body_names[make_reach(ReachParams(), skeleton=smpl, num_envs=1).body_index] == "R_Hand"
    s = standing(1, amp.num_bodies)
    task.reset(all_ids(1), s)
    task.target = s.body_pos[:, task.body_index] + torch.tensor([0.5, 0.0, 0.0], dtype=F64)
    assert task.reward(s, None).item() == pytest.approx(math.exp(-4.0 * 0.25))
    assert task.max_reward == 1.0


def test_reach_sampling_box_and_reproducibility(amp):
    s = standing(64, amp.num_bodies, xy=(3.0, -2.0))
    p = ReachParams(height_range=(0.2, 2.0), seed=7)
    a, b = (
        make_reach(p, skeleton=amp, num_envs=64),
        make_reach(p, skeleton=amp, num_envs=64),
    )
    a.reset(all_ids(64), s)
    b.reset(all_ids(64), s)
    assert torch.equal(a.target, b.target)
    assert torch.equal(a.change_at, b.change_at)
    rel = a.target[:, :2] - torch.tensor([3.0, -2.0], dtype=F64)
    assert (rel.abs() <= 1.0).all() and rel.abs().max() > 0.5
    assert ((a.target[:, 2] >= 0.2) & (a.target[:, 2] <= 2.0)).all()
    assert ((a.change_at >= 50) & (a.change_at < 100)).all()
    c = make_reach(p, skeleton=amp, num_envs=64, seed=8)  # the factory seed overrides the params'
    c.reset(all_ids(64), s)
    assert not torch.equal(a.target, c.target)
    # a partial reset with the full-batch state only touches those envs
    before = a.target.clone()
    a.reset(torch.tensor([5, 9]), s)
    changed = (a.target != before).any(-1)
    assert changed[[5, 9]].all() and changed.sum() == 2


@SETTINGS
@given(
    seed=seeds,
    yaw=st.floats(-math.pi, math.pi),
    shift=st.tuples(*[st.floats(-20.0, 20.0)] * 3),
)
def test_reach_observation_is_heading_invariant(amp, seed, yaw, shift):
    s = random_state(np.random.default_rng(seed), 5, amp.num_bodies)
    task = make_reach(ReachParams(seed=seed % 1000), skeleton=amp, num_envs=5)
    task.reset(all_ids(5), s)
    obs = task.observe(s)
    r = task.reward(s, None)
    qz = quat_from_axis_angle(Z, torch.tensor(yaw, dtype=F64))
    sh = torch.tensor(shift, dtype=F64)
    task.target = quat_apply(qz.expand(5, 4), task.target) + sh
    s2 = yaw_world(s, yaw, sh)
    assert torch.allclose(task.observe(s2), obs, atol=1e-9)
    assert torch.allclose(task.reward(s2, None), r, atol=1e-9)


def test_reach_metrics_on_hand_made_states(amp):
    B = amp.num_bodies
    task = make_reach(ReachParams(change_steps=(3, 3), success_radius=0.1), skeleton=amp, num_envs=2)
    s = standing(2, B)
    task.reset(all_ids(2), s)
    h = task.body_index
    # env 0 reaches on its 2nd step; env 1 stays 0.5 m away
    task.target = torch.tensor([[0.3, 0.0, 1.0], [0.0, 0.5, 1.0]], dtype=F64)
    hand_x = [0.0, 0.25, 0.3]
    for x in hand_x:
        bp = s.body_pos.clone()
        bp[0, h] = torch.tensor([x, 0.0, 1.0], dtype=F64)
        st_ = replace(s, body_pos=bp)
        task.reward(st_, None)
        task.step(st_)  # the 3rd step finishes both goals and samples new ones
    m = task.metrics()
    assert m["steps"] == 6
    assert m["distance"] == pytest.approx((0.3 + 0.05 + 0.0 + 3 * 0.5) / 6)
    assert m["goals"] == 2
    assert m["success_rate"] == pytest.approx(0.5)
    assert m["time_to_reach"] == pytest.approx(2 / 30)
    assert m["final_distance"] == pytest.approx((0.0 + 0.5) / 2)
    assert m["closest_distance"] == pytest.approx((0.0 + 0.5) / 2)
    assert task.metrics() == {}
    # the closest approach of a goal that comes near and moves off again (reach.py's min_distance)
    task.target = torch.tensor([[0.3, 0.0, 1.0], [0.0, 0.5, 1.0]], dtype=F64)
    for x in [0.0, 0.2, 0.0]:  # env 0: 0.3, 0.1, 0.3 m; env 1: 0.5 m
        bp = s.body_pos.clone()
        bp[0, h] = torch.tensor([x, 0.0, 1.0], dtype=F64)
        st_ = replace(s, body_pos=bp)
        task.reward(st_, None)
        task.step(st_)
    m = task.metrics()
    assert m["final_distance"] == pytest.approx((0.3 + 0.5) / 2) and m["closest_distance"] == pytest.approx((0.1 + 0.5) / 2)
    # a reset finishes a goal too (here unreached after one step)
    task.reward(s, None)
    task.step(s)
    task.reset(torch.tensor([1]), s)
    m = task.metrics()
    assert m["goals"] == 1 and m["success_rate"] == 0.0 and "time_to_reach" not in m


def test_fall_termination(amp):
    B = amp.num_bodies
    task = make_reach(ReachParams(), skeleton=amp, num_envs=3)
    s = standing(3, B)
    contact = torch.zeros(3, B, dtype=torch.bool)
    contact[0, amp.body_index("right_foot")] = True
    contact[1, amp.body_index("head")] = True
    root = s.root_pos.clone()
    root[2, 2] = 0.1
    s = replace(s, body_contact=contact, root_pos=root)
    assert task.terminated(s).tolist() == [False, True, True]
    off = make_reach(ReachParams(termination={"early_termination": False}), skeleton=amp, num_envs=3)
    assert not off.terminated(s).any()


def test_a_goal_task_resumes_from_a_state_saved_before_closest_distance_existed(amp):
    """Runs saved before ``min_distance`` (the closest approach per goal) was added resume with it
    started afresh; any other missing or extra tensor is still refused."""
    a = make_reach(ReachParams(), skeleton=amp, num_envs=3)
    s = standing(3, amp.num_bodies)
    a.reset(all_ids(3), s)
    a.reward(s, None)
    state = a.state_dict()
    old = {"tensors": {k: v for k, v in state["tensors"].items() if k != "min_distance"}, "generator": state["generator"]}
    b = make_reach(ReachParams(), skeleton=amp, num_envs=3)
    b.load_state_dict(old)
    assert torch.equal(b.target, a.target) and torch.isinf(b.min_distance).all()
    b.load_state_dict(state)
    assert torch.equal(b.min_distance, a.min_distance) and torch.isfinite(b.min_distance).all()
    broken = {"tensors": {k: v for k, v in state["tensors"].items() if k != "target"}, "generator": state["generator"]}
    with pytest.raises(ValueError, match="another task"):
        b.load_state_dict(broken)
