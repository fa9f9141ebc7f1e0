"""Episode starts away from the reference, for learning to recover (PHC Sec. 3.2; PULSE's code
uses them in distillation too): fallen states, far starts and "bonus" recovery episodes.

Used by the PHC imitation env (:mod:`mocap_phc.env`) and by the distillation episodes
(:mod:`mocap.distill`), so a latent space sees the same get-up states its teacher learned from.

* :func:`generate_fall_states`: a pool of fallen states made as PHC's code does: the humanoid is
  dropped with a random orientation and zero joint angles, then simulated for ``settle_steps``
  control steps with a held random PD action; velocities are zeroed.
* :func:`fail_starts`: replaces some reference starts by a pool state moved under the reference
  root (probability ``fall_init_prob``) or by the reference moved 2-5 m away (``far_init_prob``)
  and returns which envs start a recovery window of ``recovery_steps`` steps (during which tracking
  failures do not end the episode).
"""

from __future__ import annotations

import math
from dataclasses import fields, replace
from typing import Any

import torch
from torch import Tensor

from mocap.fail_state_params import FailStateParams
from mocap.pd_actions import pd_offset_scale
from mocap.state import HUMANOID_FIELDS, HumanoidState

_FIELDS = HUMANOID_FIELDS


_VEL_FIELDS = ("root_lin_vel", "root_ang_vel", "dof_vel", "body_lin_vel", "body_ang_vel")


def generate_fall_states(sim: Any, skeleton: Any, count: int, params: FailStateParams, generator: torch.Generator) -> HumanoidState:
    """``count`` fallen states (velocities zeroed), made with ``sim`` as the code does: a random root
    orientation at ``drop_height``, zero joint angles, then ``settle_steps`` control steps with a held
    random PD action ``offset + scale * U(-r, r)`` (PHC's absolute action map)."""
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


def moved(state: HumanoidState, shift: Tensor) -> HumanoidState:
    """``state`` translated by ``shift`` (N, 3)."""
    return replace(state, root_pos=state.root_pos + shift, body_pos=state.body_pos + shift[:, None, :])


def assign_rows(dst: HumanoidState, ids: Tensor, src: HumanoidState) -> None:
    """``dst[ids] = src`` for every state field."""
    for name in _FIELDS:
        getattr(dst, name)[ids] = getattr(src, name).to(getattr(dst, name))


def fail_starts(start: HumanoidState, pool: HumanoidState | None, params: FailStateParams, generator: torch.Generator) -> tuple[HumanoidState, Tensor, Tensor]:
    """Replace some reference starts (rows of ``start``) by fallen states from ``pool`` (moved to the
    reference root's xy) or far ones (the reference moved ``far_init_range`` m in a random direction).
    Returns the new start states, the (n,) bool mask of the rows that got a fallen or far start, and
    the mask of the fallen ones."""
    n = int(start.root_pos.shape[0])
    u = torch.rand(n, generator=generator, dtype=torch.float64)
    v = torch.rand(n, generator=generator, dtype=torch.float64)
    fall = (u < params.fall_init_prob) if pool is not None else torch.zeros(n, dtype=torch.bool)
    far = ~fall & (v < params.far_init_prob)
    state: HumanoidState = HumanoidState(**{f.name: getattr(start, f.name).clone() for f in fields(HumanoidState)})
    if bool(far.any()):
        k = int(far.sum())
        lo, hi = params.far_init_range
        radius = lo + (hi - lo) * torch.rand(k, generator=generator, dtype=torch.float64)
        angle = 2 * math.pi * torch.rand(k, generator=generator, dtype=torch.float64)
        shift = torch.stack([radius * torch.cos(angle), radius * torch.sin(angle), torch.zeros(k, dtype=torch.float64)], -1)
        rows = far.nonzero().squeeze(-1)
        assign_rows(state, rows, moved(state.index(rows), shift.to(state.root_pos)))
    if bool(fall.any()):
        assert pool is not None
        k = int(fall.sum())
        pick = torch.randint(0, pool.num_envs, (k,), generator=generator)
        chosen = pool.index(pick)
        rows = fall.nonzero().squeeze(-1)
        shift = torch.zeros(k, 3, dtype=state.root_pos.dtype)
        shift[:, :2] = state.root_pos[rows, :2].cpu() - chosen.root_pos[:, :2].to(shift)
        dev, dt = state.root_pos.device, state.root_pos.dtype
        chosen = HumanoidState(**{f.name: getattr(chosen, f.name).to(dev, dt) for f in fields(HumanoidState)})
        assign_rows(state, rows, moved(chosen, shift.to(dev)))
    return state, fall | far, fall


__all__ = ["FailStateParams", "assign_rows", "fail_starts", "generate_fall_states", "moved"]
