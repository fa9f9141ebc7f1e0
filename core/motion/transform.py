"""Rigid ground-plane transforms of reference frames: turn a clip about the vertical and move it.

A clip recorded in one place and heading can be played anywhere on the floor, facing any way:
rotating every frame about the world z axis and translating it in x and y keeps the motion
physically the same (gravity is along z). Used to start a clip where the humanoid is, the way it
lies or faces (the get-up planner of :mod:`mocap_phc.recovery_planner`).

* :func:`best_yaw`: the rotation about z that brings one orientation closest to another, in closed
  form, and the tilt that is left (the angle no rotation about z can remove);
* :func:`match_first_frames`: of several clips, the one whose first frame lies the way the humanoid
  does (up to a turn about z), and that turn;
* :func:`frames_at_rate`: the velocities of frames scaled, for a clip played faster or slower (or held);
* :func:`yaw_frames`: the frames turned by ``yaw`` about the vertical through ``pivot`` and moved
  so that ``pivot`` lands on ``target`` (heights unchanged); joint angles are unchanged.
"""

from __future__ import annotations

from dataclasses import fields, replace

import torch
from torch import Tensor

from mocap.rotations import quat_apply, quat_conjugate, quat_mul
from mocap.state import MotionFrames


def yaw_quat(yaw: Tensor) -> Tensor:
    """(..., 4) the rotation by ``yaw`` (...) rad about world z, (w, x, y, z)."""
    zero = torch.zeros_like(yaw)
    return torch.stack((torch.cos(0.5 * yaw), zero, zero, torch.sin(0.5 * yaw)), dim=-1)


def best_yaw(target_rot: Tensor, source_rot: Tensor) -> tuple[Tensor, Tensor]:
    """(yaw (N,), residual (N,)) rad: the rotation about world z that, applied to ``source_rot``
    (N, 4), comes closest to ``target_rot`` (N, 4), and the angle left between them.

    With ``d = target ⊗ source⁻¹ = (w, x, y, z)``, ``⟨q_z(ψ) ⊗ source, target⟩ = cos(ψ/2) w + sin(ψ/2) z``,
    largest in absolute value at ``ψ = 2 atan2(z, w)``; the angle left is ``2 acos(√(w² + z²))``."""
    d = quat_mul(target_rot, quat_conjugate(source_rot))
    w, z = d[..., 0], d[..., 3]
    yaw = 2.0 * torch.atan2(z, w)
    yaw = torch.atan2(torch.sin(yaw), torch.cos(yaw))  # wrapped to (-pi, pi]
    residual = 2.0 * torch.acos(torch.sqrt(w * w + z * z).clamp(max=1.0))
    return yaw, residual


def match_first_frames(first_rot: Tensor, clips: Tensor, root_rot: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """For each humanoid orientation ``root_rot`` (N, 4), the candidate clip whose first frame's root
    orientation ``first_rot`` (C, 4) comes closest up to a turn about z (:func:`best_yaw`):
    (clip (N,) taken from ``clips`` (C,), yaw (N,), residual (N,)); ties go to the earlier candidate."""
    n, c = root_rot.shape[0], first_rot.shape[0]
    if c == 0:
        raise ValueError("match_first_frames: no candidate clips")
    yaw, resid = best_yaw(root_rot[:, None].expand(n, c, 4), first_rot[None].to(root_rot).expand(n, c, 4))
    j = resid.argmin(-1)
    rows = torch.arange(n)
    return clips.to(torch.long)[j], yaw[rows, j], resid[rows, j]


def frames_at_rate(frames: MotionFrames, rate: Tensor) -> MotionFrames:
    """``frames`` with every velocity multiplied by ``rate`` (N,): the clip played at that rate (0: held at rest)."""
    vel = {}
    for f in fields(MotionFrames):
        if f.name.endswith("_vel"):
            x = getattr(frames, f.name)
            vel[f.name] = x * rate.to(x).reshape(-1, *([1] * (x.dim() - 1)))
    return replace(frames, **vel, ahead=tuple(frames_at_rate(a, rate) for a in frames.ahead))


def yaw_frames(frames: MotionFrames, yaw: Tensor, pivot: Tensor, target: Tensor) -> MotionFrames:
    """``frames`` (N rows) turned by ``yaw`` (N,) rad about the vertical through ``pivot`` (N, 2 or 3;
    its xy) and moved so that ``pivot`` lands on ``target`` (N, 2 or 3; its xy). Heights, joint
    angles and joint velocities are unchanged; positions, rotations and world velocities are turned.
    ``ahead`` frames get the same transform. ``clip_ids`` and ``times`` are kept."""
    dtype, dev = frames.root_pos.dtype, frames.root_pos.device
    yaw = yaw.to(dev, dtype)
    q = yaw_quat(yaw)
    piv = pivot[..., :2].to(dev, dtype)
    tgt = target[..., :2].to(dev, dtype)

    def lead(x: Tensor, k: int) -> Tensor:  # (N, ...) broadcast to a tensor with k leading dims after N
        return x.reshape(x.shape[0], *([1] * k), *x.shape[1:])

    def turn(v: Tensor) -> Tensor:
        k = v.dim() - 2
        return quat_apply(lead(q, k).expand(*v.shape[:-1], 4), v)

    def place(p: Tensor) -> Tensor:
        k = p.dim() - 2
        rel = p.clone()
        rel[..., :2] = rel[..., :2] - lead(piv, k)
        out = turn(rel)
        out[..., :2] = out[..., :2] + lead(tgt, k)
        return out

    def orient(r: Tensor) -> Tensor:
        k = r.dim() - 2
        return quat_mul(lead(q, k).expand_as(r), r)

    out = replace(
        frames,
        root_pos=place(frames.root_pos),
        root_rot=orient(frames.root_rot),
        root_lin_vel=turn(frames.root_lin_vel),
        root_ang_vel=turn(frames.root_ang_vel),
        body_pos=place(frames.body_pos),
        body_rot=orient(frames.body_rot),
        body_lin_vel=turn(frames.body_lin_vel),
        body_ang_vel=turn(frames.body_ang_vel),
        ahead=tuple(yaw_frames(a, yaw, pivot, target) for a in frames.ahead),
    )
    return out


__all__ = ["best_yaw", "frames_at_rate", "match_first_frames", "yaw_frames", "yaw_quat"]
