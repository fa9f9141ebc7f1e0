"""Property tests of :mod:`mocap.rotations` against independent references.

References never reuse the function under test: MuJoCo's C quaternion routines (``mju_*``),
Rodrigues' formula in numpy, ``numpy.unwrap``, and geometric identities.
"""

from __future__ import annotations

import itertools
import math

import mujoco
import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap import rotations as R

torch.set_num_threads(1)

F64 = torch.float64
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 2**32 - 1)

COORD = np.eye(3)
PERMUTATIONS = list(itertools.permutations(range(3)))  # all six orders of x, y, z


# ---------------------------------------------------------------------------------------------
# independent references (numpy / MuJoCo)


def rand_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    """Uniform random unit quaternions: normalized gaussians."""
    q = rng.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rand_rotation(rng: np.random.Generator) -> np.ndarray:
    """A random rotation matrix from the QR decomposition of a gaussian matrix (det +1)."""
    qm, r = np.linalg.qr(rng.standard_normal((3, 3)))
    qm = qm * np.sign(np.diag(r))
    if np.linalg.det(qm) < 0:
        qm[:, 0] = -qm[:, 0]
    return qm


def rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    """``I + sin(a) K + (1 - cos(a)) K^2`` with ``K`` the cross-product matrix of the unit axis."""
    k = np.asarray(axis, dtype=float)
    k = k / np.linalg.norm(k)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * kx @ kx


def mj_mat(q: np.ndarray) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.ascontiguousarray(q, dtype=float))
    return out.reshape(3, 3)


def mj_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float))
    return out


def mj_rotvec(q: np.ndarray) -> np.ndarray:
    """Shortest-path rotation vector (MuJoCo's quat2Vel with dt = 1)."""
    out = np.zeros(3)
    mujoco.mju_quat2Vel(out, np.ascontiguousarray(q, dtype=float), 1.0)
    return out


def mj_axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    out = np.zeros(4)
    a = np.asarray(axis, dtype=float)
    mujoco.mju_axisAngle2Quat(out, a / np.linalg.norm(a), float(angle))
    return out


def mj_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.zeros(3)
    mujoco.mju_rotVecQuat(out, np.ascontiguousarray(v, dtype=float), np.ascontiguousarray(q, dtype=float))
    return out


def same_rotation(a: torch.Tensor | np.ndarray, b: torch.Tensor | np.ndarray, atol: float = 1e-10) -> None:
    """Quaternions equal up to sign."""
    a = torch.as_tensor(np.asarray(a), dtype=F64)
    b = torch.as_tensor(np.asarray(b), dtype=F64)
    sign = torch.where((a * b).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    torch.testing.assert_close(a, sign * b, atol=atol, rtol=0)


def wrap(x: np.ndarray | torch.Tensor) -> np.ndarray:
    """Angle(s) wrapped into (-pi, pi]."""
    x = np.asarray(x, dtype=float)
    return np.pi - np.mod(np.pi - x, 2 * np.pi)


def t64(x: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x), dtype=F64)


# ---------------------------------------------------------------------------------------------
# algebra


@SETTINGS
@given(seeds)
def test_quat_mul_matches_mujoco_matrix_product_and_is_associative(seed):
    rng = np.random.default_rng(seed)
    a, b, c = rand_quats(rng, 8), rand_quats(rng, 8), rand_quats(rng, 8)
    ab = R.quat_mul(t64(a), t64(b))
    torch.testing.assert_close(ab, t64([mj_mul(x, y) for x, y in zip(a, b)]), atol=1e-12, rtol=0)
    # R(a b) = R(a) R(b) with matrices from MuJoCo
    ref = np.stack([mj_mat(x) @ mj_mat(y) for x, y in zip(a, b)])
    torch.testing.assert_close(R.quat_to_matrix(ab), t64(ref), atol=1e-12, rtol=0)
    lhs = R.quat_mul(R.quat_mul(t64(a), t64(b)), t64(c))
    rhs = R.quat_mul(t64(a), R.quat_mul(t64(b), t64(c)))
    torch.testing.assert_close(lhs, rhs, atol=1e-12, rtol=0)
    # broadcasting of leading dims
    assert R.quat_mul(t64(a)[:, None], t64(b)[None]).shape == (8, 8, 4)


@SETTINGS
@given(seeds)
def test_conjugate_is_inverse_and_identity_is_neutral(seed):
    q = t64(rand_quats(np.random.default_rng(seed), 8))
    ident = R.quat_identity(8, dtype=F64)
    torch.testing.assert_close(R.quat_mul(q, R.quat_conjugate(q)), ident, atol=1e-12, rtol=0)
    torch.testing.assert_close(R.quat_mul(ident, q), q, atol=0, rtol=0)
    torch.testing.assert_close(R.quat_to_matrix(R.quat_conjugate(q)), R.quat_to_matrix(q).transpose(-1, -2))


def test_identity_normalize_standardize():
    ident = R.quat_identity((2, 3), dtype=torch.float32)
    assert ident.shape == (2, 3, 4) and ident.dtype == torch.float32
    assert torch.equal(ident[..., 0], torch.ones(2, 3)) and not ident[..., 1:].any()
    assert R.quat_identity(()).shape == (4,)
    q = torch.tensor([[-2.0, 0.0, 0.0, 0.0], [0.0, -3.0, 4.0, 0.0]], dtype=F64)
    n = R.quat_normalize(q)
    torch.testing.assert_close(n, torch.tensor([[-1.0, 0, 0, 0], [0, -0.6, 0.8, 0]], dtype=F64))
    s = R.quat_standardize(torch.tensor([[-0.5, 0.5, -0.5, 0.5], [0.5, 0.5, 0.5, 0.5]]))
    assert torch.equal(s, torch.tensor([[0.5, -0.5, 0.5, -0.5], [0.5, 0.5, 0.5, 0.5]]))


@SETTINGS
@given(seeds)
def test_quat_apply_matches_matrix_and_mujoco(seed):
    rng = np.random.default_rng(seed)
    q, v = rand_quats(rng, 6), rng.standard_normal((5, 3))
    out = R.quat_apply(t64(q)[:, None], t64(v)[None])  # (6, 5, 3) by broadcasting
    ref = np.einsum("qij,vj->qvi", np.stack([mj_mat(x) for x in q]), v)
    torch.testing.assert_close(out, t64(ref), atol=1e-12, rtol=0)
    torch.testing.assert_close(out[2, 3], t64(mj_rotate(q[2], v[3])), atol=1e-12, rtol=0)


# ---------------------------------------------------------------------------------------------
# matrices, 6-D


@SETTINGS
@given(seeds)
def test_quat_to_matrix_matches_rodrigues(seed):
    rng = np.random.default_rng(seed)
    axes, angles = rng.standard_normal((8, 3)), rng.uniform(-2 * np.pi, 2 * np.pi, 8)
    q = R.quat_from_axis_angle(t64(axes), t64(angles))
    torch.testing.assert_close(q, t64([mj_axis_angle(a, t) for a, t in zip(axes, angles)]), atol=1e-12, rtol=0)
    ref = np.stack([rodrigues(a, t) for a, t in zip(axes, angles)])
    m = R.quat_to_matrix(q)
    torch.testing.assert_close(m, t64(ref), atol=1e-12, rtol=0)
    torch.testing.assert_close(torch.linalg.det(m), torch.ones(8, dtype=F64))


SPECIAL_QUATS = np.array(
    [
        [1.0, 0.0, 0.0, 0.0],  # identity (trace branch)
        [0.0, 1.0, 0.0, 0.0],  # pi about x (m00 branch)
        [0.0, 0.0, 1.0, 0.0],  # pi about y (m11 branch)
        [0.0, 0.0, 0.0, 1.0],  # pi about z (m22 branch)
        [0.0, 0.6, 0.0, -0.8],  # pi about an oblique axis
        [1e-9, 0.0, 1.0, 1e-9],  # just below pi
        [0.5, 0.5, 0.5, 0.5],
        [0.999999, 1e-3, 0.0, 0.0],
    ]
)


@SETTINGS
@given(seeds)
def test_matrix_to_quat_round_trip_all_branches(seed):
    rng = np.random.default_rng(seed)
    q = np.concatenate([rand_quats(rng, 16), SPECIAL_QUATS / np.linalg.norm(SPECIAL_QUATS, axis=-1, keepdims=True)])
    mats = t64(np.stack([mj_mat(x) for x in q]))  # MuJoCo builds the matrices
    out = R.matrix_to_quat(mats)
    assert (out[:, 0] >= 0).all()
    same_rotation(out, q, atol=1e-12)
    # and back through MuJoCo's own matrix
    torch.testing.assert_close(t64(np.stack([mj_mat(x) for x in out.numpy()])), mats, atol=1e-12, rtol=0)


@SETTINGS
@given(seeds)
def test_sixd_round_trip_and_gram_schmidt(seed):
    rng = np.random.default_rng(seed)
    q = rand_quats(rng, 8)
    mats = np.stack([mj_mat(x) for x in q])
    six = R.matrix_to_sixd(t64(mats))
    torch.testing.assert_close(six, t64(np.concatenate([mats[:, :, 0], mats[:, :, 1]], axis=-1)), atol=0, rtol=0)
    torch.testing.assert_close(R.quat_to_sixd(t64(q)), six, atol=1e-12, rtol=0)
    torch.testing.assert_close(R.sixd_to_matrix(six), t64(mats), atol=1e-12, rtol=0)
    # an arbitrary 6-vector maps to a rotation whose first column is a1's direction and whose
    # second column lies in span(a1, a2) on a2's side
    x = t64(rng.standard_normal((8, 6)))
    m = R.sixd_to_matrix(x)
    torch.testing.assert_close(m.transpose(-1, -2) @ m, torch.eye(3, dtype=F64).expand(8, 3, 3), atol=1e-12, rtol=0)
    torch.testing.assert_close(torch.linalg.det(m), torch.ones(8, dtype=F64))
    a1, a2 = x[:, :3].numpy(), x[:, 3:].numpy()
    torch.testing.assert_close(m[:, :, 0], t64(a1 / np.linalg.norm(a1, axis=-1, keepdims=True)))
    normal = np.cross(a1, a2)
    assert np.abs(np.einsum("ni,ni->n", normal, m[:, :, 1].numpy())).max() < 1e-10
    assert (np.einsum("ni,ni->n", a2, m[:, :, 1].numpy()) > 0).all()


# ---------------------------------------------------------------------------------------------
# rotation vectors, angles


@SETTINGS
@given(seeds, st.floats(1e-12, 3.1))
def test_rotvec_round_trip_and_mujoco(seed, max_angle):
    rng = np.random.default_rng(seed)
    axis = rng.standard_normal((8, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = rng.uniform(0.0, max_angle, 8)
    rv = axis * angle[:, None]
    q = R.quat_from_rotvec(t64(rv))
    torch.testing.assert_close(q, t64([mj_axis_angle(a, t) for a, t in zip(axis, angle)]), atol=1e-12, rtol=0)
    torch.testing.assert_close(R.quat_to_rotvec(q), t64(rv), atol=1e-11, rtol=1e-10)
    # arbitrary unit quaternions (either sign): the shortest-path rotation vector, |r| <= pi
    qr = rand_quats(rng, 8)
    out = R.quat_to_rotvec(t64(qr))
    torch.testing.assert_close(out, t64([mj_rotvec(x) for x in qr]), atol=1e-11, rtol=0)
    torch.testing.assert_close(R.quat_to_rotvec(-t64(qr)), out, atol=1e-12, rtol=0)
    assert (out.norm(dim=-1) <= np.pi + 1e-12).all()
    torch.testing.assert_close(R.quat_angle(t64(qr)), out.norm(dim=-1), atol=1e-12, rtol=0)


def test_rotvec_tiny_angles_and_gradients():
    rv = torch.tensor([[1e-9, -2e-9, 3e-9], [1e-4, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=F64)
    q = R.quat_from_rotvec(rv)
    half = rv.norm(dim=-1) / 2
    ref = torch.cat([torch.cos(half)[:, None], rv / 2 * (1 - half[:, None] ** 2 / 6)], -1)
    torch.testing.assert_close(q, ref, atol=1e-16, rtol=1e-15)
    torch.testing.assert_close(R.quat_to_rotvec(q), rv, atol=1e-20, rtol=1e-12)
    x = torch.tensor([[0.0, 0.0, 0.0], [1e-5, 2e-5, -1e-5], [0.3, -1.0, 0.5]], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(R.quat_from_rotvec, (x,))
    qg = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.9, 0.1, -0.2, 0.3], [0.2, 0.5, -0.5, 0.6]], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(R.quat_to_rotvec, (qg,))
    # the rotation vector's Jacobian at the identity is 2 on the vector part
    jac = torch.autograd.functional.jacobian(R.quat_to_rotvec, torch.tensor([1.0, 0, 0, 0], dtype=F64))
    torch.testing.assert_close(jac, torch.cat([torch.zeros(3, 1), 2 * torch.eye(3)], 1).to(F64))


@SETTINGS
@given(seeds)
def test_angle_and_geodesic_distance(seed):
    rng = np.random.default_rng(seed)
    axis, angle = rng.standard_normal((8, 3)), rng.uniform(-3 * np.pi, 3 * np.pi, 8)
    q = t64([mj_axis_angle(a, t) for a, t in zip(axis, angle)])
    np.testing.assert_allclose(R.quat_angle(q).numpy(), np.abs(wrap(angle)), atol=1e-10)
    a, b = rand_quats(rng, 8), rand_quats(rng, 8)
    # reference: |log(conj(b) a)| computed by MuJoCo, and the trace formula
    ref = np.array([np.linalg.norm(mj_rotvec(mj_mul(y * [1, -1, -1, -1], x))) for x, y in zip(a, b)])
    dist = R.quat_angle_between(t64(a), t64(b))
    np.testing.assert_allclose(dist.numpy(), ref, atol=1e-10)
    tr = np.einsum("nij,nij->n", np.stack([mj_mat(x) for x in a]), np.stack([mj_mat(y) for y in b]))
    np.testing.assert_allclose(np.cos(dist.numpy()), (tr - 1) / 2, atol=1e-10)
    torch.testing.assert_close(R.quat_angle_between(t64(a), -t64(a)), torch.zeros(8, dtype=F64), atol=1e-7, rtol=0)


# ---------------------------------------------------------------------------------------------
# slerp


def ref_slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """``q0 exp(t log(conj(q0) q1))`` with MuJoCo's routines (shortest path)."""
    rv = mj_rotvec(mj_mul(q0 * [1, -1, -1, -1], q1))
    ang = np.linalg.norm(rv)
    step = mj_axis_angle(rv / ang, t * ang) if ang > 0 else np.array([1.0, 0, 0, 0])
    return mj_mul(q0, step)


@SETTINGS
@given(seeds)
def test_slerp_endpoints_norm_speed_and_reference(seed):
    rng = np.random.default_rng(seed)
    q0, q1, t = rand_quats(rng, 8), rand_quats(rng, 8), rng.uniform(0, 1, 8)
    a, b = t64(q0), t64(q1)
    torch.testing.assert_close(R.quat_slerp(a, b, 0.0), a, atol=1e-12, rtol=0)
    same_rotation(R.quat_slerp(a, b, 1.0), b, atol=1e-12)
    out = R.quat_slerp(a, b, t64(t))
    torch.testing.assert_close(out.norm(dim=-1), torch.ones(8, dtype=F64))
    same_rotation(out, np.stack([ref_slerp(x, y, s) for x, y, s in zip(q0, q1, t)]), atol=1e-10)
    # constant angular speed along the shortest geodesic
    total = R.quat_angle_between(a, b)
    t2 = rng.uniform(0, 1, 8)
    out2 = R.quat_slerp(a, b, t64(t2))
    torch.testing.assert_close(R.quat_angle_between(out, out2), total * t64(np.abs(t - t2)), atol=1e-9, rtol=0)
    torch.testing.assert_close(R.quat_angle_between(a, out), total * t64(t), atol=1e-9, rtol=0)
    # t broadcasts against the leading dims
    assert R.quat_slerp(a, b, t64(t[:3, None])).shape == (3, 8, 4)


@SETTINGS
@given(seeds, st.one_of(st.floats(0.0, 1e-5), st.floats(1e-5, 0.3)))
def test_slerp_nearly_equal(seed, eps):
    rng = np.random.default_rng(seed)
    q0 = rand_quats(rng, 4)
    axis = rng.standard_normal(3)
    q1 = np.stack([mj_mul(x, mj_axis_angle(axis, eps)) for x in q0])
    t = rng.uniform(0, 1, 4)
    out = R.quat_slerp(t64(q0), -t64(q1), t64(t))  # also crosses the double cover
    assert torch.isfinite(out).all()
    same_rotation(out, np.stack([mj_mul(x, mj_axis_angle(axis, s * eps)) for x, s in zip(q0, t)]), atol=1e-14)


def test_slerp_gradient():
    q0 = torch.tensor([[1.0, 0, 0, 0], [0.5, 0.5, 0.5, 0.5]], dtype=F64, requires_grad=True)
    q1 = torch.tensor([[1.0, 1e-7, 0, 0], [0.0, 0.6, 0.0, 0.8]], dtype=F64, requires_grad=True)
    t = torch.tensor([0.3, 0.7], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(R.quat_slerp, (q0, q1, t))


# ---------------------------------------------------------------------------------------------
# heading


def rot_z(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(angle / 2), 0 * angle, 0 * angle, np.sin(angle / 2)], -1)


@SETTINGS
@given(seeds)
def test_heading(seed):
    rng = np.random.default_rng(seed)
    q = rand_quats(rng, 16)
    fwd = np.stack([mj_rotate(x, [1.0, 0, 0]) for x in q])
    q, fwd = q[np.hypot(fwd[:, 0], fwd[:, 1]) > 1e-3], fwd[np.hypot(fwd[:, 0], fwd[:, 1]) > 1e-3]
    h = R.heading_angle(t64(q))
    np.testing.assert_allclose(h.numpy(), np.arctan2(fwd[:, 1], fwd[:, 0]), atol=1e-10)
    a = rng.uniform(-4 * np.pi, 4 * np.pi, len(q))
    rotated = np.stack([mj_mul(z, x) for z, x in zip(rot_z(a), q)])
    diff = R.heading_angle(t64(rotated)).numpy() - h.numpy() - a
    np.testing.assert_allclose(wrap(diff), 0.0, atol=1e-9)
    # removing the heading leaves the forward axis in the xz half-plane x >= 0
    local = R.quat_mul(R.heading_quat_inv(t64(q)), t64(q))
    np.testing.assert_allclose(R.heading_angle(local).numpy(), 0.0, atol=1e-9)
    f = R.quat_apply(local, torch.tensor([1.0, 0, 0], dtype=F64))
    assert f[:, 1].abs().max() < 1e-12 and (f[:, 0] > 0).all()
    # heading_quat is the z rotation by the heading and its inverse is heading_quat_inv
    torch.testing.assert_close(R.heading_quat(t64(q)), t64(rot_z(h.numpy())), atol=1e-12, rtol=0)
    torch.testing.assert_close(R.heading_quat_inv(t64(q)), R.quat_conjugate(R.heading_quat(t64(q))), atol=0, rtol=0)
    # heading frame: a world vector along the heading maps to +x
    v = t64(np.stack([np.cos(h.numpy()), np.sin(h.numpy()), np.zeros(len(q))], -1))
    hv = R.quat_apply(R.heading_quat_inv(t64(q)), v)
    torch.testing.assert_close(hv, t64(np.tile([1.0, 0, 0], (len(q), 1))), atol=1e-12, rtol=0)


# ---------------------------------------------------------------------------------------------
# Euler angles


def perm_axes(perm, signs=(1, 1, 1)) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(s) * COORD[i]) for i, s in zip(perm, signs))


def euler_matrix_ref(angles: np.ndarray, axes: np.ndarray) -> np.ndarray:
    return rodrigues(axes[0], angles[0]) @ rodrigues(axes[1], angles[1]) @ rodrigues(axes[2], angles[2])


def rand_euler(rng: np.random.Generator, n: int, margin: float = 0.05) -> np.ndarray:
    """Angles inside the decomposition's principal range, away from gimbal lock."""
    outer = rng.uniform(-np.pi + margin, np.pi - margin, (n, 2))
    mid = rng.uniform(-np.pi / 2 + margin, np.pi / 2 - margin, n)
    return np.stack([outer[:, 0], mid, outer[:, 1]], -1)


@pytest.mark.parametrize("perm", PERMUTATIONS, ids=lambda p: "".join("xyz"[i] for i in p))
@settings(max_examples=15, deadline=None)
@given(seed=seeds)
def test_euler_coordinate_orders(perm, seed):
    rng = np.random.default_rng(seed)
    signs = tuple(rng.choice([-1, 1], 3))
    axes = perm_axes(perm, signs)
    angles = rand_euler(rng, 8)
    q = R.quat_from_euler(t64(angles), axes)
    if signs == (1, 1, 1):  # MuJoCo's intrinsic lower-case sequences
        seq = "".join("xyz"[i] for i in perm)
        for qi, ang in zip(q, angles):
            ref = np.zeros(4)
            mujoco.mju_euler2Quat(ref, ang, seq)
            same_rotation(qi, ref, atol=1e-12)
    ref_m = np.stack([euler_matrix_ref(ang, np.array(axes)) for ang in angles])
    torch.testing.assert_close(R.quat_to_matrix(q), t64(ref_m), atol=1e-12, rtol=0)
    torch.testing.assert_close(R.quat_to_euler(q, axes), t64(angles), atol=1e-10, rtol=0)
    # any rotation is reproduced (angles are then in the principal range)
    qr = t64(rand_quats(rng, 8))
    e = R.quat_to_euler(qr, axes)
    assert (e[:, 1].abs() <= np.pi / 2 + 1e-12).all() and (e.abs() <= np.pi + 1e-12).all()
    same_rotation(R.quat_from_euler(e, axes), qr, atol=1e-10)


@SETTINGS
@given(seeds, st.booleans())
def test_euler_random_orthonormal_axes(seed, left_handed):
    rng = np.random.default_rng(seed)
    basis = rand_rotation(rng)
    if left_handed:
        basis[:, 1] = -basis[:, 1]
    axes = basis.T  # rows are the axes
    angles = rand_euler(rng, 8)
    q = R.quat_from_euler(t64(angles), axes.tolist())
    ref_m = np.stack([euler_matrix_ref(ang, axes) for ang in angles])
    torch.testing.assert_close(R.quat_to_matrix(q), t64(ref_m), atol=1e-12, rtol=0)
    torch.testing.assert_close(R.quat_to_euler(q, axes.tolist()), t64(angles), atol=1e-10, rtol=0)
    # tensor axes, batched per sample
    batched = t64(np.broadcast_to(axes, (8, 3, 3)).copy())
    torch.testing.assert_close(R.quat_to_euler(q, batched), t64(angles), atol=1e-10, rtol=0)
    qr = t64(rand_quats(rng, 8))
    same_rotation(R.quat_from_euler(R.quat_to_euler(qr, axes.tolist()), axes.tolist()), qr, atol=1e-10)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("perm", [(1, 0, 2), (0, 1, 2), (2, 1, 0)])
def test_euler_gimbal_lock(perm, dtype):
    rng = np.random.default_rng(0)
    axes = perm_axes(perm)
    n = 16
    angles = np.stack([rng.uniform(-3, 3, n), rng.choice([-np.pi / 2, np.pi / 2], n), rng.uniform(-3, 3, n)], -1)
    q = R.quat_from_euler(torch.as_tensor(angles, dtype=dtype), axes)
    e = R.quat_to_euler(q, axes)
    assert e.dtype == dtype and torch.isfinite(e).all()
    atol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(e[:, 1].abs().double(), torch.full((n,), np.pi / 2, dtype=F64), atol=atol * 10, rtol=0)
    assert e[:, 0].abs().max() == 0  # the first angle is set to 0 in the lock
    same_rotation(R.quat_from_euler(e, axes).double(), q.double(), atol=atol)
    # near (not at) the lock the rotation is still reproduced
    near = angles.copy()
    near[:, 1] = np.sign(near[:, 1]) * (np.pi / 2 - 1e-6)
    qn = R.quat_from_euler(torch.as_tensor(near, dtype=dtype), axes)
    same_rotation(R.quat_from_euler(R.quat_to_euler(qn, axes), axes).double(), qn.double(), atol=atol)


def test_euler_rejects_non_orthogonal_axes_and_is_differentiable():
    with pytest.raises(ValueError):
        R.quat_to_euler(R.quat_identity(1), ((1, 0, 0), (1, 1, 0), (0, 0, 1)))
    axes = ((0, 1, 0), (1, 0, 0), (0, 0, 1))
    q = R.quat_from_euler(torch.tensor([[0.3, -0.4, 1.2], [-2.0, 1.0, 0.1]], dtype=F64), axes)
    q.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: R.quat_to_euler(x, axes), (q,))


# ---------------------------------------------------------------------------------------------
# angular velocity, unwrapping


@SETTINGS
@given(seeds, st.floats(1e-3, 0.1))
def test_angular_velocity_recovers_constant_rate(seed, dt):
    rng = np.random.default_rng(seed)
    n = 8
    omega = rng.standard_normal((n, 3))
    omega *= (rng.uniform(0, 3.0, n) / dt / np.linalg.norm(omega, axis=-1))[:, None]  # |omega| dt < pi
    q0 = rand_quats(rng, n)
    # q(t) = exp(omega t) q0: world-frame rotation at a constant rate, two steps
    step = [mj_axis_angle(w, np.linalg.norm(w) * dt) for w in omega]
    q1 = np.stack([mj_mul(s, x) for s, x in zip(step, q0)])
    q2 = np.stack([mj_mul(s, x) for s, x in zip(step, q1)])
    w01 = R.angular_velocity(t64(q0), t64(q1), dt)
    torch.testing.assert_close(w01, t64(omega), atol=1e-9, rtol=1e-9)
    torch.testing.assert_close(R.angular_velocity(t64(q1), -t64(q2), torch.full((n,), dt, dtype=F64)), t64(omega), atol=1e-9, rtol=1e-9)
    # a body-frame rate differs: R(q0)^T omega is the body-frame rate (sanity of the frame)
    body = np.stack([mj_mat(x).T @ w for x, w in zip(q0, omega)])
    torch.testing.assert_close(R.quat_apply(R.quat_conjugate(t64(q0)), w01), t64(body), atol=1e-8, rtol=1e-8)


@SETTINGS
@given(seeds)
def test_unwrap_matches_numpy(seed):
    rng = np.random.default_rng(seed)
    steps = rng.uniform(-3.0, 3.0, (50, 3))
    wrapped = wrap(np.cumsum(steps, axis=0) + rng.uniform(-10, 10, 3))
    out = R.unwrap_angles(t64(wrapped), dim=0)
    np.testing.assert_allclose(out.numpy(), np.unwrap(wrapped, axis=0), atol=1e-12)
    assert np.abs(np.diff(out.numpy(), axis=0)).max() <= np.pi
    np.testing.assert_allclose(R.unwrap_angles(t64(wrapped.T), dim=1).numpy(), np.unwrap(wrapped.T, axis=1), atol=1e-12)


def test_unwrap_exact_half_turns():
    # a step of exactly +pi or -pi is kept as is (numpy's convention)
    x = np.array([0.0, np.pi, 0.0, -np.pi, 2.5, -2.5])
    np.testing.assert_allclose(R.unwrap_angles(t64(x)).numpy(), np.unwrap(x), atol=1e-12)


# ---------------------------------------------------------------------------------------------
# dtypes and shapes


def test_float32_and_leading_dims():
    rng = np.random.default_rng(1)
    q64 = t64(rand_quats(rng, 24)).reshape(2, 3, 4, 4)
    q = q64.float()
    v = torch.randn(2, 3, 4, 3, generator=torch.Generator().manual_seed(0))
    axes = ((0, 1, 0), (1, 0, 0), (0, 0, 1))
    outs = {
        "mul": R.quat_mul(q, q),
        "apply": R.quat_apply(q, v),
        "rotvec": R.quat_to_rotvec(q),
        "from_rotvec": R.quat_from_rotvec(R.quat_to_rotvec(q)),
        "matrix": R.quat_to_matrix(q),
        "m2q": R.matrix_to_quat(R.quat_to_matrix(q)),
        "sixd": R.quat_to_sixd(q),
        "s2m": R.sixd_to_matrix(R.quat_to_sixd(q)),
        "angle": R.quat_angle(q),
        "slerp": R.quat_slerp(q, q.flip(0), 0.25),
        "heading": R.heading_angle(q),
        "hq": R.heading_quat_inv(q),
        "euler": R.quat_to_euler(q, axes),
        "from_euler": R.quat_from_euler(R.quat_to_euler(q, axes), axes),
        "angvel": R.angular_velocity(q, q.flip(1), 0.1),
    }
    for name, out in outs.items():
        assert out.dtype == torch.float32, name
        assert out.shape[:3] == (2, 3, 4), name
        assert torch.isfinite(out).all(), name
    same_rotation(outs["m2q"].double(), q64, atol=1e-6)
    same_rotation(outs["from_rotvec"].double(), q64, atol=1e-6)
    same_rotation(outs["from_euler"].double(), q64, atol=1e-5)
    torch.testing.assert_close(outs["s2m"], outs["matrix"], atol=1e-6, rtol=0)
