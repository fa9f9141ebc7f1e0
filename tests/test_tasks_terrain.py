"""Tests of the downstream task ``terrain`` (``mocap_tasks``), moved from ``test_tasks_more.py``.

Pinned: reward bounds and maxima (hypothesis), trajectory sampling and interpolation, heading
invariance of the goal observation and height map (hypothesis), start state, reset, termination and
metrics on hand-made states, the obstacle terrain kind and the MuJoCo height-field overrides."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from test_tasks import random_state, standing, yaw_world
from test_tasks_more import F64, SETTINGS, rot_z, seeds, shifts, yaws
from test_tasks_more import punch_lib  # noqa: F401  (fixture)

torch.set_num_threads(1)

from mocap_tasks.terrain import (
    TerrainTaskParams,
    make_terrain,
    sample_trajectories,
    terrain_reward,
    trajectory_at,
)


# ----------------------------------------------------------------------------------- terrain
@SETTINGS
@given(
    d=st.floats(0.0, 5.0),  # exp(-5 * 5.5^2) is still a normal float64: r > 0 holds numerically
    scale=st.floats(0.1, 5.0),
    form=st.sampled_from(["paper", "code"]),
    energy=st.floats(-50.0, 0.0),
)
def test_terrain_reward_bounded_maximal_at_the_trajectory_and_monotone(d, scale, form, energy):
    root = torch.tensor([[0.0, 0.0], [0.0, 0.0]], dtype=F64)
    target = torch.tensor([[d, 0.0], [d + 0.5, 0.0]], dtype=F64)
    r = terrain_reward(root, target, pos_scale=scale, distance=form)
    assert torch.all((r > 0) & (r <= 1)) and r[1] < r[0]
    expect = math.exp(-scale * (d if form == "paper" else d * d))
    assert float(r[0]) == pytest.approx(expect, rel=1e-12, abs=1e-300)
    assert float(terrain_reward(root[:1], root[:1], pos_scale=scale, distance=form)[0]) == 1.0
    with_energy = terrain_reward(root, target, torch.full((2,), energy, dtype=F64), pos_scale=scale, distance=form)
    assert torch.allclose(with_energy, r + energy)


@SETTINGS
@given(seed=seeds, lo=st.floats(0.0, 2.0), width=st.floats(0.0, 2.0), accel=st.floats(0.0, 3.0), dtheta=st.floats(0.0, 3.0))
def test_trajectories_respect_speed_acceleration_and_turn_limits(seed, lo, width, accel, dtheta):
    g = torch.Generator().manual_seed(seed)
    k, v, seg = 4, 21, 0.1
    start = torch.randn(k, 2, generator=g, dtype=F64)
    verts = sample_trajectories(
        start,
        torch.rand(k, v - 1, 4, generator=g, dtype=F64),
        num_verts=v,
        seg_dt=seg,
        speed_range=(lo, lo + width),
        accel_max=accel,
        dtheta_max=dtheta,
        sharp_turn_prob=0.0,
    )
    assert verts.shape == (k, v, 2) and torch.equal(verts[:, 0], start)
    step = verts[:, 1:] - verts[:, :-1]
    speed = torch.linalg.vector_norm(step, dim=-1) / seg
    assert torch.all(speed >= lo - 1e-9) and torch.all(speed <= lo + width + 1e-9)
    assert torch.all((speed[:, 1:] - speed[:, :-1]).abs() <= accel * seg + 1e-9)
    moving = (speed[:, 1:] > 1e-6) & (speed[:, :-1] > 1e-6)
    a = torch.atan2(step[..., 1], step[..., 0])
    turn = torch.atan2(torch.sin(a[:, 1:] - a[:, :-1]), torch.cos(a[:, 1:] - a[:, :-1])).abs()
    assert torch.all(turn[moving] <= dtheta * seg + 1e-6)


def test_trajectory_sharp_turns_and_interpolation():
    u = torch.full((1, 4, 4), 0.5, dtype=F64)
    u[0, 2, 1] = 0.0  # a sharp turn at segment 2 ...
    u[0, 2, 2] = 1.0  # ... by +pi
    verts = sample_trajectories(
        torch.zeros(1, 2, dtype=F64), u, num_verts=5, seg_dt=1.0, speed_range=(1.0, 1.0), accel_max=0.0, dtheta_max=0.0, sharp_turn_prob=0.5
    )
    # heading 0 (u = 0.5 -> 0), no turn, then a U-turn: +x, +x, back -x, -x
    assert torch.allclose(verts[0], torch.tensor([[0.0, 0], [1, 0], [2, 0], [1, 0], [0, 0]], dtype=F64), atol=1e-12)
    t = torch.tensor([[0.0, 0.5, 1.0, 2.5, 10.0, -1.0]], dtype=F64)
    pos = trajectory_at(verts, 1.0, t)
    assert torch.allclose(pos[0, :, 0], torch.tensor([0.0, 0.5, 1.0, 1.5, 0.0, 0.0], dtype=F64))


class TerrainSim:
    """A simulator with an analytic height field ``h(x, y)`` in a world turned by ``yaw`` and moved by ``shift``."""

    dt = 1.0 / 30.0
    ground_contact = None  # no ground-only contacts: the task falls back to SimState.body_contact

    def __init__(self, yaw: float = 0.0, shift=(0.0, 0.0)):
        self.yaw, self.shift = yaw, torch.tensor(shift, dtype=F64)

    def height_at(self, xy):
        p = xy.to(F64) - self.shift
        c, s = math.cos(-self.yaw), math.sin(-self.yaw)
        x, y = c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]
        return 0.3 * torch.sin(1.7 * x) * torch.cos(0.9 * y) + 0.1 * x


@SETTINGS
@given(seed=seeds, yaw=yaws, shift=shifts)
def test_terrain_observation_is_heading_invariant(amp, seed, yaw, shift):
    p = TerrainTaskParams(terrain={"kind": "flat", "size": 50.0}, map_shape=(5, 7), num_samples=4)
    tasks = [make_terrain(p, skeleton=amp, num_envs=3, seed=seed) for _ in range(2)]
    state = random_state(np.random.default_rng(seed % 2**32), 3, amp.num_bodies)
    sh = torch.tensor([shift[0], shift[1], 0.0], dtype=F64)
    moved = yaw_world(state, yaw, sh)
    g = torch.Generator().manual_seed(seed)
    verts = torch.randn(3, p.num_verts, 2, generator=g, dtype=F64) * 3
    verts3 = torch.cat((verts, torch.zeros_like(verts[..., :1])), -1)
    tasks[0].attach(TerrainSim())
    tasks[1].attach(TerrainSim(yaw, shift))
    tasks[0].verts = verts
    tasks[1].verts = (rot_z(yaw, verts3) + sh)[..., :2]
    for t in tasks:
        t.progress[:] = torch.tensor([0, 17, 250])
    a, b = tasks[0].observe(state), tasks[1].observe(moved)
    assert a.shape == (3, 2 * 4 + 35)
    assert torch.allclose(a, b, atol=1e-7)


def test_terrain_height_map_is_relative_to_the_root_and_turns_with_the_heading(amp):
    p = TerrainTaskParams(terrain={"kind": "flat", "size": 50.0}, map_shape=(3, 3), map_size=2.0, num_samples=1)
    task = make_terrain(p, skeleton=amp, num_envs=1)

    class Ramp:
        dt = 1.0 / 30.0

        def height_at(self, xy):
            return 0.5 * xy[..., 0]

    task.attach(Ramp())
    state = standing(1, amp.num_bodies, yaw=math.pi / 2)  # facing +y: the map's first axis is world +y
    hmap = task.observe(state)[0, 2:].reshape(3, 3)
    # rows (forward = +y) see no slope, columns (left = -x) go downhill by 0.5 per metre
    assert torch.allclose(hmap[:, 0], hmap[:, 0].mean().expand(3)) and torch.allclose(hmap[0], torch.tensor([0.5, 0.0, -0.5], dtype=F64) - 1.0)


def test_terrain_start_state_reset_termination_and_metrics(amp, punch_lib):  # noqa: F811
    p = TerrainTaskParams(terrain={"kind": "flat", "size": 5.0}, spawn_radius=0.3, speed_range=(1.0, 1.0), fail_distance=2.0, energy_weight=0.0)
    task = make_terrain(p, skeleton=amp, num_envs=2, seed=3)
    frames = punch_lib.frames(torch.tensor([0, 1]), torch.tensor([0.5, 0.9]))
    moved = task.start_state(torch.arange(2), frames)
    assert torch.all(moved.root_pos[:, :2].abs() <= 0.3)
    assert torch.allclose(moved.body_pos - moved.root_pos[:, None], frames.body_pos - frames.root_pos[:, None])
    assert torch.equal(moved.root_pos[:, 2], frames.root_pos[:, 2]) and torch.equal(moved.clip_ids, frames.clip_ids)
    state = standing(2, amp.num_bodies)
    task.reset(torch.arange(2), state)
    assert torch.equal(task.verts[:, 0], state.root_pos[:, :2])
    assert torch.all(task.verts.abs() <= 4.0 + 1e-12)  # clamped 1 m inside the 5-m square
    # env 0 stays on the trajectory's start; env 1 is 3 m away and on the ground (falls)
    task.verts[:] = 0.0
    s = replace(state, root_pos=state.root_pos.clone(), body_pos=state.body_pos.clone(), body_contact=torch.zeros(2, amp.num_bodies, dtype=torch.bool))
    s.root_pos[1] = torch.tensor([3.0, 0.0, 0.05], dtype=F64)
    s.body_pos[1] = s.root_pos[1]
    r = task.reward(s, None)
    assert float(r[0]) == 1.0 and float(r[1]) == pytest.approx(math.exp(-2 * 3.0))
    done = task.terminated(s)
    assert done.tolist() == [False, True]
    task.step(s)
    task.reset(torch.tensor([1]), state)
    m = task.metrics()
    assert m["traj_error"] == pytest.approx(1.5) and m["steps"] == 2
    assert m["episodes"] == 1 and m["fall_rate"] == 1.0 and m["far_rate"] == 0.0 and m["episode_traj_error"] == pytest.approx(3.0)


def test_obstacle_terrain_kind():
    from mocap_sim_mujoco.terrain import Terrain, TerrainParams

    t = Terrain(TerrainParams(kind="obstacles", size=5.0, resolution=0.1, obstacle_count=30, obstacle_height=(0.1, 0.2), seed=1))
    h = t.heights
    assert h.min() == 0.0 and 0.1 <= h.max() <= 0.2 + 1e-12
    assert set(np.unique(h[h > 0]).round(9)) <= set(np.unique(h).round(9)) and (h > 0).mean() > 0.02
    spawn = t.height_at(torch.tensor([[0.0, 0.0], [0.9, -0.9]], dtype=F64))
    assert torch.all(spawn == 0)
    again = Terrain(TerrainParams(kind="obstacles", size=5.0, resolution=0.1, obstacle_count=30, obstacle_height=(0.1, 0.2), seed=1))
    assert np.array_equal(again.heights, h)


def test_terrain_sim_overrides_build_a_mujoco_height_field(amp):
    from mocap_sim_mujoco.simulator import MujocoParams

    task = make_terrain(TerrainTaskParams(terrain={"kind": "obstacles", "size": 6.0}), skeleton=amp, num_envs=1)
    params = MujocoParams.model_validate({**MujocoParams().model_dump(), **task.sim_overrides})
    assert params.terrain is not None and params.terrain.kind == "obstacles" and params.terrain.size == 6.0
