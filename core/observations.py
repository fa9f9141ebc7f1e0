"""Observation builders shared by imitators and latent spaces: PHC's proprioception and imitation goals.

Pure batched tensor functions for any skeleton (``B`` bodies, body 0 the root). Everything is
expressed in the **heading frame** of the *simulated* root (PHC, Sec. 3.2: "normalized with
respect to the humanoid's current facing direction and root position"): world vectors are rotated
by ``h^-1`` where ``h = heading_quat(root_rot)`` is the root's yaw-only rotation, and positions
are taken relative to the simulated root. Conventions (z up, wxyz) are those of :mod:`mocap.state`.

Proprioception s^p (PHC code ``compute_humanoid_observations_smpl_max``), ``15 B - 2`` dims
(358 for SMPL's B = 24, 223 for amp's B = 15)::

    [ root height (1) | body positions - root, heading frame, root excluded ((B-1)*3)
      | body rotations h^-1 * q_j as 6-D (B*6) | linear velocities, heading frame (B*3)
      | angular velocities, heading frame (B*3) ]

Rotation goal s^{g-rot} (PHC Eq. before Eq. 2; code ``compute_imitation_observations_v6``), per
body ``j`` with ``^`` the reference at ``t+1`` (the code uses ``t+1`` for every term, including the
angular velocity the paper prints with index ``t``), ``24 B`` dims (576 for B = 24), laid out
body-major ``(N, B, 24)`` flattened::

    [ h^-1 (p^_j - p_j) (3) | sixd(h^-1 (q^_j q_j^-1) h) (6) | h^-1 (v^_j - v_j) (3)
      | h^-1 (w^_j - w_j) (3) | h^-1 (p^_j - p_root) (3) | sixd(h^-1 q^_j) (6) ]

The rotation difference ``q^ q^-1`` is a world-frame rotation; conjugating it by ``h`` (a change
of basis) expresses it in the heading frame, which makes it invariant to a yaw of the world.

Keypoint goal s^{g-kp} (code ``obs_v = 7``): the position difference, linear-velocity difference
and reference position of the rotation goal, ``9 B`` dims (216 for B = 24), body-major
``(N, B, 9)``; :data:`KEYPOINT_FROM_ROT` lists the rotation-goal columns it equals.

6-D rotations (switch ``sixd``): ``"zhou"`` (paper, Zhou et al. 2019) is the first two columns of
the rotation matrix, ``R e_x`` and ``R e_y``; ``"tan_norm"`` (PHC code) is the rotated x axis
("tangent") and z axis ("normal"), columns 0 and 2.
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from mocap.rotations import heading_quat, heading_quat_inv, quat_apply, quat_conjugate, quat_mul, quat_to_matrix, quat_to_sixd
from mocap.state import HumanoidState

SixD = Literal["zhou", "tan_norm"]
SIXD_CHOICES: tuple[str, ...] = ("zhou", "tan_norm")

#: features per body of the rotation goal, in layout order: (name, width)
ROT_GOAL_FEATURES: tuple[tuple[str, int], ...] = (
    ("pos_diff", 3),
    ("rot_diff", 6),
    ("vel_diff", 3),
    ("ang_vel_diff", 3),
    ("ref_pos", 3),
    ("ref_rot", 6),
)
#: features per body of the keypoint goal, in layout order
KEYPOINT_GOAL_FEATURES: tuple[tuple[str, int], ...] = (("pos_diff", 3), ("vel_diff", 3), ("ref_pos", 3))


def _columns(features: tuple[tuple[str, int], ...]) -> dict[str, slice]:
    out, start = {}, 0
    for name, width in features:
        out[name] = slice(start, start + width)
        start += width
    return out


#: per-body column slices of each rotation-goal feature (within the 24 columns of one body)
ROT_GOAL_COLUMNS: dict[str, slice] = _columns(ROT_GOAL_FEATURES)
#: per-body column slices of each keypoint-goal feature (within the 9 columns of one body)
KEYPOINT_GOAL_COLUMNS: dict[str, slice] = _columns(KEYPOINT_GOAL_FEATURES)
#: the rotation-goal columns (per body) that the keypoint goal's 9 columns equal, in order
KEYPOINT_FROM_ROT: tuple[int, ...] = tuple(
    c for name, _ in KEYPOINT_GOAL_FEATURES for c in range(ROT_GOAL_COLUMNS[name].start, ROT_GOAL_COLUMNS[name].stop)
)

ROT_GOAL_PER_BODY = sum(w for _, w in ROT_GOAL_FEATURES)  # 24
KEYPOINT_GOAL_PER_BODY = sum(w for _, w in KEYPOINT_GOAL_FEATURES)  # 9


# ----------------------------------------------------------------------------------- dimensions
def proprioception_dim(num_bodies: int) -> int:
    """``1 + 3 (B-1) + 6 B + 3 B + 3 B = 15 B - 2`` (358 for B = 24)."""
    return 15 * num_bodies - 2


def imitation_goal_rot_dim(num_bodies: int) -> int:
    """``24 B`` (576 for B = 24)."""
    return ROT_GOAL_PER_BODY * num_bodies


def imitation_goal_keypoint_dim(num_bodies: int) -> int:
    """``9 B`` (216 for B = 24)."""
    return KEYPOINT_GOAL_PER_BODY * num_bodies


def imitation_goal_dim(num_bodies: int, kind: Literal["rot", "keypoint"]) -> int:
    return imitation_goal_rot_dim(num_bodies) if kind == "rot" else imitation_goal_keypoint_dim(num_bodies)


# ------------------------------------------------------------------------------------- helpers
def rotation_sixd(q: Tensor, sixd: SixD = "zhou") -> Tensor:
    """6-D representation of rotations ``q`` (..., 4): ``"zhou"`` = columns (0, 1) of R, ``"tan_norm"`` = (0, 2)."""
    if sixd == "zhou":
        return quat_to_sixd(q)
    if sixd == "tan_norm":
        m = quat_to_matrix(q)
        return torch.cat((m[..., :, 0], m[..., :, 2]), dim=-1)
    raise ValueError(f"unknown 6-D convention {sixd!r}; choose one of {', '.join(SIXD_CHOICES)}")


def _heading_inv(state: HumanoidState, num_bodies: int) -> Tensor:
    """(N, B, 4) the inverse heading quaternion of each env's root, repeated per body."""
    h_inv = heading_quat_inv(state.root_rot)
    return h_inv[:, None, :].expand(-1, num_bodies, -1)


def _check_bodies(state: HumanoidState) -> int:
    if state.body_pos.dim() != 3 or state.body_pos.shape[-1] != 3:
        raise ValueError(f"body_pos must be (N, B, 3), got {tuple(state.body_pos.shape)}")
    return int(state.body_pos.shape[1])


# ------------------------------------------------------------------------------- proprioception
def proprioception(state: HumanoidState, sixd: SixD = "zhou") -> Tensor:
    """PHC's s^p (module doc): (N, 15 B - 2) in the simulated root's heading frame."""
    B = _check_bodies(state)
    N = state.body_pos.shape[0]
    h_inv = _heading_inv(state, B)
    root_h = state.root_pos[:, 2:3]
    rel = quat_apply(h_inv[:, 1:], state.body_pos[:, 1:] - state.root_pos[:, None, :])
    rot = rotation_sixd(quat_mul(h_inv, state.body_rot), sixd)
    lin = quat_apply(h_inv, state.body_lin_vel)
    ang = quat_apply(h_inv, state.body_ang_vel)
    return torch.cat((root_h, rel.reshape(N, -1), rot.reshape(N, -1), lin.reshape(N, -1), ang.reshape(N, -1)), dim=-1)


# ---------------------------------------------------------------------------------- goal terms
def imitation_goal_rot(state: HumanoidState, ref_next: HumanoidState, sixd: SixD = "zhou") -> Tensor:
    """PHC's rotation-based goal s^{g-rot} (module doc): (N, 24 B), body-major.

    Args:
        state: the simulated state at time t.
        ref_next: the reference at t + 1 (the same bodies).
        sixd: 6-D convention of the rotation features.
    """
    B = _check_bodies(state)
    N = state.body_pos.shape[0]
    h_inv = _heading_inv(state, B)
    h = quat_conjugate(h_inv)
    pos_diff = quat_apply(h_inv, ref_next.body_pos - state.body_pos)
    rot_world = quat_mul(ref_next.body_rot, quat_conjugate(state.body_rot))
    rot_diff = rotation_sixd(quat_mul(quat_mul(h_inv, rot_world), h), sixd)
    vel_diff = quat_apply(h_inv, ref_next.body_lin_vel - state.body_lin_vel)
    ang_diff = quat_apply(h_inv, ref_next.body_ang_vel - state.body_ang_vel)
    ref_pos = quat_apply(h_inv, ref_next.body_pos - state.root_pos[:, None, :])
    ref_rot = rotation_sixd(quat_mul(h_inv, ref_next.body_rot), sixd)
    return torch.cat((pos_diff, rot_diff, vel_diff, ang_diff, ref_pos, ref_rot), dim=-1).reshape(N, -1)


def imitation_goal_keypoint(state: HumanoidState, ref_next: HumanoidState) -> Tensor:
    """PHC's keypoint-only goal s^{g-kp} (module doc): (N, 9 B), body-major.

    Only reference *positions* and linear velocities are read (a keypoint reference).
    """
    B = _check_bodies(state)
    N = state.body_pos.shape[0]
    h_inv = _heading_inv(state, B)
    pos_diff = quat_apply(h_inv, ref_next.body_pos - state.body_pos)
    vel_diff = quat_apply(h_inv, ref_next.body_lin_vel - state.body_lin_vel)
    ref_pos = quat_apply(h_inv, ref_next.body_pos - state.root_pos[:, None, :])
    return torch.cat((pos_diff, vel_diff, ref_pos), dim=-1).reshape(N, -1)


def imitation_goal(
    state: HumanoidState, ref_next: HumanoidState, kind: Literal["rot", "keypoint"] = "rot", sixd: SixD = "zhou"
) -> Tensor:
    """:func:`imitation_goal_rot` or :func:`imitation_goal_keypoint` by ``kind``."""
    if kind == "rot":
        return imitation_goal_rot(state, ref_next, sixd)
    if kind == "keypoint":
        return imitation_goal_keypoint(state, ref_next)
    raise ValueError(f"unknown imitation goal {kind!r}; choose 'rot' or 'keypoint'")


def world_to_heading(root_rot: Tensor, v: Tensor) -> Tensor:
    """Express world vectors ``v`` (N, ..., 3) in the heading frame of ``root_rot`` (N, 4)."""
    h_inv = heading_quat_inv(root_rot)
    return quat_apply(h_inv.reshape(h_inv.shape[0], *([1] * (v.dim() - 2)), 4), v)


def heading_to_world(root_rot: Tensor, v: Tensor) -> Tensor:
    """Inverse of :func:`world_to_heading`."""
    h = heading_quat(root_rot)
    return quat_apply(h.reshape(h.shape[0], *([1] * (v.dim() - 2)), 4), v)


__all__ = [
    "KEYPOINT_FROM_ROT",
    "KEYPOINT_GOAL_COLUMNS",
    "KEYPOINT_GOAL_FEATURES",
    "ROT_GOAL_COLUMNS",
    "ROT_GOAL_FEATURES",
    "SIXD_CHOICES",
    "heading_to_world",
    "imitation_goal",
    "imitation_goal_dim",
    "imitation_goal_keypoint",
    "imitation_goal_keypoint_dim",
    "imitation_goal_rot",
    "imitation_goal_rot_dim",
    "proprioception",
    "proprioception_dim",
    "rotation_sixd",
    "world_to_heading",
]
