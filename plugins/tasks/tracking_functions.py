"""The pure functions of the tracking tasks of :mod:`mocap_tasks.tracking` (which re-exports them): body
selection, the PHC imitation reward and Hybrid's head reward with their default weights and scales,
Hybrid's head goal and the tracking-failure test."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import torch
from mocap.imitation_rewards import TERMS, ImitationReward, RewardForm
from mocap.rotations import heading_quat_inv, quat_angle, quat_apply, quat_conjugate, quat_mul
from mocap.state import HumanoidState
from mocap_tasks.tracking_params import HMD_SCALES, HMD_WEIGHTS, PHC_SCALES, PHC_WEIGHTS
from torch import Tensor


# ------------------------------------------------------------------------------ pure functions
def select_bodies(state: HumanoidState, bodies: Sequence[int] | Tensor) -> HumanoidState:
    """``state`` with only the per-body fields of ``bodies`` (root pose and DoFs kept as they are),
    so that heading-frame goals built on it use the real root."""
    idx = torch.as_tensor(bodies, dtype=torch.long, device=state.body_pos.device)
    return HumanoidState(
        root_pos=state.root_pos,
        root_rot=state.root_rot,
        root_lin_vel=state.root_lin_vel,
        root_ang_vel=state.root_ang_vel,
        dof_pos=state.dof_pos,
        dof_vel=state.dof_vel,
        body_pos=state.body_pos[:, idx],
        body_rot=state.body_rot[:, idx],
        body_lin_vel=state.body_lin_vel[:, idx],
        body_ang_vel=state.body_ang_vel[:, idx],
    )


def imitation_reward(
    sim: HumanoidState,
    ref: HumanoidState,
    form: RewardForm = "paper",
    weights: Sequence[float] = PHC_WEIGHTS,
    scales: Sequence[float] = PHC_SCALES,
) -> tuple[Tensor, dict[str, Tensor]]:
    """PHC's ``r^g-imitation = sum_i w_i exp(-k_i e_i)`` over all bodies of ``sim``/``ref`` (the
    imitator's :class:`mocap.imitation_rewards.ImitationReward`): ``(reward (N,), terms)``."""
    return ImitationReward(form, tuple(weights), tuple(scales))(sim, ref)  # type: ignore[arg-type]


def _head_rows(state: HumanoidState, head: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    return state.body_pos[:, head], state.body_rot[:, head], state.body_lin_vel[:, head], state.body_ang_vel[:, head]


def head_reward(
    sim: HumanoidState,
    ref: HumanoidState,
    head: int,
    weights: Sequence[float] = HMD_WEIGHTS,
    scales: Sequence[float] = HMD_SCALES,
) -> tuple[Tensor, dict[str, Tensor]]:
    """Hybrid HMD reward on the head (module doc): ``sum_i w_i exp(-k_i |d_i|^2)``, ``(reward, terms)``."""
    p, q, v, w = _head_rows(sim, head)
    rp, rq, rv, rw = _head_rows(ref, head)
    errors = {
        "pos": (p - rp).square().sum(-1),
        "rot": quat_angle(quat_mul(q, quat_conjugate(rq))).square(),
        "vel": (v - rv).square().sum(-1),
        "ang_vel": (w - rw).square().sum(-1),
    }
    terms = {name: torch.exp(-k * errors[name]) for name, k in zip(TERMS, scales)}
    total = sum(wt * terms[name] for name, wt in zip(TERMS, weights))
    return total, terms  # type: ignore[return-value]


def head_goal(state: HumanoidState, refs: Sequence[HumanoidState], head: int) -> Tensor:
    """(N, 13 F) Hybrid's head goal for the reference frames ``refs`` (module doc), current minus reference."""
    h_inv = heading_quat_inv(state.root_rot)
    h = quat_conjugate(h_inv)
    p, q, v, w = _head_rows(state, head)
    parts = []
    for ref in refs:
        rp, rq, rv, rw = _head_rows(ref, head)
        dq = quat_mul(quat_mul(h_inv, quat_mul(q, quat_conjugate(rq))), h)
        dq = torch.where(dq[..., :1] < 0, -dq, dq)  # canonical: w >= 0
        parts += [quat_apply(h_inv, p - rp), quat_apply(h_inv, v - rv), dq, quat_apply(h_inv, w - rw)]
    return torch.cat(parts, dim=-1)


def tracking_failed(dist: Tensor, rule: Literal["mean", "any"], threshold: float, age: Tensor | None = None, grace: int = 0) -> Tensor:
    """(N,) bool from (N, K) distances to the reference: ``mean`` or ``any`` of them above ``threshold``,
    never while ``age`` (steps of the state since the reset) is at most ``grace``."""
    if rule == "mean":
        failed = dist.mean(-1) > threshold
    elif rule == "any":
        failed = (dist > threshold).any(-1)
    else:
        raise ValueError(f"unknown termination rule {rule!r}; choose 'mean' or 'any'")
    if age is not None and grace > 0:
        failed = failed & (age.to(failed.device) > grace)
    return failed


def _like(ref: HumanoidState, state: HumanoidState) -> HumanoidState:
    """The fields of ``ref`` in ``state``'s dtype and device."""
    dt, dev = state.body_pos.dtype, state.body_pos.device
    return HumanoidState(
        **{
            k: getattr(ref, k).to(dev, dt)
            for k in (
                "root_pos",
                "root_rot",
                "root_lin_vel",
                "root_ang_vel",
                "dof_pos",
                "dof_vel",
                "body_pos",
                "body_rot",
                "body_lin_vel",
                "body_ang_vel",
            )
        }
    )
