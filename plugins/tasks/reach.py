"""The ``reach`` task (PULSE Sec. 4.3 / App. C, following ASE): bring the right hand to a target point.

Goal. A 3-D point ``c`` (world frame), resampled after U[``change_steps``) control steps ([CODE]
``tarChangeSteps`` U[50, 100); the paper does not say) and at every reset:

* ``c_xy = a_xy + U[-xy_range, xy_range]^2`` with ``a`` the anchor (``anchor``): the root's xy at the
  episode start (default; [CODE] zeroes the root xy at reset and samples in world coordinates, so
  targets lie around the start position) or the root's xy when the target is sampled;
  the square is world-axis aligned as in the code;
* ``c_z ~ U[height_range]``. [P] App. C: "a 2-meter box centered at (0, 0, 1)" = xy in [-1, 1] m,
  z in [0, 2] m (the main text says "within 1 meter of the humanoid"); [CODE] ``tarDistMax`` 1,
  ``tarHeightMin/Max`` 0.2 / 2.0.

Observation (3): ``h^-1 (c - p_root)``, the target relative to the root in the heading frame
(code ``compute_location_observations``).

Reward: ``r = exp(-coefficient * ||p_hand - c||^2)`` in (0, 1], 1 exactly at the target;
``coefficient`` 5 ([P]) or 4 ([CODE] ``pos_err_scale``). ``body`` is the reaching body (default the
right hand: ``R_Hand`` on smpl, ``right_hand`` on amp). Switch ``far_weight`` w (ours; 0 in the
paper and the code): ``r = (1 - w) exp(-coefficient d^2) + w exp(-far_coefficient d^2)``, still in
(0, 1] and 1 at the target, for a policy that has strayed metres away, where ``exp(-5 d^2)`` is ~0
and gives PPO nothing to follow (measured through PULSE: mean distance 5.4 m at 3.2M env steps).
Switch ``mid_weight`` m (ours; 0 in the paper and the code) adds a third term between the two:
``r = (1 - w - m) exp(-coefficient d^2) + m exp(-mid_coefficient d^2) + w exp(-far_coefficient d^2)``,
for the 0.5-1.5 m band where the narrow term is ~0 and the wide one is ~flat (measured through the
v20 latents: every seed stood ~1 m from its targets). Tried through PULSE v20 (0.3 / 0.4 / 0.3, one
seed, 7M env steps): no better (bench/results/task_compare_v20.md, ``pulse_mid_reward``).

Termination: a fall (:class:`~mocap_tasks.common.FallParams`).

Hook: ``step(state)`` (called by the env once per control step after the reward) advances the
step counters and resamples the targets whose time is up. Without it the target never changes and
the timing metrics are not defined.

Metrics (since the last :meth:`ReachTask.metrics`). A *goal* is one sampled target; it *finishes*
when it is resampled or its env is reset; it is *reached* at the first reward computation with
``||p_hand - c|| <= success_radius``:

* ``distance``: mean hand-target distance over the control steps, m;
* ``reward``: mean reward over the control steps; ``steps``: their number (a sum);
* ``success_rate``: fraction of the finished goals (with at least one step) that were reached;
* ``time_to_reach``: mean time from sampling to reaching over the reached finished goals, s
  (``steps * dt``; the first step counts as ``dt``);
* ``final_distance``: mean distance at the last step of each finished goal, m;
* ``closest_distance``: mean over the finished goals of the smallest distance during the goal, m;
* ``goals``: number of finished goals (a sum). Goal metrics are absent when no goal finished.
"""

from __future__ import annotations

from typing import Any

import torch
from mocap.interfaces import Task
from mocap.observations import world_to_heading
from mocap.skeleton import Skeleton
from mocap.state import SimState
from mocap_tasks.common import GoalBookkeeping, TaskBase, resolve_body, rows
from torch import Tensor
from mocap_tasks.task_params import ReachParams

__all__ = ["ReachParams", "ReachTask", "make_reach", "reach_reward"]


def reach_reward(
    hand_pos: Tensor,
    target: Tensor,
    coefficient: float = 5.0,
    far_weight: float = 0.0,
    far_coefficient: float = 0.05,
    mid_weight: float = 0.0,
    mid_coefficient: float = 1.0,
) -> Tensor:
    """(N,) ``(1 - w - m) exp(-coefficient d^2) + m exp(-mid_coefficient d^2) + w exp(-far_coefficient d^2)``,
    ``d = ||hand_pos - target||``, ``w = far_weight``, ``m = mid_weight`` (both 0: the paper's
    ``exp(-coefficient d^2)``)."""
    if far_weight + mid_weight > 1.0 + 1e-9:
        raise ValueError(f"far_weight + mid_weight must be <= 1, got {far_weight} + {mid_weight}")
    diff = hand_pos - target
    d2 = (diff * diff).sum(-1)
    r = torch.exp(-coefficient * d2)
    if far_weight == 0.0 and mid_weight == 0.0:
        return r
    r = (1.0 - far_weight - mid_weight) * r + far_weight * torch.exp(-far_coefficient * d2)
    if mid_weight > 0.0:
        r = r + mid_weight * torch.exp(-mid_coefficient * d2)
    return r


class ReachTask(GoalBookkeeping, TaskBase, Task):
    """The ``reach`` task (module docstring). Goal: :attr:`target` (N, 3) world points."""

    goal_dim = 3
    max_reward = 1.0

    def __init__(
        self,
        params: ReachParams,
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
        self.body_index = resolve_body(skeleton, params.body)
        N, dev, f64 = self.num_envs, self.device, torch.float64
        self.target = torch.zeros(N, 3, dtype=f64, device=dev)
        self.anchor_xy = torch.zeros(N, 2, dtype=f64, device=dev)
        self.change_at = torch.full((N,), params.change_steps[0], dtype=torch.long, device=dev)
        # per-goal bookkeeping for the metrics
        self._init_goals(N, dev)

    # ------------------------------------------------------------------------------ goals
    def _sample(self, ids: Tensor, root_xy: Tensor | None) -> None:
        p = self.params
        k = int(ids.numel())
        if root_xy is not None:
            self.anchor_xy[ids] = root_xy.to(self.anchor_xy)
        u = self._rand(k, 3)
        xy = self.anchor_xy[ids] + p.xy_range * (2.0 * u[:, :2] - 1.0)
        lo, hi = p.height_range
        z = lo + (hi - lo) * u[:, 2:]
        self.target[ids] = torch.cat((xy, z), dim=-1)
        self.change_at[ids] = self.progress[ids] + self._randint(p.change_steps[0], p.change_steps[1], k)
        self._new_goals(ids)

    def reset(self, env_ids: Tensor, state: SimState) -> None:
        ids = self._ids(env_ids)
        if ids.numel() == 0:
            return
        self._finish_goals(ids)
        r = rows(state, ids, self.num_envs)
        self.progress[ids] = 0
        self._sample(ids, r.root_pos[:, :2].detach().to(self.device))

    def step(self, state: SimState) -> None:
        """Advance counters and resample the targets whose time is up (module docstring)."""
        self.progress += 1
        self.goal_steps += 1
        due = (self.progress >= self.change_at).nonzero().flatten()
        if due.numel():
            self._finish_goals(due)
            root_xy = state.root_pos[due, :2].detach().to(self.device) if self.params.anchor == "current_root" else None
            self._sample(due, root_xy)

    # ------------------------------------------------------------------------ observation
    def observe(self, state: SimState) -> Tensor:
        rel = self.target.to(state.root_pos) - state.root_pos
        return world_to_heading(state.root_rot, rel)

    def markers(self, env_id: int = 0) -> list[tuple[Any, tuple[float, ...], float]]:
        """For videos: the hand target as a red sphere."""
        return [(self.target[env_id].detach().cpu().double().numpy(), (0.9, 0.15, 0.15, 1.0), 0.05)]

    # ----------------------------------------------------------------------------- reward
    def hand_position(self, state: SimState) -> Tensor:
        return state.body_pos[:, self.body_index]

    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        hand = self.hand_position(state)
        target = self.target.to(hand)
        r = reach_reward(hand, target, p.coefficient, p.far_weight, p.far_coefficient, p.mid_weight, p.mid_coefficient)
        dist = torch.linalg.vector_norm(hand - target, dim=-1)
        new = (self.reached_step < 0) & (dist.to(self.device) <= p.success_radius)
        self.reached_step = torch.where(new, self.goal_steps + 1, self.reached_step)
        self._track_distance(dist)
        self._sums.add("distance", dist)
        self._sums.add("reward", r)
        self._sums.add("steps", float(r.numel()), count=1)
        return r

    def terminated(self, state: SimState) -> Tensor:
        return self._fallen(state)

    def metrics(self) -> dict[str, float]:
        return self._pop_goal_metrics(self._sums.pop(totals=("steps",)))


def make_reach(
    params: ReachParams,
    *,
    skeleton: Skeleton,
    num_envs: int,
    device: Any = "cpu",
    seed: int | None = None,
    **_: Any,
) -> ReachTask:
    """Registry factory of the ``reach`` task."""
    return ReachTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed)
