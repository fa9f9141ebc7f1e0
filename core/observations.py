"""Observation builders shared by imitators and latent spaces: PHC's proprioception and imitation goals.

Pure batched tensor functions for any skeleton (``B`` bodies, body 0 the root). Everything is
expressed in the **heading frame** of the *simulated* root (PHC, Sec. 3.1: "normalized with
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

from collections.abc import Sequence
from typing import Literal

import torch
from torch import Tensor

from mocap.rotations import heading_quat, heading_quat_inv, quat_apply, quat_to_matrix, quat_to_sixd
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
KEYPOINT_FROM_ROT: tuple[int, ...] = tuple(c for name, _ in KEYPOINT_GOAL_FEATURES for c in range(ROT_GOAL_COLUMNS[name].start, ROT_GOAL_COLUMNS[name].stop))

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


def heading_cos_sin(root_rot: Tensor) -> tuple[Tensor, Tensor]:
    """(N,) cosine and sine of the heading angle of ``root_rot`` (N, 4)
    (:func:`~mocap.rotations.heading_angle` without the ``atan2``): the rotated x axis projected on
    the xy plane, normalized; ``(1, 0)`` when it points straight up or down."""
    w, x, y, z = root_rot.unbind(-1)
    hx = w * w + x * x - y * y - z * z
    hy = 2.0 * (x * y + w * z)
    r = torch.sqrt(hx * hx + hy * hy)
    flat = r <= 1e-12 * (w * w + x * x + y * y + z * z)
    c = torch.where(flat, torch.ones_like(r), hx / torch.where(flat, torch.ones_like(r), r))
    s = torch.where(flat, torch.zeros_like(r), hy / torch.where(flat, torch.ones_like(r), r))
    return c, s


def heading_inv_matrix_t(root_rot: Tensor) -> Tensor:
    """(N, 3, 3) ``R(h^-1)^T``: ``v @ heading_inv_matrix_t(root_rot)[:, None]`` rotates row vectors
    (N, ..., 3) into the heading frame (one batched matmul for any number of vectors)."""
    c, s = heading_cos_sin(root_rot)
    zero, one = torch.zeros_like(c), torch.ones_like(c)
    # R(h^-1) = [[c, s, 0], [-s, c, 0], [0, 0, 1]]; rows of the result are v . (row_i), so the
    # right-multiplied matrix is its transpose
    return torch.stack((torch.stack((c, -s, zero), -1), torch.stack((s, c, zero), -1), torch.stack((zero, zero, one), -1)), -2)


def _to_heading(rt: Tensor, v: Tensor) -> Tensor:
    """Row vectors ``v`` (N, K, 3) in the heading frame given ``rt`` = :func:`heading_inv_matrix_t`."""
    return torch.bmm(v, rt)


def _sixd_columns(sixd: SixD) -> tuple[int, int]:
    if sixd == "zhou":
        return (0, 1)
    if sixd == "tan_norm":
        return (0, 2)
    raise ValueError(f"unknown 6-D convention {sixd!r}; choose one of {', '.join(SIXD_CHOICES)}")


def _check_bodies(state: HumanoidState) -> int:
    if state.body_pos.dim() != 3 or state.body_pos.shape[-1] != 3:
        raise ValueError(f"body_pos must be (N, B, 3), got {tuple(state.body_pos.shape)}")
    return int(state.body_pos.shape[1])


# ------------------------------------------------------------------------------- proprioception
# Implementation note (speed): every heading-frame quantity is a yaw rotation of vectors, so the
# vectors of one observation are gathered into one (N, K, 3) array and rotated by ONE batched
# matmul; a 6-D rotation feature is two columns of a rotation matrix, i.e. two more vectors. The
# quaternion formulas of the module docstring are the specification; tests/test_observations.py
# checks this implementation against them.
def _proprio_from(state: HumanoidState, rt: Tensor, sim_mat: Tensor, sixd: SixD) -> Tensor:
    N, B = state.body_pos.shape[:2]
    cols = _sixd_columns(sixd)
    rel = state.body_pos[:, 1:] - state.root_pos[:, None, :]
    rot = sim_mat[..., list(cols)].transpose(-1, -2).reshape(N, 2 * B, 3)  # per body: column a, column b
    v = torch.cat((rel, rot, state.body_lin_vel, state.body_ang_vel), dim=1)
    return torch.cat((state.root_pos[:, 2:3], _to_heading(rt, v).reshape(N, -1)), dim=-1)


def proprioception(state: HumanoidState, sixd: SixD = "zhou") -> Tensor:
    """PHC's s^p (module doc): (N, 15 B - 2) in the simulated root's heading frame."""
    _check_bodies(state)
    rt = heading_inv_matrix_t(state.root_rot)
    return _proprio_from(state, rt, quat_to_matrix(state.body_rot), sixd)


# ---------------------------------------------------------------------------------- goal terms
def _goal_rot_from(state: HumanoidState, ref_next: HumanoidState, rt: Tensor, sim_mat: Tensor, sixd: SixD) -> Tensor:
    N, B = state.body_pos.shape[:2]
    cols = list(_sixd_columns(sixd))
    ref_mat = quat_to_matrix(ref_next.body_rot)
    # R(h^-1 q^ q^-1 h) e_j = R(h^-1) [R(q^) R(q)^T (R(h) e_j)]; rt = R(h^-1)^T = R(h), so
    # R(h) e_j is column j of rt
    diff = torch.matmul(torch.matmul(ref_mat, sim_mat.transpose(-1, -2)), rt[:, None][..., cols])
    v = torch.cat(
        (
            (ref_next.body_pos - state.body_pos)[:, :, None],
            diff.transpose(-1, -2),
            (ref_next.body_lin_vel - state.body_lin_vel)[:, :, None],
            (ref_next.body_ang_vel - state.body_ang_vel)[:, :, None],
            (ref_next.body_pos - state.root_pos[:, None, :])[:, :, None],
            ref_mat[..., cols].transpose(-1, -2),
        ),
        dim=2,
    )  # (N, B, 8, 3) in the layout order of ROT_GOAL_FEATURES
    return _to_heading(rt, v.reshape(N, 8 * B, 3)).reshape(N, -1)


def imitation_goal_rot(state: HumanoidState, ref_next: HumanoidState, sixd: SixD = "zhou") -> Tensor:
    """PHC's rotation-based goal s^{g-rot} (module doc): (N, 24 B), body-major.

    Args:
        state: the simulated state at time t.
        ref_next: the reference at t + 1 (the same bodies).
        sixd: 6-D convention of the rotation features.
    """
    _check_bodies(state)
    rt = heading_inv_matrix_t(state.root_rot)
    return _goal_rot_from(state, ref_next, rt, quat_to_matrix(state.body_rot), sixd)


def _goal_keypoint_from(state: HumanoidState, ref_next: HumanoidState, rt: Tensor) -> Tensor:
    N, B = state.body_pos.shape[:2]
    v = torch.stack(
        (ref_next.body_pos - state.body_pos, ref_next.body_lin_vel - state.body_lin_vel, ref_next.body_pos - state.root_pos[:, None, :]),
        dim=2,
    )
    return _to_heading(rt, v.reshape(N, 3 * B, 3)).reshape(N, -1)


def imitation_goal_keypoint(state: HumanoidState, ref_next: HumanoidState) -> Tensor:
    """PHC's keypoint-only goal s^{g-kp} (module doc): (N, 9 B), body-major.

    Only reference *positions* and linear velocities are read (a keypoint reference).
    """
    _check_bodies(state)
    return _goal_keypoint_from(state, ref_next, heading_inv_matrix_t(state.root_rot))


def proprioception_and_goal(
    state: HumanoidState,
    ref_next: HumanoidState,
    kind: Literal["rot", "keypoint"] = "rot",
    sixd: SixD = "zhou",
    ahead: Sequence[HumanoidState] = (),
) -> tuple[Tensor, Tensor]:
    """``(proprioception(state, sixd), imitation_goal(state, ref_next, kind, sixd))`` sharing the
    heading rotation and the simulated bodies' rotation matrices (the policy input of every step).

    ``ahead``: later reference frames; the goal is then ``[g(ref_next) | g(ahead[0]) | ...]``, each
    block the same goal against the current simulated state (PHC code's ``fut_tracks`` option)."""
    _check_bodies(state)
    if kind not in ("rot", "keypoint"):
        raise ValueError(f"unknown imitation goal {kind!r}; choose 'rot' or 'keypoint'")
    rt = heading_inv_matrix_t(state.root_rot)
    sim_mat = quat_to_matrix(state.body_rot)
    proprio = _proprio_from(state, rt, sim_mat, sixd)
    goals = [_goal_rot_from(state, r, rt, sim_mat, sixd) if kind == "rot" else _goal_keypoint_from(state, r, rt) for r in (ref_next, *ahead)]
    return proprio, goals[0] if len(goals) == 1 else torch.cat(goals, dim=-1)


def imitation_goal(state: HumanoidState, ref_next: HumanoidState, kind: Literal["rot", "keypoint"] = "rot", sixd: SixD = "zhou") -> Tensor:
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
    "heading_cos_sin",
    "heading_inv_matrix_t",
    "proprioception",
    "proprioception_and_goal",
    "proprioception_dim",
    "rotation_sixd",
    "world_to_heading",
]
