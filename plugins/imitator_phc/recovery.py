"""PHC's fail-state recovery goal (digest phc §4.4): far from the reference, imitate only its root.

When the simulated root is farther than ``close_distance`` from the reference root, the imitation
goal is computed on a *masked* reference in which everything but the root is replaced by the
simulated values, so the non-root goal terms vanish and the goal collapses to a point goal (the
reference root's relative position and orientation). Beyond ``far_distance`` the reference root is
moved along the line to the humanoid so that it lies exactly ``far_distance`` away (PHC Eq. 3 and
the far clamp). Two forms:

* ``"paper"`` ([P]): close 0.5 m, far 5 m; non-root body positions, rotations and velocities are
  the simulated ones, the root's velocities stay the reference's;
* ``"code"`` ([C] ``zero_out_far``): close 0.25 m, far 3 m (the :class:`RecoveryGoalParams`
  defaults follow the paper; set the distances for the code's values); *all* velocities, the
  root's included, are replaced by the simulated ones.

:func:`recovery_reference` is pure (no state); :class:`PHCObservation` applies it when its
``recovery`` field is set.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Literal

import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor

from mocap.state import HUMANOID_FIELDS, HumanoidState


class RecoveryGoalParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    form: Literal["paper", "code"] = Field(
        "paper", description="'paper': root velocities stay the reference's; 'code' ([C] zero_out_far): all velocities are the simulated ones"
    )
    close_distance: float = Field(0.5, gt=0, description="root distance up to which the full imitation goal is used, m ([P] 0.5; [C] 0.25)")
    far_distance: float = Field(5.0, gt=0, description="the reference root is pulled to at most this distance, m ([P] 5; [C] 3)")
    reward: Literal["imitation", "point"] = Field(
        "imitation",
        description="task reward while far (root farther than close_distance before the step): 'point' = PHC Eq. 4's "
        "point-goal term r = d_{t-1} - d_t (the decrease of the root-to-reference-root distance, m per control step; "
        "[P] for the recovery primitive and the composer) or 'imitation' = the imitation reward as everywhere else",
    )
    point_form: Literal["paper", "code"] = Field(
        "paper",
        description="the point-goal term: 'paper' = d_{t-1} - d_t (PHC Eq. 4); 'code' = 9 min(d_{t-1} - d_t, 1/3) (the "
        "official code's compute_point_goal_reward: scaled and clipped)",
    )
    far_energy_weight: float = Field(
        0.1,
        ge=0.0,
        description="weight of the energy penalty while far with reward 'point' (PHC Eq. 4: 0.5 r^point + 0.5 r^amp + "
        "0.1 r^energy; [C] keeps the penalty inside the task reward with a smaller coefficient instead); 1 = unchanged",
    )


_FIELDS = HUMANOID_FIELDS


def recovery_reference(
    state: HumanoidState, ref: HumanoidState, params: RecoveryGoalParams
) -> tuple[HumanoidState, Tensor]:
    """(the reference to build the goal from, (N,) bool "far" mask) — module docstring.

    Rows that are close are returned unchanged; far rows get the masked reference.
    """
    state = replace(state, **{k: getattr(state, k).to(ref.body_pos.dtype) for k in _FIELDS})
    offset = ref.root_pos - state.root_pos
    dist = torch.linalg.vector_norm(offset, dim=-1)
    far = dist > params.close_distance
    if not bool(far.any()):
        return ref, far
    scale = torch.where(dist > params.far_distance, params.far_distance / dist.clamp_min(1e-9), torch.ones_like(dist))
    root_pos = state.root_pos + offset * scale[:, None]
    m = far[:, None, None]
    body_pos = torch.where(m, state.body_pos, ref.body_pos)
    body_rot = torch.where(m, state.body_rot, ref.body_rot)
    body_lin_vel = torch.where(m, state.body_lin_vel, ref.body_lin_vel)
    body_ang_vel = torch.where(m, state.body_ang_vel, ref.body_ang_vel)
    # the root row: clamped reference root position, reference root rotation
    body_pos = body_pos.clone()
    body_rot = body_rot.clone()
    body_pos[:, 0] = torch.where(far[:, None], root_pos, ref.body_pos[:, 0])
    body_rot[:, 0] = ref.body_rot[:, 0]
    if params.form == "paper":  # the root's velocities stay the reference's
        body_lin_vel = body_lin_vel.clone()
        body_ang_vel = body_ang_vel.clone()
        body_lin_vel[:, 0] = ref.body_lin_vel[:, 0]
        body_ang_vel[:, 0] = ref.body_ang_vel[:, 0]
    f1 = far[:, None]
    masked = replace(
        ref,
        root_pos=body_pos[:, 0],
        root_rot=body_rot[:, 0],
        root_lin_vel=body_lin_vel[:, 0],
        root_ang_vel=body_ang_vel[:, 0],
        dof_pos=torch.where(f1, state.dof_pos, ref.dof_pos),
        dof_vel=torch.where(f1, state.dof_vel, ref.dof_vel),
        body_pos=body_pos,
        body_rot=body_rot,
        body_lin_vel=body_lin_vel,
        body_ang_vel=body_ang_vel,
    )
    return masked, far




# ------------------------------------------------------------------------------ fail states
class FailStateParams(BaseModel):
    """Episode starts away from the reference (PHC §3.4 / digest phc §4.4), for recovery training."""

    model_config = ConfigDict(extra="forbid")
    fall_init_prob: float = Field(
        0.0, ge=0.0, le=1.0, description="share of resets from a fallen state ([C] 0.3; 1.0 in the code's first get-up phase)"
    )
    far_init_prob: float = Field(0.0, ge=0.0, le=1.0, description="share of the other resets moved away from the reference ([P] far states)")
    far_init_range: tuple[float, float] = Field((2.0, 5.0), description="distance of a far start from the reference root, m ([P] 2-5)")
    recovery_episode_prob: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="chance that a terminated episode becomes a 'bonus' recovery episode (it goes on, with a recovery "
        "window, instead of being reset) ([C] recoveryEpisodeProb 0.5 in phase 2 and for the composer)",
    )
    recovery_steps: int = Field(
        90, ge=0, description="control steps after a fallen or far start during which tracking failures do not terminate ([C] 90 = 3 s)"
    )
    pool_size: int | None = Field(None, ge=1, description="fallen states generated at start (None: one per env)")
    settle_steps: int = Field(75, ge=1, description="control steps each fallen state is simulated for ([C] 150 physics steps at 60 Hz = 2.5 s)")
    action_range: float = Field(0.5, gt=0.0, le=1.0, description="held random normalized PD action in U(-r, r) while falling ([C] 0.5)")
    drop_height: float = Field(1.2, gt=0.0, description="root height the humanoid is dropped from with a random orientation, m")


_VEL_FIELDS = ("root_lin_vel", "root_ang_vel", "dof_vel", "body_lin_vel", "body_ang_vel")


def generate_fall_states(sim: Any, skeleton: Any, count: int, params: FailStateParams, generator: torch.Generator) -> HumanoidState:
    """``count`` fallen states (velocities zeroed), made with ``sim`` as the code does: a random root
    orientation at ``drop_height``, zero joint angles, then ``settle_steps`` control steps with a held
    random PD action ``offset + scale * U(-r, r)`` (PHC's absolute action map)."""
    from mocap_phc.env import pd_offset_scale

    offset, scale = pd_offset_scale(skeleton)
    n_env = int(sim.num_envs)
    dev = sim.state.root_pos.device
    dtype = sim.state.root_pos.dtype
    chunks = []
    done = 0
    while done < count:
        q = torch.randn(n_env, 4, generator=generator, dtype=torch.float64)
        q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
        zeros3 = torch.zeros(n_env, 3, dtype=torch.float64)
        root_pos = zeros3.clone()
        root_pos[:, 2] = params.drop_height
        D = skeleton.num_dofs
        start = HumanoidState(
            root_pos=root_pos.to(dev, dtype),
            root_rot=q.to(dev, dtype),
            root_lin_vel=zeros3.to(dev, dtype),
            root_ang_vel=zeros3.to(dev, dtype),
            dof_pos=torch.zeros(n_env, D, device=dev, dtype=dtype),
            dof_vel=torch.zeros(n_env, D, device=dev, dtype=dtype),
            body_pos=torch.zeros(n_env, skeleton.num_bodies, 3, device=dev, dtype=dtype),
            body_rot=torch.zeros(n_env, skeleton.num_bodies, 4, device=dev, dtype=dtype),
            body_lin_vel=torch.zeros(n_env, skeleton.num_bodies, 3, device=dev, dtype=dtype),
            body_ang_vel=torch.zeros(n_env, skeleton.num_bodies, 3, device=dev, dtype=dtype),
        )
        sim.reset(torch.arange(n_env), start)
        a = (torch.rand(n_env, D, generator=generator, dtype=torch.float64) * 2 - 1) * params.action_range
        targets = (offset.double() + scale.double() * a).to(dev, torch.float32)
        for _ in range(params.settle_steps):
            state = sim.step(targets)
        take = min(n_env, count - done)
        s = state.index(torch.arange(take))
        s = HumanoidState(**{f: getattr(s, f).clone() for f in _FIELDS})
        for f in _VEL_FIELDS:
            getattr(s, f).zero_()
        chunks.append(s)
        done += take
    return HumanoidState(**{f: torch.cat([getattr(c, f) for c in chunks]) for f in _FIELDS})




def point_goal_reward(prev_dist: Tensor, dist: Tensor, form: Literal["paper", "code"] = "paper") -> Tensor:
    """PHC Eq. 4's point-goal term (Won et al.): the decrease of the root distance to the reference
    root, ``d_{t-1} - d_t`` ('paper'), or the official code's ``9 min(d_{t-1} - d_t, 1/3)`` ('code')."""
    if form == "paper":
        return prev_dist - dist
    if form == "code":
        return 9.0 * (prev_dist - dist).clamp_max(1.0 / 3.0)
    raise ValueError(f"unknown point-goal form {form!r}; choose 'paper' or 'code'")


def moved(state: HumanoidState, shift: Tensor) -> HumanoidState:
    """``state`` translated by ``shift`` (N, 3)."""
    return replace(state, root_pos=state.root_pos + shift, body_pos=state.body_pos + shift[:, None, :])


__all__ = ["FailStateParams", "RecoveryGoalParams", "generate_fall_states", "moved", "point_goal_reward", "recovery_reference"]
