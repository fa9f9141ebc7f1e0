"""Random and perturbed simulator states for the imitation reward and termination tests."""

from __future__ import annotations

import numpy as np
import torch

from mocap.state import HumanoidState, SimState

F64 = torch.float64


def random_state(rng: np.random.Generator, n: int, b: int, d: int = 6) -> SimState:
    t = lambda a: torch.as_tensor(a, dtype=F64)  # noqa: E731
    rot = t(rng.standard_normal((n, b, 4)))
    rot = rot / rot.norm(dim=-1, keepdim=True)
    pos = t(rng.normal(0, 0.3, (n, b, 3)))
    lin, ang = t(rng.normal(0, 1, (n, b, 3))), t(rng.normal(0, 1, (n, b, 3)))
    return SimState(
        root_pos=pos[:, 0].clone(),
        root_rot=rot[:, 0].clone(),
        root_lin_vel=lin[:, 0].clone(),
        root_ang_vel=ang[:, 0].clone(),
        dof_pos=t(rng.normal(0, 1, (n, d))),
        dof_vel=t(rng.normal(0, 1, (n, d))),
        body_pos=pos,
        body_rot=rot,
        body_lin_vel=lin,
        body_ang_vel=ang,
    )


def perturbed(s: HumanoidState, rng: np.random.Generator, eps: float) -> SimState:
    t = lambda a: torch.as_tensor(a, dtype=F64)  # noqa: E731
    rot = s.body_rot + eps * t(rng.standard_normal(s.body_rot.shape))
    rot = rot / rot.norm(dim=-1, keepdim=True)
    pos = s.body_pos + eps * t(rng.standard_normal(s.body_pos.shape))
    return SimState(
        root_pos=pos[:, 0].clone(),
        root_rot=rot[:, 0].clone(),
        root_lin_vel=s.root_lin_vel,
        root_ang_vel=s.root_ang_vel,
        dof_pos=s.dof_pos,
        dof_vel=s.dof_vel,
        body_pos=pos,
        body_rot=rot,
        body_lin_vel=s.body_lin_vel + eps * t(rng.standard_normal(s.body_lin_vel.shape)),
        body_ang_vel=s.body_ang_vel + eps * t(rng.standard_normal(s.body_ang_vel.shape)),
    )
