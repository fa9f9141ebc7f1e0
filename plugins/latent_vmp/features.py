"""VMP per-frame features ``m_t``, windows of ``2W+1`` frames, heading normalization, standardization.

Per frame (paper Eq. 1, in this order; ``n`` = skeleton DoFs, ``E`` = end effectors)::

    h      1    root height above the ground plane z = 0 (planar root position dropped)
    theta  6    root orientation, 6-D (first two columns of R), in the centre frame's heading
    v      6    root linear (3) then angular (3) velocity, world vectors in the centre frame's heading
    q      n    joint angles (the library's ``dof_pos``)
    qd     n    joint velocities (``dof_vel``: forward differences)
    p      3E   end-effector positions relative to *that frame's own* root position, rotated into
                the centre frame's heading

Heading normalization (paper section 3.2): every frame of the window centred at ``t`` is expressed
in the heading frame ``H_t`` of the centre frame's root (rotation about world z by its yaw,
:func:`mocap.rotations.heading_quat_inv`); the planar root position never enters the features, so
a global yaw rotation plus a planar translation of a clip leaves every window unchanged.

Windows never span two clips; at clip ends the first / last frame is repeated (edge padding,
paper section 3.7). Standardization: per scalar feature, mean and std over every frame of the
dataset (each frame in its own heading frame, i.e. as the centre of its window), the 6 orientation
channels excepted (mean 0, std 1: not standardized, as the paper says).

Everything is computed from a :class:`mocap.motion.library.MotionLibrary`'s packed per-frame
tensors (rows = frames of all clips, clip after clip).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from mocap.rotations import heading_quat_inv, matrix_to_sixd, quat_apply, quat_mul, quat_to_matrix
from mocap.skeleton import Skeleton

GROUPS = ("h", "theta", "v", "q", "qd", "p")


@dataclass(frozen=True)
class FeatureLayout:
    """Where each feature group sits in the per-frame vector of ``dim`` scalars."""

    num_dofs: int
    end_effectors: tuple[str, ...]

    @property
    def sizes(self) -> dict[str, int]:
        n = self.num_dofs
        return {"h": 1, "theta": 6, "v": 6, "q": n, "qd": n, "p": 3 * len(self.end_effectors)}

    @property
    def slices(self) -> dict[str, slice]:
        out, start = {}, 0
        for g, k in self.sizes.items():
            out[g] = slice(start, start + k)
            start += k
        return out

    @property
    def dim(self) -> int:
        return sum(self.sizes.values())

    @property
    def theta(self) -> slice:
        return self.slices["theta"]


def resolve_end_effectors(skeleton: Skeleton, names: list[str] | tuple[str, ...] | None) -> tuple[str, ...]:
    """``names`` checked against the skeleton, or (None) the hands and feet among ``skeleton.end_effectors``
    (bodies whose name contains ``hand`` or ``foot``; all end effectors if none does)."""
    if names is not None:
        for n in names:
            skeleton.body_index(n)  # raises with the valid names
        return tuple(names)
    picked = tuple(n for n in skeleton.end_effectors if "hand" in n or "foot" in n)
    return picked or tuple(skeleton.end_effectors)


def clip_starts(lib) -> Tensor:
    """(C,) packed row of each clip's first frame."""
    n = lib.num_frames.to(torch.long)
    return torch.cumsum(n, 0) - n


def window_rows(lib, centres: Tensor, half: int) -> Tensor:
    """(N, 2W+1) packed rows of the windows centred at packed rows ``centres`` (N,), edge-padded
    within each centre's clip (a window never leaves its clip)."""
    centres = centres.to(torch.long).to(lib.frame_clip.device)
    clip = lib.frame_clip[centres]
    start = clip_starts(lib).to(centres.device)[clip]
    length = lib.num_frames.to(centres.device)[clip]
    local = centres - start
    offs = torch.arange(-half, half + 1, device=centres.device)
    idx = (local[:, None] + offs[None, :]).clamp(min=torch.zeros_like(local)[:, None], max=(length - 1)[:, None])
    return start[:, None] + idx


def window_features(lib, rows: Tensor, ee_index: Tensor, centre: int | None = None) -> Tensor:
    """(N, K, F) heading-normalized features of the frames at packed rows ``rows`` (N, K), in the heading
    frame of column ``centre`` (default: the middle column K // 2). Unstandardized."""
    centre = rows.shape[1] // 2 if centre is None else centre
    root_pos = lib.root_pos[rows]  # (N, K, 3)
    root_rot = lib.root_rot[rows]  # (N, K, 4)
    hinv = heading_quat_inv(lib.root_rot[rows[:, centre]])[:, None, :].expand_as(root_rot)  # (N, K, 4)
    h = root_pos[..., 2:3]
    theta = matrix_to_sixd(quat_to_matrix(quat_mul(hinv, root_rot)))
    v = torch.cat((quat_apply(hinv, lib.body_lin_vel[rows][..., 0, :]), quat_apply(hinv, lib.body_ang_vel[rows][..., 0, :])), -1)
    q = lib.dof_pos[rows]
    qd = lib.dof_vel[rows]
    ee = lib.body_pos[rows][..., ee_index, :] - root_pos[..., None, :]  # (N, K, E, 3)
    p = quat_apply(hinv[..., None, :].expand(*ee.shape[:-1], 4), ee).flatten(-2)
    return torch.cat((h, theta, v, q, qd, p), -1)


def frame_features(lib, ee_index: Tensor) -> Tensor:
    """(total_frames, F): every frame in its own heading frame (the centre of its window)."""
    rows = torch.arange(lib.total_frames, device=lib.root_pos.device)[:, None]
    return window_features(lib, rows, ee_index, centre=0)[:, 0]


def feature_stats(frames: Tensor, layout: FeatureLayout, std_min: float) -> tuple[Tensor, Tensor]:
    """Per-dimension mean and std (population) of ``frames`` (M, F), std clamped to ``std_min``; the
    orientation channels get mean 0 and std 1 (not standardized)."""
    f = frames.double()
    mean = f.mean(0)
    std = f.std(0, unbiased=False).clamp_min(std_min)
    mean[layout.theta] = 0.0
    std[layout.theta] = 1.0
    return mean.to(frames.dtype), std.to(frames.dtype)


def standardize(x: Tensor, mean: Tensor, std: Tensor) -> Tensor:
    """``(x - mean) / std`` over the last dimension (orientation channels have mean 0, std 1)."""
    return (x - mean) / std


def destandardize(z: Tensor, mean: Tensor, std: Tensor) -> Tensor:
    """Inverse of :func:`standardize`."""
    return z * std + mean


__all__ = [
    "GROUPS",
    "FeatureLayout",
    "clip_starts",
    "destandardize",
    "feature_stats",
    "frame_features",
    "resolve_end_effectors",
    "standardize",
    "window_features",
    "window_rows",
]
