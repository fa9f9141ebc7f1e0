"""Rotation utilities on batched torch tensors.

Conventions (see :mod:`mocap.state`): quaternions are ``(w, x, y, z)``, unit-norm, and a rotation
``q`` maps body-frame vectors to the world frame, ``v_world = q * v_body * conj(q)``. The world is
z up, x forward, y left. Every function works on arbitrary leading (batch) dimensions, float32 or
float64, on any device, and is differentiable where the underlying map is smooth (small-angle
branches use Taylor series so that gradients stay finite at the identity).

Notation used in the docstrings: ``q = (w, u)`` with ``u = (x, y, z)``; ``R(q)`` its 3x3 matrix;
``R_e(t)`` the rotation by angle ``t`` about unit axis ``e``; ``exp``/``log`` the maps between a
rotation vector ``r = angle * axis`` and a quaternion, ``exp(r) = (cos(|r|/2), sin(|r|/2) r/|r|)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

__all__ = [
    "angular_velocity",
    "heading_angle",
    "heading_quat",
    "heading_quat_inv",
    "matrix_to_quat",
    "matrix_to_sixd",
    "quat_angle",
    "quat_angle_between",
    "quat_apply",
    "quat_conjugate",
    "quat_from_axis_angle",
    "quat_from_euler",
    "quat_from_rotvec",
    "quat_identity",
    "quat_mul",
    "quat_normalize",
    "quat_slerp",
    "quat_standardize",
    "quat_to_euler",
    "quat_to_matrix",
    "quat_to_rotvec",
    "quat_to_sixd",
    "sixd_to_matrix",
    "unwrap_angles",
]


# --------------------------------------------------------------------------------------------
# small helpers


def _cross(a: Tensor, b: Tensor) -> Tensor:
    """``a x b`` over the last dimension, broadcasting the leading ones."""
    ax, ay, az = a.unbind(-1)
    bx, by, bz = b.unbind(-1)
    return torch.stack((ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx), dim=-1)


def _dot(a: Tensor, b: Tensor) -> Tensor:
    return (a * b).sum(-1)


def _as_like(x: Tensor | float | Sequence[float], ref: Tensor) -> Tensor:
    """``x`` as a tensor with ``ref``'s dtype and device."""
    return torch.as_tensor(x, dtype=ref.dtype, device=ref.device)


def _float_dtype(*xs: object) -> torch.dtype:
    for x in xs:
        if isinstance(x, Tensor) and x.is_floating_point():
            return x.dtype
    return torch.get_default_dtype()


# --------------------------------------------------------------------------------------------
# basic quaternion algebra


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``); leading dims broadcast.

    ``(aw, av) * (bw, bv) = (aw bw - av.bv, aw bv + bw av + av x bv)``, so that
    ``R(a * b) = R(a) R(b)``.
    """
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def quat_conjugate(q: Tensor) -> Tensor:
    """``conj(w, u) = (w, -u)``: the inverse rotation of a unit quaternion."""
    return torch.cat((q[..., :1], -q[..., 1:]), dim=-1)


def quat_normalize(q: Tensor, eps: float = 1e-12) -> Tensor:
    """``q / max(|q|, eps)``."""
    return q / torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min(eps)


def quat_standardize(q: Tensor) -> Tensor:
    """The representative with ``w >= 0`` (``q`` and ``-q`` are the same rotation)."""
    return torch.where(q[..., :1] < 0, -q, q)


def quat_identity(
    shape: int | Sequence[int] | torch.Size = (),
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Tensor:
    """Identity quaternions ``(1, 0, 0, 0)`` of shape ``(*shape, 4)``."""
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    q = torch.zeros(*shape, 4, dtype=dtype, device=device)
    q[..., 0] = 1.0
    return q


def quat_apply(q: Tensor, v: Tensor) -> Tensor:
    """Rotate 3-vectors: ``R(q) v = v + 2 w (u x v) + 2 u x (u x v)`` (``q`` unit; dims broadcast)."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


# --------------------------------------------------------------------------------------------
# axis-angle / rotation vectors


def quat_from_axis_angle(axis: Tensor | Sequence[float], angle: Tensor | float) -> Tensor:
    """``(cos(angle/2), sin(angle/2) axis/|axis|)``; ``axis`` (..., 3), ``angle`` (...), broadcast."""
    dtype = _float_dtype(axis, angle)
    device = next((x.device for x in (axis, angle) if isinstance(x, Tensor)), None)
    ax = torch.as_tensor(axis, dtype=dtype, device=device)
    ang = torch.as_tensor(angle, dtype=dtype, device=device)
    ax = ax / torch.linalg.vector_norm(ax, dim=-1, keepdim=True)
    shape = torch.broadcast_shapes(ax.shape[:-1], ang.shape)
    half = 0.5 * ang.expand(shape)
    return torch.cat((torch.cos(half)[..., None], torch.sin(half)[..., None] * ax.expand(*shape, 3)), dim=-1)


def quat_from_rotvec(rv: Tensor) -> Tensor:
    """``exp(r) = (cos(a/2), sin(a/2)/a * r)`` with ``a = |r|``.

    For ``a < 1e-3`` the Taylor series ``cos(a/2) = 1 - a^2/8 + a^4/384`` and
    ``sin(a/2)/a = 1/2 - a^2/48 + a^4/3840`` is used (exact to rounding, smooth gradient at 0).
    """
    a2 = _dot(rv, rv)
    small = a2 < 1e-6
    a = torch.sqrt(torch.where(small, torch.ones_like(a2), a2))
    half = 0.5 * a
    w = torch.where(small, 1.0 - a2 / 8.0 + a2 * a2 / 384.0, torch.cos(half))
    k = torch.where(small, 0.5 - a2 / 48.0 + a2 * a2 / 3840.0, torch.sin(half) / a)
    return torch.cat((w[..., None], k[..., None] * rv), dim=-1)


def quat_to_rotvec(q: Tensor) -> Tensor:
    """``log(q)``: ``axis * angle`` with angle in ``[0, pi]`` (``q`` is first standardized to ``w >= 0``).

    With ``s = |u|``: ``angle = 2 atan2(s, w)`` and ``r = angle / s * u``. For ``s < 1e-3`` the
    factor uses ``2 atan2(s, w) / s = (2/w) (1 - r^2/3 + r^4/5)``, ``r = s/w``.
    """
    q = quat_standardize(q)
    w = q[..., 0]
    u = q[..., 1:]
    s2 = _dot(u, u)
    small = s2 < 1e-6
    s = torch.sqrt(torch.where(small, torch.ones_like(s2), s2))
    w_safe = torch.where(small, w, torch.ones_like(w))  # w ~ 1 on the small branch
    r2 = s2 / (w_safe * w_safe)
    factor = torch.where(
        small,
        2.0 / w_safe * (1.0 - r2 / 3.0 + r2 * r2 / 5.0),
        2.0 * torch.atan2(s, w) / s,
    )
    return factor[..., None] * u


# --------------------------------------------------------------------------------------------
# matrices and the 6-D representation


def quat_to_matrix(q: Tensor) -> Tensor:
    """``R(q)`` (..., 3, 3); with ``n = 2/|q|^2`` (so a slightly non-unit ``q`` still gives a rotation
    of the normalized quaternion)::

        [[1 - n(y²+z²),  n(xy - wz),    n(xz + wy)],
         [n(xy + wz),    1 - n(x²+z²),  n(yz - wx)],
         [n(xz - wy),    n(yz + wx),    1 - n(x²+y²)]]
    """
    w, x, y, z = q.unbind(-1)
    n = 2.0 / _dot(q, q)
    xx, yy, zz = n * x * x, n * y * y, n * z * z
    xy, xz, yz = n * x * y, n * x * z, n * y * z
    wx, wy, wz = n * w * x, n * w * y, n * w * z
    rows = (
        torch.stack((1.0 - yy - zz, xy - wz, xz + wy), dim=-1),
        torch.stack((xy + wz, 1.0 - xx - zz, yz - wx), dim=-1),
        torch.stack((xz - wy, yz + wx, 1.0 - xx - yy), dim=-1),
    )
    return torch.stack(rows, dim=-2)


def matrix_to_quat(m: Tensor) -> Tensor:
    """Unit quaternion (``w >= 0``) of a rotation matrix (..., 3, 3), Shepperd's method.

    Four candidate formulas, each dividing by the largest of ``4w², 4x², 4y², 4z²``, i.e. picking
    the largest of ``trace, m00, m11, m22``:

    * trace: ``w = sqrt(1+tr)/2``, ``(x, y, z) = (m21-m12, m02-m20, m10-m01) / 4w``;
    * m00:   ``x = sqrt(1+m00-m11-m22)/2``, ``(w, y, z) = (m21-m12, m01+m10, m02+m20) / 4x``;
    * m11:   ``y = sqrt(1-m00+m11-m22)/2``, ``(w, x, z) = (m02-m20, m01+m10, m12+m21) / 4y``;
    * m22:   ``z = sqrt(1-m00-m11+m22)/2``, ``(w, x, y) = (m10-m01, m02+m20, m12+m21) / 4z``.

    The result is normalized (absorbing a slightly non-orthogonal input) and standardized.
    """
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    tr = m00 + m11 + m22
    # 2 * (the large component) for each branch; clamped so that unused branches stay finite
    r = torch.sqrt(torch.stack((1.0 + tr, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22), dim=-1).clamp_min(1e-12))
    cands = torch.stack(
        (
            torch.stack((r[..., 0] * r[..., 0], m21 - m12, m02 - m20, m10 - m01), dim=-1),
            torch.stack((m21 - m12, r[..., 1] * r[..., 1], m01 + m10, m02 + m20), dim=-1),
            torch.stack((m02 - m20, m01 + m10, r[..., 2] * r[..., 2], m12 + m21), dim=-1),
            torch.stack((m10 - m01, m02 + m20, m12 + m21, r[..., 3] * r[..., 3]), dim=-1),
        ),
        dim=-2,
    ) / (2.0 * r[..., None])  # row i is candidate i: (4 c_i^2, ...) / (4 c_i) with r = 2 c_i
    best = torch.argmax(torch.stack((tr, m00, m11, m22), dim=-1), dim=-1)
    q = torch.gather(cands, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    return quat_standardize(quat_normalize(q))


def matrix_to_sixd(m: Tensor) -> Tensor:
    """6-D representation (Zhou et al. 2019): the first two columns of ``m``, ``(c0, c1)`` -> (..., 6)."""
    return torch.cat((m[..., :, 0], m[..., :, 1]), dim=-1)


def sixd_to_matrix(x: Tensor) -> Tensor:
    """Rotation matrix from any 6-D vector ``(a1, a2)`` by Gram-Schmidt.

    ``b1 = a1/|a1|``, ``b2 = (a2 - (b1.a2) b1) / |...|``, ``b3 = b1 x b2``; columns ``(b1, b2, b3)``.
    """
    a1, a2 = x[..., :3], x[..., 3:]
    b1 = a1 / torch.linalg.vector_norm(a1, dim=-1, keepdim=True).clamp_min(1e-12)
    b2 = a2 - _dot(b1, a2)[..., None] * b1
    b2 = b2 / torch.linalg.vector_norm(b2, dim=-1, keepdim=True).clamp_min(1e-12)
    b3 = _cross(b1, b2)
    return torch.stack((b1, b2, b3), dim=-1)


def quat_to_sixd(q: Tensor) -> Tensor:
    """``matrix_to_sixd(quat_to_matrix(q))``: first two columns of ``R(q)`` (..., 6)."""
    return matrix_to_sixd(quat_to_matrix(q))


# --------------------------------------------------------------------------------------------
# angles, interpolation, velocities


def quat_angle(q: Tensor) -> Tensor:
    """Rotation angle in ``[0, pi]``: ``2 atan2(|u|, |w|)`` (accurate near 0 and pi)."""
    return 2.0 * torch.atan2(torch.linalg.vector_norm(q[..., 1:], dim=-1), q[..., 0].abs())


def quat_angle_between(a: Tensor, b: Tensor) -> Tensor:
    """Geodesic distance on SO(3): ``quat_angle(conj(a) * b)`` in ``[0, pi]``."""
    return quat_angle(quat_mul(quat_conjugate(a), b))


def quat_slerp(q0: Tensor, q1: Tensor, t: Tensor | float) -> Tensor:
    """Spherical linear interpolation along the shortest path; ``t`` broadcasts with ``q0.shape[:-1]``.

    ``q1`` is negated if ``q0.q1 < 0``; with ``theta`` the angle between the 4-vectors,
    ``theta = 2 atan2(|q0 - q1|, |q0 + q1|)``,
    ``slerp = sin((1-t) theta)/sin(theta) q0 + sin(t theta)/sin(theta) q1``; for ``theta < 1e-4``
    the weights use ``sin(k theta)/sin(theta) = k (1 + (1 - k^2) theta^2 / 6)``. The result is
    renormalized. ``t = 0`` gives ``q0``, ``t = 1`` gives ``±q1``.
    """
    t = torch.as_tensor(t, dtype=q0.dtype, device=q0.device)[..., None]
    q1 = torch.where(_dot(q0, q1)[..., None] < 0, -q1, q1)
    theta = 2.0 * torch.atan2(
        torch.linalg.vector_norm(q0 - q1, dim=-1, keepdim=True),
        torch.linalg.vector_norm(q0 + q1, dim=-1, keepdim=True),
    )
    small = theta < 1e-4
    theta_safe = torch.where(small, torch.ones_like(theta), theta)
    sin_t = torch.sin(theta_safe)
    k0, k1 = 1.0 - t, t
    th2 = theta * theta
    w0 = torch.where(small, k0 * (1.0 + (1.0 - k0 * k0) * th2 / 6.0), torch.sin(k0 * theta_safe) / sin_t)
    w1 = torch.where(small, k1 * (1.0 + (1.0 - k1 * k1) * th2 / 6.0), torch.sin(k1 * theta_safe) / sin_t)
    return quat_normalize(w0 * q0 + w1 * q1)


def angular_velocity(q0: Tensor, q1: Tensor, dt: Tensor | float) -> Tensor:
    """World-frame angular velocity taking ``q0`` to ``q1`` in ``dt``: ``log(q1 * conj(q0)) / dt``.

    ``q1 = exp(omega dt) * q0`` for a constant world-frame rate ``omega`` (shortest path, so
    ``|omega| dt`` must stay below pi). ``dt`` is a scalar or broadcasts with ``q0.shape[:-1]``.
    """
    rv = quat_to_rotvec(quat_mul(q1, quat_conjugate(q0)))
    dt = torch.as_tensor(dt, dtype=rv.dtype, device=rv.device)
    return rv / dt[..., None]


# --------------------------------------------------------------------------------------------
# heading (yaw about world z)


def heading_angle(q: Tensor) -> Tensor:
    """Yaw of the rotated x axis projected on the xy plane, in ``(-pi, pi]``.

    ``R(q) e_x = (w²+x²-y²-z², 2(xy + wz), 2(xz - wy))`` (times ``|q|²``), heading =
    ``atan2(2(xy + wz), w²+x²-y²-z²)``; 0 when the x axis points straight up or down.
    """
    w, x, y, z = q.unbind(-1)
    return torch.atan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)


def heading_quat(q: Tensor) -> Tensor:
    """Rotation about world z by the heading: ``(cos(h/2), 0, 0, sin(h/2))``."""
    half = 0.5 * heading_angle(q)
    zero = torch.zeros_like(half)
    return torch.stack((torch.cos(half), zero, zero, torch.sin(half)), dim=-1)


def heading_quat_inv(q: Tensor) -> Tensor:
    """Inverse heading rotation ``(cos(h/2), 0, 0, -sin(h/2))``; ``quat_apply(heading_quat_inv(root), v)``
    expresses a world vector in the heading frame."""
    half = 0.5 * heading_angle(q)
    zero = torch.zeros_like(half)
    return torch.stack((torch.cos(half), zero, zero, -torch.sin(half)), dim=-1)


# --------------------------------------------------------------------------------------------
# Euler angles about arbitrary orthonormal axes


def _axes_tensor(axes: Tensor | Sequence[Sequence[float]], ref: Tensor) -> Tensor:
    """Axes as a (..., 3, 3) tensor whose rows are the axes; python input is checked and normalized."""
    if isinstance(axes, Tensor):
        return axes.to(dtype=ref.dtype, device=ref.device)
    rows = [[float(c) for c in a] for a in axes]
    if len(rows) != 3 or any(len(r) != 3 for r in rows):
        raise ValueError(f"axes must be three 3-vectors, got {axes!r}")
    norms = [math.sqrt(sum(c * c for c in r)) for r in rows]
    if min(norms) == 0.0:
        raise ValueError(f"axes must be non-zero, got {axes!r}")
    rows = [[c / n for c in r] for r, n in zip(rows, norms)]
    for i in range(3):
        for j in range(i + 1, 3):
            if abs(sum(a * b for a, b in zip(rows[i], rows[j]))) > 1e-6:
                raise ValueError(f"Euler axes must be mutually orthogonal, got {axes!r}")
    return torch.tensor(rows, dtype=ref.dtype, device=ref.device)


def quat_from_euler(angles: Tensor, axes: Tensor | Sequence[Sequence[float]]) -> Tensor:
    """Intrinsic rotation ``R = R_{e0}(a0) R_{e1}(a1) R_{e2}(a2)`` as ``q(e0,a0) * q(e1,a1) * q(e2,a2)``.

    Args:
        angles: (..., 3) angles, rad.
        axes: three unit axes ``e0, e1, e2`` (rows), e.g. ``((0, 1, 0), (1, 0, 0), (0, 0, 1))`` for
            y-x-z; a (3, 3) or (..., 3, 3) tensor is used as is. Any axes work here (they need not
            be orthogonal), but :func:`quat_to_euler` requires orthonormal ones.
    """
    a = _axes_tensor(axes, angles)
    q0 = quat_from_axis_angle(a[..., 0, :], angles[..., 0])
    q1 = quat_from_axis_angle(a[..., 1, :], angles[..., 1])
    q2 = quat_from_axis_angle(a[..., 2, :], angles[..., 2])
    return quat_mul(quat_mul(q0, q1), q2)


def quat_to_euler(q: Tensor, axes: Tensor | Sequence[Sequence[float]]) -> Tensor:
    """Angles ``(a0, a1, a2)`` with ``R(q) = R_{e0}(a0) R_{e1}(a1) R_{e2}(a2)`` for orthonormal axes.

    Closed form. Let ``E`` be the matrix with columns ``e_i`` and ``s = det E = ±1`` (both
    handednesses are allowed, e.g. y-x-z has ``s = -1``). Since ``E^T R_{e_i}(t) E = R_{c_i}(s t)``
    (``c_i`` the coordinate axes), ``R' = E^T R E = R_x(s a0) R_y(s a1) R_z(s a2)``; its quaternion is
    ``q' = (w, s E^T u)``. For ``R' = R_x(A) R_y(B) R_z(C)``: ``R'02 = sin B``,
    ``(R'12, R'22) = cos B (-sin A, cos A)``, so

    * ``B = asin(R'02)``, evaluated as ``atan2(R'02, hypot(R'12, R'22))`` (same value, accurate
      near ±pi/2), in ``[-pi/2, pi/2]``;
    * ``A = atan2(-R'12, R'22)``, in ``(-pi, pi]``;
    * ``C`` from the residual ``conj(q_y(B)) conj(q_x(A)) q' = q_z(C)``, ``C = 2 atan2(z, w)`` after
      standardizing, in ``[-pi, pi]``; solving for ``C`` last keeps ``R_x(A) R_y(B) R_z(C) = R'``
      even where ``A`` is poorly conditioned.

    Gimbal lock (``cos B < 16 eps`` of the dtype, where ``A`` would be the angle of rounding
    noise): ``A`` is set to 0 and ``C`` takes the whole rotation about the aligned axes; the
    reconstruction error this adds is at most ``16 eps pi``. The angles returned are
    ``s (A, B, C)``. Tensor ``axes`` (3, 3) or (..., 3, 3) are trusted to be orthonormal rows;
    python sequences are checked and normalized.
    """
    a = _axes_tensor(axes, q)
    s = torch.sign(_dot(a[..., 0, :], _cross(a[..., 1, :], a[..., 2, :])))
    s = torch.where(s == 0, torch.ones_like(s), s)
    w = q[..., 0]
    u = q[..., 1:]
    uc = s[..., None] * (a * u[..., None, :]).sum(-1)  # (e_i . u) * s
    x, y, z = uc.unbind(-1)
    w, x, y, z = torch.broadcast_tensors(w, x, y, z)
    n2 = w * w + x * x + y * y + z * z
    r02 = 2.0 * (x * z + w * y) / n2
    r12 = 2.0 * (y * z - w * x) / n2
    r22 = (w * w - x * x - y * y + z * z) / n2
    tiny = torch.finfo(q.dtype).tiny
    cos_b = torch.sqrt((r12 * r12 + r22 * r22).clamp_min(tiny))
    b = torch.atan2(r02, cos_b)
    lock = cos_b < 16.0 * torch.finfo(q.dtype).eps
    a_ang = torch.where(
        lock,
        torch.zeros_like(cos_b),
        torch.atan2(torch.where(lock, torch.zeros_like(r12), -r12), torch.where(lock, torch.ones_like(r22), r22)),
    )
    zero = torch.zeros_like(b)
    ha, hb = 0.5 * a_ang, 0.5 * b
    qa_inv = torch.stack((torch.cos(ha), -torch.sin(ha), zero, zero), dim=-1)
    qb_inv = torch.stack((torch.cos(hb), zero, -torch.sin(hb), zero), dim=-1)
    qp = torch.stack((w, x, y, z), dim=-1)
    qc = quat_standardize(quat_mul(qb_inv, quat_mul(qa_inv, qp)))
    c = 2.0 * torch.atan2(qc[..., 3], qc[..., 0])
    return s[..., None] * torch.stack((a_ang, b, c), dim=-1)


def unwrap_angles(angles: Tensor, dim: int = 0) -> Tensor:
    """Remove ``2 pi`` jumps along ``dim`` (like ``numpy.unwrap``).

    Each step ``d`` is replaced by its representative ``d' = ((d + pi) mod 2 pi) - pi`` (``pi``
    rather than ``-pi`` when ``d > 0``) where ``|d| >= pi``; the corrections ``d' - d`` are summed
    along ``dim`` and added to the samples after the first.
    """
    d = torch.diff(angles, dim=dim)
    dd = torch.remainder(d + math.pi, 2.0 * math.pi) - math.pi
    dd = torch.where((dd == -math.pi) & (d > 0), torch.full_like(dd, math.pi), dd)
    corr = torch.where(d.abs() < math.pi, torch.zeros_like(d), dd - d)
    first = angles.narrow(dim, 0, 1)
    return angles + torch.cat((torch.zeros_like(first), torch.cumsum(corr, dim=dim)), dim=dim)
