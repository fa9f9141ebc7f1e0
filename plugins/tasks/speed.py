"""The ``speed`` task (PULSE Sec. 4.3 / App. C, following ASE): move the root at a target speed along a
target direction.

Goal. A horizontal unit direction ``d`` (world frame) and a target speed ``v*``:

* ``v*`` ~ U[``speed_range``] (paper and code: U[0, 5] m/s), resampled after U[``change_steps``) control
  steps ([CODE] ``speedChangeSteps`` U[100, 200); the paper does not say);
* ``d`` by ``direction``: ``"initial_heading"`` (default) the root's facing at the episode start,
  ``"world_x"`` world +x, ``"random"`` uniform in angle, resampled with the speed. [CODE] uses world +x
  *and* rotates every initial state to face +x (``_sample_ref_state``, "ZL Hack"), so at the start
  the target direction is the facing direction: ``"initial_heading"`` is that without touching
  the initial states; ``"world_x"`` is the code literally (the env must then face +x at reset for
  the same task).

Observation (3): ``[h^-1 d (x, y) | v*]`` with ``h`` the root's heading (code ``compute_speed_observations``).

Reward ([CODE] ``compute_speed_reward``, ASE)::

    r = exp(-scale * ((v* - v . d)^2 + tangent_weight * (v . d_perp)^2))    in (0, 1]

with ``v`` the horizontal root velocity (``velocity``: the state's ``root_lin_vel`` [P] "root
velocity", or [CODE] the finite difference of the root position over the control step), ``d_perp``
``d`` turned by +90 deg; ``scale`` 0.25, ``tangent_weight`` 0.1. Its maximum 1 is reached exactly at
``v = v* d``. The paper prints ``r = abs(v_t - v^0_t)``, which grows with the error (a typo, or a
cost); it is not offered.

Termination: a fall (:class:`~mocap_tasks.common.FallParams`). No time limit (the env's).

Hook: ``step(state)`` (called by the env once per control step after the reward) advances the
step counters, resamples the goals whose time is up, and stores the root position for the
finite-difference velocity. Without it the goal never changes.

Metrics (over the control steps whose reward was computed since the last :meth:`SpeedTask.metrics`):

* ``speed_error``: mean ``|v* - v . d|``, m/s (error along the target direction);
* ``tangent_speed``: mean ``|v . d_perp|``, m/s (drift across it);
* ``velocity_error``: mean ``||v - v* d||``, m/s;
* ``heading_error``: mean unsigned angle between the root's facing (heading) and ``d``, rad;
* ``reward``: mean reward; ``steps``: number of env steps counted (a sum).
"""

from __future__ import annotations

import math
from typing import Any

import torch
from mocap.interfaces import Task
from mocap.observations import world_to_heading
from mocap.skeleton import Skeleton
from mocap.state import SimState
from mocap_tasks.common import (
    TaskBase,
    angle_between_2d,
    root_heading,
    rows,
)
from torch import Tensor
from mocap_tasks.task_params import SpeedParams

__all__ = ["SpeedParams", "SpeedTask", "make_speed", "speed_reward"]


def speed_reward(
    v_xy: Tensor,
    direction: Tensor,
    target_speed: Tensor,
    scale: float = 0.25,
    tangent_weight: float = 0.1,
) -> Tensor:
    """(N,) ``exp(-scale ((v* - v.d)^2 + w (v.d_perp)^2))`` for velocities ``v_xy`` (N, 2), unit ``direction`` (N, 2)."""
    along = (v_xy * direction).sum(-1)
    perp = torch.stack((-direction[:, 1], direction[:, 0]), dim=-1)
    tangent = (v_xy * perp).sum(-1)
    err = target_speed - along
    return torch.exp(-scale * (err * err + tangent_weight * tangent * tangent))


class SpeedTask(TaskBase, Task):
    """The ``speed`` task (module docstring). Goals: :attr:`target_dir` (N, 2) world unit vectors and
    :attr:`target_speed` (N,) m/s."""

    goal_dim = 3
    max_reward = 1.0

    def __init__(
        self,
        params: SpeedParams,
        *,
        skeleton: Skeleton,
        num_envs: int,
        device: Any = "cpu",
        seed: int | None = None,
    ):
        self.params = params
        self._setup(
            params.termination,
            skeleton,
            num_envs,
            device,
            params.seed if seed is None else seed,
            params.start,
        )
        self.sim_overrides = {}
        N, dev = self.num_envs, self.device
        self.target_dir = torch.zeros(N, 2, dtype=torch.float64, device=dev)
        self.target_dir[:, 0] = 1.0
        self.target_speed = torch.zeros(N, dtype=torch.float64, device=dev)
        self.change_at = torch.full((N,), params.change_steps[0], dtype=torch.long, device=dev)
        self.prev_root_pos = torch.zeros(N, 3, dtype=torch.float64, device=dev)

    # ------------------------------------------------------------------------------ goals
    def _sample(self, ids: Tensor, state: SimState | None, new_direction: bool) -> None:
        p = self.params
        k = int(ids.numel())
        lo, hi = p.speed_range
        self.target_speed[ids] = (lo + (hi - lo) * self._rand(k)).to(self.target_speed.dtype)
        self.change_at[ids] = self.progress[ids] + self._randint(p.change_steps[0], p.change_steps[1], k)
        if not new_direction:
            return
        if p.direction == "random":
            angle = 2.0 * math.pi * self._rand(k)
        elif p.direction == "world_x":
            angle = torch.zeros(k, dtype=torch.float64, device=self.device)
        else:
            assert state is not None
            angle = root_heading(state).to(self.device, torch.float64)
        self.target_dir[ids] = torch.stack((torch.cos(angle), torch.sin(angle)), dim=-1).to(self.target_dir.dtype)

    def reset(self, env_ids: Tensor, state: SimState) -> None:
        ids = self._ids(env_ids)
        if ids.numel() == 0:
            return
        r = rows(state, ids, self.num_envs)
        self.progress[ids] = 0
        self.prev_root_pos[ids] = r.root_pos.detach().to(self.device, self.prev_root_pos.dtype)
        self._sample(ids, r, new_direction=True)

    def step(self, state: SimState) -> None:
        """Advance counters, resample due goals, remember the root position (module docstring)."""
        self.progress += 1
        self.prev_root_pos = state.root_pos.detach().to(self.device, self.prev_root_pos.dtype).clone()
        due = (self.progress >= self.change_at).nonzero().flatten()
        if due.numel():
            self._sample(due, None, new_direction=self.params.direction == "random")

    # ------------------------------------------------------------------------ observation
    def observe(self, state: SimState) -> Tensor:
        d = self.target_dir.to(state.root_rot)
        d3 = torch.cat((d, torch.zeros_like(d[:, :1])), dim=-1)
        local = world_to_heading(state.root_rot, d3)[:, :2]
        return torch.cat((local, self.target_speed.to(d)[:, None]), dim=-1)

    def markers(self, env_id: int = 0) -> list[tuple[Any, tuple[float, ...], float]]:
        """For videos: a green sphere 1 m ahead of the root along the target direction, its size
        growing with the target speed."""
        root = self.prev_root_pos[env_id].detach().cpu().double()
        d = self.target_dir[env_id].detach().cpu().double()
        pos = torch.stack((root[0] + d[0], root[1] + d[1], root.new_tensor(0.1)))
        return [(pos.numpy(), (0.1, 0.8, 0.2, 1.0), 0.04 + 0.02 * float(self.target_speed[env_id]))]

    # ----------------------------------------------------------------------------- reward
    def root_velocity(self, state: SimState) -> Tensor:
        """(N, 2) horizontal root velocity used by the reward (``velocity`` switch)."""
        if self.params.velocity == "finite_difference":
            return ((state.root_pos - self.prev_root_pos.to(state.root_pos)) / self.dt)[:, :2]
        return state.root_lin_vel[:, :2]

    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        v = self.root_velocity(state)
        d = self.target_dir.to(v)
        v_star = self.target_speed.to(v)
        r = speed_reward(v, d, v_star, p.scale, p.tangent_weight)
        along = (v * d).sum(-1)
        tangent = v[:, 1] * d[:, 0] - v[:, 0] * d[:, 1]
        h = root_heading(state).to(v)
        facing = torch.stack((torch.cos(h), torch.sin(h)), dim=-1)
        s = self._sums
        s.add("speed_error", (v_star - along).abs())
        s.add("tangent_speed", tangent.abs())
        s.add("velocity_error", torch.linalg.vector_norm(v - v_star[:, None] * d, dim=-1))
        s.add("heading_error", angle_between_2d(facing, d))
        s.add("reward", r)
        s.add("steps", float(r.numel()), count=1)
        return r

    def terminated(self, state: SimState) -> Tensor:
        return self._fallen(state)

    def metrics(self) -> dict[str, float]:
        return self._sums.pop(totals=("steps",))


def make_speed(
    params: SpeedParams,
    *,
    skeleton: Skeleton,
    num_envs: int,
    device: Any = "cpu",
    seed: int | None = None,
    **_: Any,
) -> SpeedTask:
    """Registry factory of the ``speed`` task."""
    return SpeedTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed)
