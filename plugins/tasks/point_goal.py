"""The ``point_goal`` task (hybrid-RVQ paper Sec. 6.3.3 / App. C.3, Eqs. 15-16): walk to a
point on the ground.

Goal. A 2-D target ``t`` (world xy) drawn uniformly in the disc of radius ``radius`` ([P] 10 m)
around the root's xy at the episode start ([P] "within 10 m of the agent's initial position"), and
redrawn (around the same start point) every ``change_steps`` control steps ([P] every 4 s = 120
steps). The episode lasts ``episode_steps`` ([P] at most 8 s = 240 steps, so one target change).

Observation (2): ``h^-1 (p_xy - t_xy)``, the agent minus the target ([P] ``g = p_xy - t_xy``; the
paper does not give the frame: [DEFAULT] the root's heading frame, :mod:`mocap_tasks.common`).

Reward ([P] Eq. 16)::

    r = w_pos r_pos + w_speed r_speed,   r_pos = exp(-pos_scale ||p_xy - t_xy||^2),
    r_speed = exp(-max(0, u - <v_xy, d>)^2)

with ``w_pos, w_speed = 0.7, 0.3``, ``pos_scale`` 0.5, ``u`` 1 m/s, ``v_xy`` the root's ground
velocity and ``d`` a unit direction (``direction`` switch): ``"toward_target"`` (default) ``d = (t -
p) / ||t - p||``; ``"paper"`` ``d = (p - t) / ||p - t||`` as printed, which points *away* from the
target and rewards walking away (a sign slip in Eq. 16; the correction is ours). "Once the agent
arrives at the goal, we give the maximum value for the reward": ``r = 1`` within ``arrive_radius``
([DEFAULT] 0.5 m, unspecified in the paper). ``r`` is in (0, 1]: ``max_reward`` 1.

Termination (``termination``): ``"paper"`` the head lower than ``head_height`` ([P] 0.5 m above the
ground); ``"fall"`` the shared fall test (:class:`~mocap_tasks.common.FallParams`); ``"both"``.

Hook: ``step(state)`` advances the counters and redraws the targets whose time is up.

Metrics (since the last :meth:`PointGoalTask.metrics`). A *goal* is one drawn target; it *finishes*
when it is redrawn or its env is reset; it is *reached* at the first reward computation with the
root within ``arrive_radius`` of it:

* ``distance``: mean root-target ground distance over the control steps, m;
* ``reward``: mean reward; ``steps``: their number (a sum);
* ``success_rate``: fraction of the finished goals (with at least one step) that were reached;
* ``time_to_reach``: mean time from drawing to reaching over the reached finished goals, s;
* ``final_distance``: mean distance at the last step of each finished goal, m;
* ``closest_distance``: mean over the finished goals of the smallest distance during the goal, m;
* ``goals``: number of finished goals (a sum). Goal metrics are absent when no goal finished.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import torch
from mocap.interfaces import Task
from mocap.observations import world_to_heading
from mocap.skeleton import Skeleton
from mocap.state import SimState
from mocap_tasks.common import (
    GoalBookkeeping,
    TaskBase,
    horizontal_unit,
    resolve_body,
    rows,
)
from torch import Tensor
from mocap_tasks.task_params import PointGoalParams

__all__ = ["HEAD_NAMES", "PointGoalParams", "PointGoalTask", "make_point_goal", "point_goal_reward"]

#: head body names of the built-in skeletons (``amp``, ``smpl``), tried in order
HEAD_NAMES: tuple[str, ...] = ("head", "Head")


def point_goal_reward(
    root_xy: Tensor,
    root_vel_xy: Tensor,
    target_xy: Tensor,
    *,
    pos_weight: float = 0.7,
    speed_weight: float = 0.3,
    pos_scale: float = 0.5,
    target_speed: float = 1.0,
    arrive_radius: float = 0.5,
    direction: Literal["toward_target", "paper"] = "toward_target",
) -> Tensor:
    """(N,) Eq. 16 ``(w_p exp(-s ||p - t||^2) + w_v exp(-max(0, u - <v, d>)^2)) / (w_p + w_v)``, 1 within
    ``arrive_radius``. The weights are normalized by their sum (the paper's sum to 1), so ``r`` is in (0, 1]."""
    diff = target_xy - root_xy
    dist2 = (diff * diff).sum(-1)
    d = horizontal_unit(diff if direction == "toward_target" else -diff)
    toward = (root_vel_xy * d).sum(-1)
    r_pos = torch.exp(-pos_scale * dist2)
    r_speed = torch.exp(-((target_speed - toward).clamp_min(0.0) ** 2))
    r = (pos_weight * r_pos + speed_weight * r_speed) / (pos_weight + speed_weight)
    return torch.where(dist2 <= arrive_radius**2, torch.ones_like(r), r)


class PointGoalTask(GoalBookkeeping, TaskBase, Task):
    """The ``point_goal`` task (module docstring). Goal: :attr:`target` (N, 2) world xy."""

    goal_dim = 2
    max_reward = 1.0

    def __init__(self, params: PointGoalParams, *, skeleton: Skeleton, num_envs: int, device: Any = "cpu", seed: int | None = None):
        self.params = p = params
        self._setup(p.fall, skeleton, num_envs, device, p.seed if seed is None else seed)
        self.sim_overrides = {}
        self.episode_steps = p.episode_steps
        self.head_index = resolve_body(skeleton, p.head, HEAD_NAMES)
        N, dev, f64 = self.num_envs, self.device, torch.float64
        self.target = torch.zeros(N, 2, dtype=f64, device=dev)
        self.anchor_xy = torch.zeros(N, 2, dtype=f64, device=dev)
        self._init_goals(N, dev)

    # ------------------------------------------------------------------------------ goals
    def _sample(self, ids: Tensor) -> None:
        k = int(ids.numel())
        u = self._rand(k, 2)
        r = self.params.radius * torch.sqrt(u[:, 0])  # uniform in the disc
        a = 2.0 * math.pi * u[:, 1]
        self.target[ids] = self.anchor_xy[ids] + torch.stack((r * torch.cos(a), r * torch.sin(a)), -1)
        self._new_goals(ids)

    def reset(self, env_ids: Tensor, state: SimState) -> None:
        ids = self._ids(env_ids)
        if ids.numel() == 0:
            return
        self._finish_goals(ids)
        r = rows(state, ids, self.num_envs)
        self.progress[ids] = 0
        self.anchor_xy[ids] = r.root_pos[:, :2].detach().to(self.device, torch.float64)
        self._sample(ids)

    def step(self, state: SimState) -> None:
        """Advance counters; redraw the targets whose time is up (module docstring)."""
        self.progress += 1
        self.goal_steps += 1
        due = ((self.progress % self.params.change_steps) == 0).nonzero().flatten()
        if due.numel():
            self._finish_goals(due)
            self._sample(due)

    # ------------------------------------------------------------------------ observation
    def observe(self, state: SimState) -> Tensor:
        rel = state.root_pos[:, :2] - self.target.to(state.root_pos)
        rel3 = torch.cat((rel, torch.zeros_like(rel[:, :1])), -1)
        return world_to_heading(state.root_rot, rel3)[:, :2]

    # ----------------------------------------------------------------------------- reward
    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        root = state.root_pos[:, :2]
        target = self.target.to(root)
        r = point_goal_reward(
            root,
            state.root_lin_vel[:, :2],
            target,
            pos_weight=p.pos_weight,
            speed_weight=p.speed_weight,
            pos_scale=p.pos_scale,
            target_speed=p.target_speed,
            arrive_radius=p.arrive_radius,
            direction=p.direction,
        )
        dist = torch.linalg.vector_norm(root - target, dim=-1)
        new = (self.reached_step < 0) & (dist.to(self.device) <= p.arrive_radius)
        self.reached_step = torch.where(new, self.goal_steps + 1, self.reached_step)
        self._track_distance(dist)
        self._sums.add("distance", dist)
        self._sums.add("reward", r)
        self._sums.add("steps", float(r.numel()), count=1)
        return r

    def terminated(self, state: SimState) -> Tensor:
        mode = self.params.termination
        head_low = state.body_pos[:, self.head_index, 2] < self.params.head_height
        if mode == "paper":
            return head_low
        fell = self._fallen(state).to(head_low.device)
        return fell if mode == "fall" else fell | head_low

    def metrics(self) -> dict[str, float]:
        return self._pop_goal_metrics(self._sums.pop(totals=("steps",)))


def make_point_goal(params: PointGoalParams, *, skeleton: Skeleton, num_envs: int, device: Any = "cpu", seed: int | None = None, **_: Any) -> PointGoalTask:
    """Registry factory of the ``point_goal`` task."""
    return PointGoalTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed)
