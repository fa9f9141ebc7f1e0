"""The ``strike`` task (PULSE Sec. 4.3 / App. C, following ASE without the sword): knock a standing
box over with the hand.

Simulator. The task asks for the simulator's target prop through :attr:`StrikeTask.sim_overrides`
(``{"target": {half_size, mass, friction}}``, :class:`mocap_sim_mujoco.simulator.TargetParams`) and
needs :meth:`StrikeTask.attach` to keep the simulator: :meth:`reset` places the box with
``sim.set_target(env_ids, pos, rot)``, the reward reads ``sim.target_state()`` (pos, rot wxyz,
world velocities) and the termination reads ``sim.ground_contact`` (ground-only contacts, so that
touching the box is not a fall).

Reset. The box stands upright on the ground (centre at ``half_size[2]``; [CODE] centre 0.9 m),
at a distance ``dist`` from the root in a uniform direction, with a uniform yaw ([CODE]):
``dist ~ U[distance]`` ([P] 1.5-5 m), or, with probability ``near_prob``, ``U[distance[0], near_max]``
([CODE]: U[0.5, 10] m, 50 % "near" with max 1.5 m).

Observation (15, [CODE] ``compute_strike_observations``; [P] "target position and orientation,
linear and angular velocity, in the agent frame")::

    [ h^-1 (x_t - x_root, y_t - y_root, z_t) (3) | sixd(h^-1 q_t) (6) | h^-1 v_t (3) | h^-1 w_t (3) ]

(the height is the box's absolute height, the code's convention; ``sixd`` = ``tan_norm`` [CODE]).

Reward, with ``u`` = the box's up axis and ``c = u . e_z``:

* ``"paper"`` ([P]): ``r = 1 - c`` in [0, 2] (0 upright, 1 lying, 2 upside down): ``max_reward`` 2;
* ``"code"`` ([CODE] ``compute_strike_reward``, default): ``r = 0.6 max(0, 1 - c) + 0.4 r_vel`` with
  ``r_vel = exp(-4 max(0, 1 - v_toward)^2)``, zeroed when ``v_toward <= 0``, ``v_toward`` the root's
  horizontal velocity along the unit xy direction from the root to the box (target speed 1 m/s);
  ``r = 1`` once ``c < success_up_dot`` (0.2). In [0, 1], ``max_reward`` 1.

Termination: a fall (ground contacts only) or, by ``illegal_contact``, a forbidden hit of the box:
``"paper"`` any body other than the strike bodies touches the box ([P] "any body other than the
right hand"); ``"code"`` ([CODE] ``compute_humanoid_reset``) only bodies that are neither strike
bodies nor feet and only with a contact-force component above ``contact_force_threshold`` (50 N;
our state sums ground and box forces per body); ``"off"``. A body touches the box when it is in
``SimState.body_contact`` (ground or props) but not in the simulator's ``ground_contact``.

Hook: ``step(state)`` (once per control step after the reward) advances the step counters and
stores the root position (finite-difference velocity).

Metrics (since the last :meth:`StrikeTask.metrics`). An *episode* finishes when its env is reset
again; the box is *hit* (knocked over) at the first reward computation with ``c < success_up_dot``:

* ``reward``: mean reward; ``up_dot``: mean ``c`` over the control steps; ``steps``: their number;
* ``hit_rate``: fraction of the finished episodes (with at least one step) whose box was knocked over;
* ``time_to_hit``: mean time from the reset to the hit over those episodes, s;
* ``illegal_contact_rate``: fraction of the finished episodes with a forbidden box contact seen by
  :meth:`terminated` (whatever ``illegal_contact`` says, the ``paper`` rule is what is counted);
* ``episodes``: number of finished episodes (a sum). Episode metrics are absent when none finished.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import torch
from mocap.interfaces import MovableTarget, Task
from mocap.observations import rotation_sixd, world_to_heading
from mocap.rotations import heading_quat_inv, quat_mul
from mocap.skeleton import Skeleton
from mocap.state import SimState, TargetState
from mocap_tasks.common import (
    TaskBase,
    horizontal_unit,
    quat_from_yaw,
    resolve_body,
    rows,
)
from torch import Tensor
from mocap_tasks.task_params import StrikeParams

__all__ = [
    "StrikeParams",
    "StrikeTask",
    "make_strike",
    "strike_reward_code",
    "strike_reward_paper",
    "up_dot",
]


def up_dot(target_rot: Tensor) -> Tensor:
    """(N,) ``e_z . R(q) e_z``: the z component of the box's up axis (1 upright, 0 lying, -1 upside down)."""
    x, y = target_rot[..., 1], target_rot[..., 2]
    n2 = (target_rot * target_rot).sum(-1)
    return 1.0 - 2.0 * (x * x + y * y) / n2


def strike_reward_paper(target_rot: Tensor) -> Tensor:
    """(N,) [P] ``1 - u_up . u_t`` in [0, 2]."""
    return 1.0 - up_dot(target_rot)


def strike_reward_code(
    target_pos: Tensor,
    target_rot: Tensor,
    root_pos: Tensor,
    root_vel_xy: Tensor,
    *,
    rot_weight: float = 0.6,
    vel_weight: float = 0.4,
    toward_speed: float = 1.0,
    vel_scale: float = 4.0,
    success_up_dot: float = 0.2,
) -> Tensor:
    """(N,) [CODE] ``rot_weight max(0, 1 - c) + vel_weight r_vel``, 1 once ``c < success_up_dot`` (module docstring)."""
    c = up_dot(target_rot)
    rot_r = (1.0 - c).clamp_min(0.0)
    direction = horizontal_unit(target_pos - root_pos)
    v = (direction * root_vel_xy).sum(-1)
    err = (toward_speed - v).clamp_min(0.0)
    vel_r = torch.where(v > 0, torch.exp(-vel_scale * err * err), torch.zeros_like(v))
    r = rot_weight * rot_r + vel_weight * vel_r
    return torch.where(c < success_up_dot, torch.ones_like(r), r)


class StrikeTask(TaskBase, Task):
    """The ``strike`` task (module docstring)."""

    goal_dim = 15

    def __init__(
        self,
        params: StrikeParams,
        *,
        skeleton: Skeleton,
        num_envs: int,
        device: Any = "cpu",
        seed: int | None = None,
    ):
        self.params = p = params
        self._setup(p.termination, skeleton, num_envs, device, p.seed if seed is None else seed, p.start)
        self.max_reward = 2.0 if p.reward == "paper" else 1.0
        hx, hy, hz = p.half_size
        self.sim_overrides = {
            "target": {
                "half_size": tuple(p.half_size),
                "mass": 8.0 * hx * hy * hz * p.density,
                "friction": p.friction,
            }
        }
        names = p.strike_bodies
        mask = torch.zeros(skeleton.num_bodies, dtype=torch.bool)
        if names is None:
            mask[resolve_body(skeleton, None)] = True
        else:
            for n in names:
                mask[resolve_body(skeleton, n)] = True
        self.strike_mask = mask.to(self.device)
        N, dev = self.num_envs, self.device
        self.prev_root_pos = torch.zeros(N, 3, dtype=torch.float64, device=dev)
        self.hit_step = torch.full((N,), -1, dtype=torch.long, device=dev)
        self.illegal = torch.zeros(N, dtype=torch.bool, device=dev)
        self.steps_in_episode = torch.zeros(N, dtype=torch.long, device=dev)
        self._episode_stats = {
            "episodes": 0.0,
            "hits": 0.0,
            "time": 0.0,
            "illegal": 0.0,
        }

    # -------------------------------------------------------------------------- simulator
    def _need_sim(self) -> MovableTarget:
        sim = self.sim
        if sim is None:
            raise RuntimeError("the strike task needs the simulator: call attach(sim) with a simulator built with sim_overrides")
        if not isinstance(sim, MovableTarget) or not sim.has_target:
            raise RuntimeError(
                f"the strike task needs a simulator with a target prop (mocap.interfaces.MovableTarget, built with the task's "
                f"sim_overrides); {type(sim).__name__} has none"
            )
        return sim

    def target_state(self) -> TargetState:
        """The simulator's :class:`mocap.state.TargetState` (pos, rot, lin_vel, ang_vel, fallen)."""
        return self._need_sim().target_state()

    def target_contact(self, state: SimState) -> Tensor:
        """(N, B) bool: bodies touching the box (a contact, but not with the ground)."""
        if state.body_contact.numel() == 0:
            return torch.zeros(state.body_pos.shape[:2], dtype=torch.bool, device=state.root_pos.device)
        return state.body_contact & ~self._ground_contact(state)

    # ------------------------------------------------------------------------------ goals
    def reset(self, env_ids: Tensor, state: SimState) -> None:
        ids = self._ids(env_ids)
        if ids.numel() == 0:
            return
        self._finish_episodes(ids)
        p = self.params
        r = rows(state, ids, self.num_envs)
        k = int(ids.numel())
        u = self._rand(k, 4)
        lo, hi = p.distance
        dmax = torch.where(
            u[:, 0] < p.near_prob,
            torch.full_like(u[:, 0], p.near_max),
            torch.full_like(u[:, 0], hi),
        )
        dist = lo + (dmax - lo) * u[:, 1]
        theta = 2.0 * math.pi * u[:, 2]
        root = r.root_pos.detach().to(self.device, torch.float64)
        pos = torch.stack(
            (
                root[:, 0] + dist * torch.cos(theta),
                root[:, 1] + dist * torch.sin(theta),
                torch.full_like(dist, p.half_size[2]),
            ),
            dim=-1,
        )
        yaw = 2.0 * math.pi * u[:, 3] if p.random_yaw else torch.zeros_like(dist)
        self._need_sim().set_target(ids, pos, quat_from_yaw(yaw))
        self.prev_root_pos[ids] = root
        self.progress[ids] = 0
        self.hit_step[ids] = -1
        self.illegal[ids] = False
        self.steps_in_episode[ids] = 0

    def step(self, state: SimState) -> None:
        """Advance counters; remember the root position (module docstring)."""
        self.progress += 1
        self.steps_in_episode += 1
        self.prev_root_pos = state.root_pos.detach().to(self.device, torch.float64).clone()

    def _finish_episodes(self, ids: Tensor) -> None:
        ids = ids[self.steps_in_episode[ids] > 0]
        if ids.numel() == 0:
            return
        hit = self.hit_step[ids] >= 0
        e = self._episode_stats
        e["episodes"] += float(ids.numel())
        e["hits"] += float(hit.sum())
        e["time"] += float(self.hit_step[ids][hit].double().sum()) * self.dt
        e["illegal"] += float(self.illegal[ids].sum())

    def markers(self, env_id: int = 0) -> list[tuple[Any, tuple[float, ...], float]]:
        """For videos (the humanoid-only recorder does not draw the box): the target's centre and the
        centre of its top face; the top drops beside the centre when the target is knocked over."""
        from mocap.rotations import quat_apply

        t = self.target_state()
        pos, rot = t.pos[env_id].detach().cpu().double(), t.rot[env_id].detach().cpu().double()
        top = pos + quat_apply(rot, torch.tensor([0.0, 0.0, float(self.params.half_size[2])], dtype=torch.float64))
        return [(pos.numpy(), (0.95, 0.55, 0.1, 1.0), 0.08), (top.numpy(), (0.95, 0.85, 0.1, 1.0), 0.06)]

    # ------------------------------------------------------------------------ observation
    def observe(self, state: SimState) -> Tensor:
        t = self.target_state()
        dt = state.root_pos.dtype
        pos, rot = (
            t.pos.to(state.root_pos.device, dt),
            t.rot.to(state.root_pos.device, dt),
        )
        lin, ang = t.lin_vel.to(pos), t.ang_vel.to(pos)
        rel = torch.cat((pos[:, :2] - state.root_pos[:, :2], pos[:, 2:]), dim=-1)
        local_rot = quat_mul(heading_quat_inv(state.root_rot), rot)
        return torch.cat(
            (
                world_to_heading(state.root_rot, rel),
                rotation_sixd(local_rot, self.params.sixd),
                world_to_heading(state.root_rot, lin),
                world_to_heading(state.root_rot, ang),
            ),
            dim=-1,
        )

    # ----------------------------------------------------------------------------- reward
    def root_velocity(self, state: SimState) -> Tensor:
        """(N, 2) horizontal root velocity of the code reward (``velocity`` switch)."""
        if self.params.velocity == "finite_difference":
            return ((state.root_pos - self.prev_root_pos.to(state.root_pos)) / self.dt)[:, :2]
        return state.root_lin_vel[:, :2]

    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        t = self.target_state()
        pos, rot = t.pos.to(state.root_pos), t.rot.to(state.root_pos)
        c = up_dot(rot)
        if p.reward == "paper":
            r = strike_reward_paper(rot)
        else:
            r = strike_reward_code(
                pos,
                rot,
                state.root_pos,
                self.root_velocity(state),
                rot_weight=p.rot_weight,
                vel_weight=p.vel_weight,
                toward_speed=p.toward_speed,
                vel_scale=p.vel_scale,
                success_up_dot=p.success_up_dot,
            )
        new = (self.hit_step < 0) & (c.to(self.device) < p.success_up_dot)
        self.hit_step = torch.where(new, self.steps_in_episode + 1, self.hit_step)
        self._sums.add("reward", r)
        self._sums.add("up_dot", c)
        self._sums.add("steps", float(r.numel()), count=1)
        return r

    def illegal_contact(self, state: SimState, rule: Literal["paper", "code"] | None = None) -> Tensor:
        """(N,) bool: a forbidden body touches the box under ``rule`` (default the params' rule)."""
        rule = rule or self.params.illegal_contact  # type: ignore[assignment]
        if rule == "off":
            return torch.zeros(state.num_envs, dtype=torch.bool, device=state.root_pos.device)
        touch = self.target_contact(state)
        forbidden = ~self.strike_mask.to(touch.device)
        if rule == "code":
            forbidden = forbidden & ~self._allowed.to(touch.device)
            if state.contact_forces.numel():
                strong = (state.contact_forces.abs() > self.params.contact_force_threshold).any(-1)
                touch = touch & strong
        return (touch & forbidden).any(-1)

    def terminated(self, state: SimState) -> Tensor:
        illegal_paper = self.illegal_contact(state, "paper")
        self.illegal |= illegal_paper.to(self.device)
        out = self._fallen(state)
        if self.params.illegal_contact != "off":
            rule_hit = illegal_paper if self.params.illegal_contact == "paper" else self.illegal_contact(state, "code")
            out = out | rule_hit.to(out.device)
        return out

    def metrics(self) -> dict[str, float]:
        out = self._sums.pop(totals=("steps",))
        e = self._episode_stats
        if e["episodes"] > 0:
            out["episodes"] = e["episodes"]
            out["hit_rate"] = e["hits"] / e["episodes"]
            out["illegal_contact_rate"] = e["illegal"] / e["episodes"]
            if e["hits"] > 0:
                out["time_to_hit"] = e["time"] / e["hits"]
        self._episode_stats = {k: 0.0 for k in e}
        return out


def make_strike(
    params: StrikeParams,
    *,
    skeleton: Skeleton,
    num_envs: int,
    device: Any = "cpu",
    seed: int | None = None,
    **_: Any,
) -> StrikeTask:
    """Registry factory of the ``strike`` task."""
    return StrikeTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed)
