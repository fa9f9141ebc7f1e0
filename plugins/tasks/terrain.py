"""The ``terrain`` task (PULSE Sec. 4.3 / App. C.4, following PACER): follow a 2-D
trajectory across procedurally generated terrain.

Simulator. The task asks for a height-field ground through :attr:`TerrainTask.sim_overrides`
(``{"terrain": TerrainParams}``, :mod:`mocap_sim_mujoco.terrain`: kinds ``flat``, ``rough`` (uneven
ground), ``stairs``, ``slopes``, ``obstacles``; one kind per simulator, the spawn square around the
origin is flat). [P] trains on stairs, slopes, uneven surfaces and obstacles at once; [CODE] (PACER)
uses a curriculum of 5 levels x 20 terrains of 20 x 20 m: not reproduced, a comparison runs one
spec per kind (or a ``matrix:`` over ``task.params.terrain.kind``). :meth:`attach` keeps the
simulator for its ``height_at`` query (a simulator without one is treated as flat ground z = 0).

Start. :meth:`start_state` moves each start frame drawn by the env horizontally so that the root
stands at a uniform point of the square of half side ``spawn_radius`` around the origin (inside
the terrain's flat spawn square); heading, pose and velocities are kept.

Trajectory ([CODE] PACER/ASE ``TrajGenerator``; [P] "speed in [0, 3] m/s, acceleration in [0, 2]
m/s^2"): ``num_verts`` vertices evenly spaced over the episode (``episode_steps`` control steps),
starting at the root's xy. Per segment the heading turns by ``U[-1, 1] dtheta_max dt_v`` or, with
probability ``sharp_turn_prob``, by ``U[-pi, pi]`` (the first segment: a uniform heading); the speed
starts at ``U[speed_range]`` and changes by ``U[-1, 1] accel_max dt_v`` per segment, clipped to
``speed_range``. Vertices are clamped to ``bounds_margin`` inside the terrain square (there is no
ground outside it). ``tau(t)`` is the piecewise-linear trajectory, constant after its end.

Observation (``2 num_samples + H W``): the trajectory at ``t + k sample_spacing``, ``k = 0 ..
num_samples - 1`` ([CODE] 10 samples 0.5 s apart), relative to the root in its heading frame, then
the local height map: terrain heights minus the root height on an ``H x W`` grid (``map_shape``)
spanning ``map_size`` metres, centred on the root and turned with its heading ([P] 32 x 32 over
2 m x 2 m; [P] has 3 channels, the other two (PACER: other humanoids) do not exist here, so 1).

Reward ([P])::

    r = exp(-pos_scale * e) + energy,   e = ||p_root,xy - tau(t)||  ([P])  or  ||.||^2  ([CODE] PACER)

(``distance`` switch; ``pos_scale`` 2) and ``energy = -energy_weight sum_j (tau_j qdot_j)^2`` ([P]
0.0005, squared) or ``-energy_weight sum_j |tau_j qdot_j|`` ([CODE] PHC power reward, not squared, 0 for
the first 3 steps; the default, because the squared form measured about -1e2 per step on a falling
amp humanoid; ``energy_form``), :func:`mocap.imitation_rewards.energy_penalty`. The tracking term is in (0, 1] and the
energy term <= 0: ``max_reward`` 1.

Termination: a fall (:class:`~mocap_tasks.common.FallParams`; ground contacts include the height
field) or, with ``fail_distance``, the root farther than that from ``tau(t)`` ([DEFAULT] 4 m, as
ASE's trajectory task).

Hook: ``step(state)`` advances the step counters (the trajectory time is ``progress * dt``).

Metrics (since the last :meth:`TerrainTask.metrics`):

* ``traj_error``: mean ``||p_root,xy - tau(t)||`` over the control steps, m;
* ``reward``, ``energy``: means over the control steps; ``steps``: their number (a sum);
* ``fall_rate``: fraction of the finished episodes (with at least one step) that ended in a fall
  (:meth:`terminated` saw one); ``far_rate``: ... that ended by leaving the trajectory;
* ``episode_traj_error``: mean over those episodes of their mean error, m;
* ``episodes``: number of finished episodes (a sum). Episode metrics are absent when none finished.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Literal

import torch
from mocap.interfaces import Task
from mocap.observations import world_to_heading
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, SimState
from mocap.imitation_rewards import energy_penalty
from mocap_sim_mujoco.terrain import height_map
from mocap_tasks.common import TaskBase, root_heading, rows
from torch import Tensor
from mocap_tasks.task_params import TerrainTaskParams

__all__ = ["TerrainTask", "TerrainTaskParams", "make_terrain", "sample_trajectories", "terrain_reward", "trajectory_at"]


def sample_trajectories(
    start_xy: Tensor,
    u: Tensor,
    *,
    num_verts: int,
    seg_dt: float,
    speed_range: tuple[float, float],
    accel_max: float,
    dtheta_max: float,
    sharp_turn_prob: float,
) -> Tensor:
    """(K, num_verts, 2) trajectories from ``start_xy`` (K, 2) and uniform noise ``u`` (K, num_verts - 1, 4)
    (module docstring): per segment a heading change and a speed change, then the cumulative sum."""
    k, s = start_xy.shape[0], num_verts - 1
    u = u.to(start_xy)
    dtheta = (2.0 * u[..., 0] - 1.0) * dtheta_max * seg_dt
    sharp = u[..., 1] < sharp_turn_prob
    dtheta = torch.where(sharp, math.pi * (2.0 * u[..., 2] - 1.0), dtheta)
    dtheta[:, 0] = math.pi * (2.0 * u[:, 0, 2] - 1.0)  # the initial heading
    lo, hi = speed_range
    speed = torch.empty(k, s, dtype=start_xy.dtype, device=start_xy.device)
    speed[:, 0] = lo + (hi - lo) * u[:, 0, 3]
    dspeed = (2.0 * u[..., 3] - 1.0) * accel_max * seg_dt
    for i in range(1, s):
        speed[:, i] = (speed[:, i - 1] + dspeed[:, i]).clamp(lo, hi)
    heading = torch.cumsum(dtheta, dim=-1)
    step = torch.stack((torch.cos(heading), torch.sin(heading)), -1) * (speed * seg_dt)[..., None]
    verts = torch.cat((start_xy[:, None], start_xy[:, None] + torch.cumsum(step, dim=1)), dim=1)
    return verts


def trajectory_at(verts: Tensor, seg_dt: float, t: Tensor) -> Tensor:
    """(N, ..., 2) piecewise-linear position of trajectories ``verts`` (N, V, 2) at times ``t`` (N, ...), s;
    clamped to the first / last vertex outside ``[0, (V - 1) seg_dt]``."""
    n, v = verts.shape[:2]
    f = (t / seg_dt).clamp(0.0, v - 1.0)
    i0 = torch.floor(f).long().clamp(max=v - 2)
    a = (f - i0).unsqueeze(-1).to(verts)
    flat_i = i0.reshape(n, -1)
    p0 = torch.gather(verts, 1, flat_i[..., None].expand(-1, -1, 2)).reshape(*t.shape, 2)
    p1 = torch.gather(verts, 1, (flat_i + 1)[..., None].expand(-1, -1, 2)).reshape(*t.shape, 2)
    return p0 + a * (p1 - p0)


def terrain_reward(
    root_xy: Tensor,
    target_xy: Tensor,
    energy: Tensor | None = None,
    *,
    pos_scale: float = 2.0,
    distance: Literal["paper", "code"] = "paper",
) -> Tensor:
    """(N,) ``exp(-pos_scale e) + energy`` with ``e = ||root_xy - target_xy||`` ('paper') or its square ('code')."""
    d = torch.linalg.vector_norm(root_xy - target_xy, dim=-1)
    e = d if distance == "paper" else d * d
    r = torch.exp(-pos_scale * e)
    return r if energy is None else r + energy.to(r)


class TerrainTask(TaskBase, Task):
    """The ``terrain`` task (module docstring). Goals: :attr:`verts` (N, V, 2) world trajectories."""

    max_reward = 1.0

    def __init__(self, params: TerrainTaskParams, *, skeleton: Skeleton, num_envs: int, device: Any = "cpu", seed: int | None = None):
        self.params = p = params
        self._setup(p.termination, skeleton, num_envs, device, p.seed if seed is None else seed)
        self.sim_overrides = {"terrain": p.terrain.model_dump()}
        self.episode_steps = p.episode_steps
        self.goal_dim = 2 * p.num_samples + p.map_shape[0] * p.map_shape[1]
        N, dev, f64 = self.num_envs, self.device, torch.float64
        self.verts = torch.zeros(N, p.num_verts, 2, dtype=f64, device=dev)
        self.fell = torch.zeros(N, dtype=torch.bool, device=dev)
        self.far = torch.zeros(N, dtype=torch.bool, device=dev)
        self.err_sum = torch.zeros(N, dtype=f64, device=dev)
        self.err_count = torch.zeros(N, dtype=torch.long, device=dev)
        self._episode_stats = {"episodes": 0.0, "falls": 0.0, "far": 0.0, "error": 0.0}

    @property
    def seg_dt(self) -> float:
        """Time between trajectory vertices, s (the episode spread over ``num_verts - 1`` segments)."""
        return self.params.episode_steps * self.dt / (self.params.num_verts - 1)

    # -------------------------------------------------------------------------- terrain
    def height_at(self, xy: Tensor) -> Tensor:
        """Ground height (...) at world ``xy`` (..., 2): the attached simulator's, else 0."""
        if self.sim is not None:
            return self.sim.height_at(xy).to(xy)
        return torch.zeros(xy.shape[:-1], dtype=xy.dtype, device=xy.device)

    def start_state(self, env_ids: Tensor, frames: HumanoidState) -> HumanoidState:
        """The start frames moved horizontally onto the spawn square (module docstring)."""
        k = frames.num_envs
        r = self.params.spawn_radius
        spawn = (2.0 * self._rand(k, 2) - 1.0) * r
        shift = torch.zeros(k, 3, dtype=frames.root_pos.dtype, device=frames.root_pos.device)
        shift[:, :2] = spawn.to(shift) - frames.root_pos[:, :2]
        return replace(frames, root_pos=frames.root_pos + shift, body_pos=frames.body_pos + shift[:, None])

    # ------------------------------------------------------------------------------ goals
    def _finish_episodes(self, ids: Tensor) -> None:
        ids = ids[self.err_count[ids] > 0]
        if ids.numel() == 0:
            return
        e = self._episode_stats
        e["episodes"] += float(ids.numel())
        e["falls"] += float(self.fell[ids].sum())
        e["far"] += float(self.far[ids].sum())
        e["error"] += float((self.err_sum[ids] / self.err_count[ids]).sum())

    def reset(self, env_ids: Tensor, state: SimState) -> None:
        ids = self._ids(env_ids)
        if ids.numel() == 0:
            return
        self._finish_episodes(ids)
        p = self.params
        r = rows(state, ids, self.num_envs)
        k = int(ids.numel())
        verts = sample_trajectories(
            r.root_pos[:, :2].detach().to(self.device, torch.float64),
            self._rand(k, p.num_verts - 1, 4),
            num_verts=p.num_verts,
            seg_dt=self.seg_dt,
            speed_range=p.speed_range,
            accel_max=p.accel_max,
            dtheta_max=p.dtheta_max,
            sharp_turn_prob=p.sharp_turn_prob,
        )
        lim = p.terrain.size - p.bounds_margin
        self.verts[ids] = verts.clamp(-lim, lim)
        self.progress[ids] = 0
        self.fell[ids] = False
        self.far[ids] = False
        self.err_sum[ids] = 0.0
        self.err_count[ids] = 0

    def step(self, state: SimState) -> None:
        """Advance the step counters (the trajectory time)."""
        self.progress += 1

    def target(self, offset_steps: int = 0) -> Tensor:
        """(N, 2) ``tau`` at ``(progress + offset_steps) dt``."""
        t = (self.progress + offset_steps).to(torch.float64) * self.dt
        return trajectory_at(self.verts, self.seg_dt, t)

    # ------------------------------------------------------------------------ observation
    def observe(self, state: SimState) -> Tensor:
        p = self.params
        t = self.progress.to(torch.float64)[:, None] * self.dt + p.sample_spacing * torch.arange(p.num_samples, dtype=torch.float64, device=self.device)
        samples = trajectory_at(self.verts, self.seg_dt, t).to(state.root_pos)  # (N, S, 2)
        rel = samples - state.root_pos[:, None, :2]
        rel3 = torch.cat((rel, torch.zeros_like(rel[..., :1])), -1)
        traj_obs = world_to_heading(state.root_rot, rel3)[..., :2].reshape(state.num_envs, -1)
        H, W = p.map_shape
        spacing = p.map_size / max(max(H, W) - 1, 1)
        heights = height_map(self.height_at, state.root_pos[:, :2], root_heading(state).to(state.root_pos), (H, W), spacing)
        hmap = (heights - state.root_pos[:, 2, None, None]).reshape(state.num_envs, -1)
        return torch.cat((traj_obs, hmap), -1)

    # ----------------------------------------------------------------------------- reward
    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        target = self.target(1).to(state.root_pos)  # the time of ``state``: one step after the counter
        energy = energy_penalty(
            state.dof_force.to(state.dof_vel) if state.dof_force.numel() else state.dof_force,
            state.dof_vel,
            form=p.energy_form,
            coef=p.energy_weight,
            progress=(self.progress + 1).to(state.dof_vel.device),
        )
        root = state.root_pos[:, :2]
        r = terrain_reward(root, target, energy, pos_scale=p.pos_scale, distance=p.distance)
        err = torch.linalg.vector_norm(root - target, dim=-1)
        self.err_sum += err.detach().to(self.err_sum)
        self.err_count += 1
        s = self._sums
        s.add("traj_error", err)
        s.add("energy", energy)
        s.add("reward", r)
        s.add("steps", float(r.numel()), count=1)
        return r

    def terminated(self, state: SimState) -> Tensor:
        fell = self._fallen(state)
        out = fell
        if self.params.fail_distance is not None:
            err = torch.linalg.vector_norm(state.root_pos[:, :2] - self.target(1).to(state.root_pos), dim=-1)
            far = err > self.params.fail_distance
            self.far |= far.to(self.device) & ~fell.to(self.device)
            out = out | far.to(out.device)
        self.fell |= fell.to(self.device)
        return out

    def metrics(self) -> dict[str, float]:
        out = self._sums.pop(totals=("steps",))
        e = self._episode_stats
        if e["episodes"] > 0:
            out["episodes"] = e["episodes"]
            out["fall_rate"] = e["falls"] / e["episodes"]
            out["far_rate"] = e["far"] / e["episodes"]
            out["episode_traj_error"] = e["error"] / e["episodes"]
        self._episode_stats = {k: 0.0 for k in e}
        return out


def make_terrain(params: TerrainTaskParams, *, skeleton: Skeleton, num_envs: int, device: Any = "cpu", seed: int | None = None, **_: Any) -> TerrainTask:
    """Registry factory of the ``terrain`` task."""
    return TerrainTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed)
