"""Forward kinematics of a :class:`mocap.skeleton.Skeleton` in torch, batched over leading dims.

Model (see :mod:`mocap.skeleton`): at rest every body frame is aligned with the world frame and
body ``j``'s origin sits at ``offset_j`` in its parent's frame. A joint made of hinges
``h0, h1, ...`` (axes ``n_k`` in the body frame) has the local rotation
``L_j = R_{n0}(t0) R_{n1}(t1) ...`` (intrinsic order, as MuJoCo composes several hinges of one
body); a fixed joint has ``L_j = I``. With ``p`` the parent of ``j``::

    rot_j = rot_p * L_j
    pos_j = pos_p + rot_p offset_j

and body 0 (the free root) takes ``root_pos`` and ``root_rot``. Quaternions are wxyz.

Per-skeleton index tables are computed once and cached on the skeleton object (weakly: the
entry goes away with the skeleton), with their tensors cached per dtype and device.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from mocap.rotations import quat_apply, quat_from_axis_angle, quat_mul, quat_standardize, quat_to_euler
from mocap.skeleton import Skeleton

__all__ = [
    "dofs_from_local_rotations",
    "forward_kinematics",
    "forward_kinematics_dofs",
    "local_rotations_from_dofs",
]


# --------------------------------------------------------------------------------------------
# per-skeleton tables


@dataclass
class _Level:
    """Bodies at one depth of the tree: their ids, their parents' positions in the previous level."""

    bodies: np.ndarray  # (n,) body indices
    parent_pos: np.ndarray  # (n,) index into the previous level's bodies
    offsets: np.ndarray  # (n, 3)


@dataclass
class _Tables:
    num_bodies: int
    num_dofs: int
    hinge_axes: np.ndarray  # (D, 3) unit axes in DoF order
    # local rotations: per hinge count k, the joints (local index j-1) and their DoF indices (n, k)
    groups: list[tuple[int, np.ndarray, np.ndarray]]
    group_inverse: np.ndarray  # (B-1,) position of each joint in the concatenated groups
    levels: list[_Level]
    level_inverse: np.ndarray  # (B,) position of each body in the concatenated levels
    # inverse kinematics (DoFs from local rotations)
    ball_joints: np.ndarray  # (nb,) local joint index of 3-hinge joints
    ball_dofs: np.ndarray  # (nb, 3)
    ball_axes: np.ndarray  # (nb, 3, 3) rows = hinge axes
    hinge_joints: np.ndarray  # (nh,) local joint index of 1-hinge joints
    hinge_dofs: np.ndarray  # (nh,)
    dof_inverse: np.ndarray  # (D,) position of each DoF in [ball dofs..., hinge dofs...]
    inverse_error: str | None  # why dofs_from_local_rotations cannot handle this skeleton
    tensors: dict[tuple[torch.dtype, torch.device], dict[str, Tensor]] = field(default_factory=dict)

    def get(self, dtype: torch.dtype, device: torch.device) -> dict[str, Tensor]:
        key = (dtype, device)
        out = self.tensors.get(key)
        if out is None:
            as_float = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
            as_long = lambda a: torch.as_tensor(a, dtype=torch.long, device=device)  # noqa: E731
            out = {
                "hinge_axes": as_float(self.hinge_axes),
                "group_inverse": as_long(self.group_inverse),
                "level_inverse": as_long(self.level_inverse),
                "ball_joints": as_long(self.ball_joints),
                "ball_axes": as_float(self.ball_axes),
                "hinge_joints": as_long(self.hinge_joints),
                "hinge_axis": as_float(self.hinge_axes[self.hinge_dofs]),
                "dof_inverse": as_long(self.dof_inverse),
            }
            for k, _joints, dofs in self.groups:
                out[f"group{k}_dofs"] = as_long(dofs)
            for i, level in enumerate(self.levels):
                out[f"level{i}_joints"] = as_long(level.bodies - 1)
                out[f"level{i}_parents"] = as_long(level.parent_pos)
                out[f"level{i}_offsets"] = as_float(level.offsets)
            self.tensors[key] = out
        return out


_CACHE: dict[int, tuple[weakref.ref, _Tables]] = {}


def _tables(skeleton: Skeleton) -> _Tables:
    entry = _CACHE.get(id(skeleton))
    if entry is not None and entry[0]() is skeleton:
        return entry[1]
    tables = _build_tables(skeleton)
    key = id(skeleton)

    def _drop(ref: weakref.ref, key: int = key) -> None:
        current = _CACHE.get(key)
        if current is not None and current[0] is ref:
            del _CACHE[key]

    _CACHE[key] = (weakref.ref(skeleton, _drop), tables)
    return tables


def _unit(v: tuple[float, float, float]) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(a)
    if not n > 0:
        raise ValueError(f"hinge axis {v!r} has zero length")
    return a / n


def _build_tables(skeleton: Skeleton) -> _Tables:
    bodies = skeleton.bodies
    nb = len(bodies)
    if nb == 0 or bodies[0].parent != -1:
        raise ValueError(f"skeleton {skeleton.name!r}: body 0 must be the root (parent -1)")
    for i, body in enumerate(bodies[1:], start=1):
        if not 0 <= body.parent < i:
            raise ValueError(f"skeleton {skeleton.name!r}: body {body.name!r} has parent {body.parent}, must precede it")
    hinge_axes = np.array([_unit(h.axis) for h in skeleton.hinges], dtype=np.float64).reshape(-1, 3)
    slices = skeleton.dof_slices

    # joints grouped by hinge count
    by_count: dict[int, list[int]] = {}
    for j in range(1, nb):
        by_count.setdefault(len(bodies[j].joint.hinges), []).append(j)
    groups: list[tuple[int, np.ndarray, np.ndarray]] = []
    order: list[int] = []
    for k in sorted(by_count):
        joints = by_count[k]
        dofs = np.array([list(range(slices[j].start, slices[j].stop)) for j in joints], dtype=np.int64).reshape(len(joints), k)
        groups.append((k, np.array(joints) - 1, dofs))
        order.extend(j - 1 for j in joints)
    group_inverse = np.argsort(np.array(order, dtype=np.int64)) if order else np.zeros(0, dtype=np.int64)

    # tree levels (depth), parents of level L are all in level L-1
    depth = [0] * nb
    for j in range(1, nb):
        depth[j] = depth[bodies[j].parent] + 1
    levels: list[_Level] = []
    where: dict[int, int] = {0: 0}  # body -> position within its level
    level_order = [0]
    for d in range(1, max(depth) + 1):
        ids = [j for j in range(nb) if depth[j] == d]
        for pos, j in enumerate(ids):
            where[j] = pos
        levels.append(
            _Level(
                bodies=np.array(ids, dtype=np.int64),
                parent_pos=np.array([where[bodies[j].parent] for j in ids], dtype=np.int64),
                offsets=np.array([bodies[j].offset for j in ids], dtype=np.float64).reshape(-1, 3),
            )
        )
        level_order.extend(ids)
    level_inverse = np.argsort(np.array(level_order, dtype=np.int64))

    # inverse: ball (3 hinges, orthonormal axes) and single hinges
    ball_joints, ball_dofs, ball_axes, hinge_joints, hinge_dofs = [], [], [], [], []
    inverse_error = None
    for j in range(1, nb):
        hinges = bodies[j].joint.hinges
        sl = slices[j]
        if len(hinges) == 3:
            axes = hinge_axes[sl]
            if np.abs(axes @ axes.T - np.eye(3)).max() > 1e-6:
                inverse_error = inverse_error or f"ball joint of body {bodies[j].name!r} has non-orthogonal hinge axes"
            ball_joints.append(j - 1)
            ball_dofs.append(list(range(sl.start, sl.stop)))
            ball_axes.append(axes)
        elif len(hinges) == 1:
            hinge_joints.append(j - 1)
            hinge_dofs.append(sl.start)
        elif len(hinges) != 0:
            inverse_error = inverse_error or f"joint of body {bodies[j].name!r} has {len(hinges)} hinges (only 0, 1 or 3 are invertible)"
    dof_order = [d for row in ball_dofs for d in row] + hinge_dofs
    return _Tables(
        num_bodies=nb,
        num_dofs=skeleton.num_dofs,
        hinge_axes=hinge_axes,
        groups=groups,
        group_inverse=group_inverse,
        levels=levels,
        level_inverse=level_inverse,
        ball_joints=np.array(ball_joints, dtype=np.int64),
        ball_dofs=np.array(ball_dofs, dtype=np.int64).reshape(-1, 3),
        ball_axes=np.array(ball_axes, dtype=np.float64).reshape(-1, 3, 3),
        hinge_joints=np.array(hinge_joints, dtype=np.int64),
        hinge_dofs=np.array(hinge_dofs, dtype=np.int64),
        dof_inverse=np.argsort(np.array(dof_order, dtype=np.int64)) if dof_order else np.zeros(0, dtype=np.int64),
        inverse_error=inverse_error,
    )


# --------------------------------------------------------------------------------------------
# DoFs <-> local rotations


def local_rotations_from_dofs(skeleton: Skeleton, dof_pos: Tensor) -> Tensor:
    """Local rotation of bodies ``1..B-1`` relative to their parent, (..., B-1, 4) wxyz.

    ``L_j = q(n0, t0) * q(n1, t1) * ...`` over the joint's hinges in order (``R_{n0}(t0)
    R_{n1}(t1) ...``); identity for fixed joints. ``dof_pos`` is (..., D) in the skeleton's DoF
    order.
    """
    tab = _tables(skeleton)
    if dof_pos.shape[-1] != tab.num_dofs:
        raise ValueError(f"dof_pos has {dof_pos.shape[-1]} DoFs, skeleton {skeleton.name!r} has {tab.num_dofs}")
    t = tab.get(dof_pos.dtype, dof_pos.device)
    batch = dof_pos.shape[:-1]
    hinge_q = quat_from_axis_angle(t["hinge_axes"], dof_pos)  # (..., D, 4)
    parts = []
    for k, joints, _ in tab.groups:
        if k == 0:
            ident = torch.zeros(len(joints), 4, dtype=dof_pos.dtype, device=dof_pos.device)
            ident[:, 0] = 1.0
            parts.append(ident.expand(*batch, len(joints), 4))
            continue
        dofs = t[f"group{k}_dofs"]  # (n, k)
        q = hinge_q.index_select(-2, dofs[:, 0])
        for i in range(1, k):
            q = quat_mul(q, hinge_q.index_select(-2, dofs[:, i]))
        parts.append(q)
    if not parts:
        return dof_pos.new_zeros(*batch, 0, 4)
    return torch.cat(parts, dim=-2).index_select(-2, t["group_inverse"])


def dofs_from_local_rotations(skeleton: Skeleton, joint_rot: Tensor) -> Tensor:
    """Hinge angles (..., D) whose local rotations best match ``joint_rot`` (..., B-1, 4).

    * Ball joints (3 hinges with orthonormal axes ``n0, n1, n2``): the exact decomposition
      ``L = R_{n0}(t0) R_{n1}(t1) R_{n2}(t2)`` by :func:`mocap.rotations.quat_to_euler`, with
      ``t1`` in ``[-pi/2, pi/2]`` and ``t0, t2`` in ``[-pi, pi]`` (principal range; joint limits
      are not applied).
    * Single hinges (axis ``n``): the twist of the swing-twist decomposition ``L = swing * twist``,
      ``t = 2 atan2(u.n, w)`` after standardizing ``w >= 0`` (in ``[-pi, pi]``). The swing
      (rotation about any axis orthogonal to ``n``) cannot be represented by the hinge and is
      lost: ``local_rotations_from_dofs`` of the result differs from ``joint_rot`` by it.
    * Fixed joints are ignored.

    Raises ``ValueError`` for skeletons with 2-hinge (or more than 3) joints or non-orthogonal
    ball axes.
    """
    tab = _tables(skeleton)
    if tab.inverse_error is not None:
        raise ValueError(f"skeleton {skeleton.name!r}: {tab.inverse_error}")
    if joint_rot.shape[-2] != tab.num_bodies - 1:
        raise ValueError(f"joint_rot has {joint_rot.shape[-2]} joints, skeleton {skeleton.name!r} has {tab.num_bodies - 1}")
    t = tab.get(joint_rot.dtype, joint_rot.device)
    batch = joint_rot.shape[:-2]
    parts = []
    if len(tab.ball_joints):
        q = joint_rot.index_select(-2, t["ball_joints"])  # (..., nb, 4)
        parts.append(quat_to_euler(q, t["ball_axes"]).flatten(-2))  # (..., nb * 3)
    if len(tab.hinge_joints):
        q = quat_standardize(joint_rot.index_select(-2, t["hinge_joints"]))  # (..., nh, 4)
        along = (q[..., 1:] * t["hinge_axis"]).sum(-1)
        parts.append(2.0 * torch.atan2(along, q[..., 0]))
    if not parts:
        return joint_rot.new_zeros(*batch, 0)
    return torch.cat(parts, dim=-1).index_select(-1, t["dof_inverse"])


# --------------------------------------------------------------------------------------------
# forward kinematics


def forward_kinematics(skeleton: Skeleton, root_pos: Tensor, root_rot: Tensor, joint_rot: Tensor) -> tuple[Tensor, Tensor]:
    """World positions (..., B, 3) and rotations (..., B, 4) of every body.

    ``root_pos`` (..., 3), ``root_rot`` (..., 4) and ``joint_rot`` (..., B-1, 4) (local
    rotations of bodies 1..B-1) broadcast over their leading dims. Bodies are processed one tree
    depth at a time: ``rot_j = rot_p * L_j``, ``pos_j = pos_p + rot_p offset_j``.
    """
    tab = _tables(skeleton)
    if joint_rot.shape[-2] != tab.num_bodies - 1:
        raise ValueError(f"joint_rot has {joint_rot.shape[-2]} joints, skeleton {skeleton.name!r} has {tab.num_bodies - 1}")
    t = tab.get(joint_rot.dtype, joint_rot.device)
    batch = torch.broadcast_shapes(root_pos.shape[:-1], root_rot.shape[:-1], joint_rot.shape[:-2])
    joint_rot = joint_rot.expand(*batch, *joint_rot.shape[-2:])
    rot = root_rot.to(joint_rot.dtype).expand(*batch, 4)[..., None, :]
    pos = root_pos.to(joint_rot.dtype).expand(*batch, 3)[..., None, :]
    rots, poss = [rot], [pos]
    for i in range(len(tab.levels)):
        parent_idx = t[f"level{i}_parents"]
        parent_rot = rot.index_select(-2, parent_idx)
        parent_pos = pos.index_select(-2, parent_idx)
        rot = quat_mul(parent_rot, joint_rot.index_select(-2, t[f"level{i}_joints"]))
        pos = parent_pos + quat_apply(parent_rot, t[f"level{i}_offsets"])
        rots.append(rot)
        poss.append(pos)
    inv = t["level_inverse"]
    return torch.cat(poss, dim=-2).index_select(-2, inv), torch.cat(rots, dim=-2).index_select(-2, inv)


def forward_kinematics_dofs(skeleton: Skeleton, root_pos: Tensor, root_rot: Tensor, dof_pos: Tensor) -> tuple[Tensor, Tensor]:
    """:func:`forward_kinematics` from hinge angles (..., D) instead of local rotations."""
    return forward_kinematics(skeleton, root_pos, root_rot, local_rotations_from_dofs(skeleton, dof_pos))
