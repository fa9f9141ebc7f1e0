"""PHC's fail-state recovery goal (PHC Sec. 3.2, Eq. 3): far from the reference, imitate only its root.

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
from typing import Literal

import torch
from torch import Tensor

from mocap.fail_states import FailStateParams, generate_fall_states, moved
from mocap_phc.phc_params import RecoveryGoalParams
from mocap.state import HUMANOID_FIELDS, HumanoidState


_FIELDS = HUMANOID_FIELDS


def recovery_reference(state: HumanoidState, ref: HumanoidState, params: RecoveryGoalParams) -> tuple[HumanoidState, Tensor]:
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


def point_goal_reward(prev_dist: Tensor, dist: Tensor, form: Literal["paper", "code"] = "paper") -> Tensor:
    """PHC Eq. 4's point-goal term (Won et al.): the decrease of the root distance to the reference
    root, ``d_{t-1} - d_t`` ('paper'), or the official code's ``9 min(d_{t-1} - d_t, 1/3)`` ('code')."""
    if form == "paper":
        return prev_dist - dist
    if form == "code":
        return 9.0 * (prev_dist - dist).clamp_max(1.0 / 3.0)
    raise ValueError(f"unknown point-goal form {form!r}; choose 'paper' or 'code'")


__all__ = ["FailStateParams", "RecoveryGoalParams", "generate_fall_states", "moved", "point_goal_reward", "recovery_reference"]
