"""Property tests of :mod:`mocap.kinematics` on random skeletons, against MuJoCo's own kinematics.

The skeletons here are random trees built in the test (not the real humanoids): random offsets,
fixed joints, single hinges about random axes, 3-hinge ball joints (y-x-z coordinate axes or
random orthonormal triples of either handedness) and, for forward kinematics only, joints whose
hinge axes are not orthogonal.
"""

from __future__ import annotations

import gc
import math

import mujoco
import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap import kinematics as K
from mocap.rotations import quat_from_axis_angle, quat_mul, quat_normalize
from mocap.skeleton import Body, Geom, Hinge, Joint, Skeleton

torch.set_num_threads(1)

F64 = torch.float64
SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 2**32 - 1)

YXZ = ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
OUTER, MIDDLE = 2.8, 1.3  # joint ranges keeping the ball decomposition away from wrap and lock


# ---------------------------------------------------------------------------------------------
# random skeletons


def _hinge(name: str, axis, lim: float) -> Hinge:
    return Hinge(name=name, axis=tuple(float(a) for a in axis), range=(-lim, lim), kp=100.0, kd=10.0, torque_limit=100.0)


unit_vectors = (
    st.tuples(*[st.floats(-1.0, 1.0)] * 3)
    .filter(lambda v: math.sqrt(sum(c * c for c in v)) > 0.2)
    .map(lambda v: tuple(c / math.sqrt(sum(x * x for x in v)) for c in v))
)
unit_quats = st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: math.sqrt(sum(c * c for c in q)) > 0.2).map(lambda q: np.asarray(q) / np.linalg.norm(q))


def _orthonormal_axes(q: np.ndarray, flip: bool) -> np.ndarray:
    """Rows = the columns of the rotation matrix of ``q`` (Rodrigues-free: quaternion formula),
    the second one negated when ``flip`` (left-handed triple)."""
    w, x, y, z = q
    m = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    axes = m.T.copy()
    if flip:
        axes[1] = -axes[1]
    return axes


@st.composite
def joints(draw, name: str, invertible: bool) -> Joint:
    kinds = ["fixed", "hinge", "ball_yxz", "ball_random"] + ([] if invertible else ["two", "three_skew"])
    kind = draw(st.sampled_from(kinds))
    if kind == "fixed":
        return Joint("fixed")
    if kind == "hinge":
        return Joint("hinge", (_hinge(f"{name}_h", draw(unit_vectors), OUTER),))
    if kind == "ball_yxz":
        axes = YXZ
    elif kind == "ball_random":
        axes = _orthonormal_axes(draw(unit_quats), draw(st.booleans()))
    elif kind == "two":
        axes = [draw(unit_vectors) for _ in range(2)]
    else:
        axes = [draw(unit_vectors) for _ in range(3)]
    lims = [OUTER, MIDDLE, OUTER][: len(axes)]
    return Joint("ball", tuple(_hinge(f"{name}_{i}", a, lim) for i, (a, lim) in enumerate(zip(axes, lims))))


@st.composite
def skeletons(draw, invertible: bool = True, max_bodies: int = 9) -> Skeleton:
    n = draw(st.integers(1, max_bodies))
    offsets = st.tuples(*[st.floats(-0.5, 0.5)] * 3)
    bodies = [Body("b0", -1, (0.0, 0.0, 0.0), Joint("fixed"), 1.0, (Geom("sphere", (0.05,)),))]
    for j in range(1, n):
        bodies.append(
            Body(
                name=f"b{j}",
                parent=draw(st.integers(0, j - 1)),
                offset=draw(offsets),
                joint=draw(joints(f"b{j}", invertible)),
                mass=1.0,
                geoms=(Geom("sphere", (0.05,)),),
            )
        )
    skeleton = Skeleton(name="random", bodies=tuple(bodies))
    skeleton.validate()
    return skeleton


def random_dofs(skeleton: Skeleton, rng: np.random.Generator, n: int, within_range: bool = True) -> np.ndarray:
    lo = np.array([h.range[0] for h in skeleton.hinges]).reshape(-1)
    hi = np.array([h.range[1] for h in skeleton.hinges]).reshape(-1)
    if not within_range:
        lo, hi = np.full_like(lo, -2 * np.pi), np.full_like(hi, 2 * np.pi)
    return rng.uniform(lo, hi, (n, skeleton.num_dofs))


def rand_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------------------------
# MuJoCo reference


def fmt(v) -> str:
    return " ".join(repr(float(c)) for c in v)


def to_mjcf(skeleton: Skeleton) -> str:
    children: dict[int, list[int]] = {}
    for j, b in enumerate(skeleton.bodies[1:], start=1):
        children.setdefault(b.parent, []).append(j)

    def body_xml(j: int, indent: str) -> str:
        b = skeleton.bodies[j]
        lines = [f'{indent}<body name="{b.name}" pos="{fmt(b.offset if j else (0, 0, 0))}">']
        if j == 0:
            lines.append(f"{indent}  <freejoint/>")
        for h in b.joint.hinges:
            lines.append(f'{indent}  <joint name="{h.name}" type="hinge" axis="{fmt(h.axis)}"/>')
        lines.append(f'{indent}  <geom type="sphere" size="0.05"/>')
        lines.extend(body_xml(c, indent + "  ") for c in children.get(j, []))
        lines.append(f"{indent}</body>")
        return "\n".join(lines)

    return f"""<mujoco>
  <compiler angle="radian"/>
  <worldbody>
{body_xml(0, "    ")}
  </worldbody>
</mujoco>"""


def mujoco_fk(skeleton: Skeleton, root_pos: np.ndarray, root_rot: np.ndarray, dofs: np.ndarray):
    model = mujoco.MjModel.from_xml_string(to_mjcf(skeleton))
    data = mujoco.MjData(model)
    body_ids = [model.body(b.name).id for b in skeleton.bodies]
    qpos_adr = [model.joint(h.name).qposadr[0] for h in skeleton.hinges]
    pos, rot = [], []
    for p, q, d in zip(root_pos, root_rot, dofs):
        data.qpos[:] = 0.0
        data.qpos[0:3] = p
        data.qpos[3:7] = q
        data.qpos[qpos_adr] = d
        mujoco.mj_kinematics(model, data)
        pos.append(data.xpos[body_ids].copy())
        rot.append(data.xquat[body_ids].copy())
    return np.stack(pos), np.stack(rot)


def assert_same_rotation(a: torch.Tensor, b: torch.Tensor, atol: float) -> None:
    sign = torch.where((a * b).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(a.dtype)
    torch.testing.assert_close(a, sign * b, atol=atol, rtol=0)


def t64(x) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x), dtype=F64)


# ---------------------------------------------------------------------------------------------
# tests


@SETTINGS
@given(skeletons(invertible=False), seeds)
def test_fk_matches_mujoco(skeleton, seed):
    rng = np.random.default_rng(seed)
    n = 6
    root_pos = rng.uniform(-2, 2, (n, 3))
    root_rot = rand_quats(rng, n)
    dofs = random_dofs(skeleton, rng, n, within_range=False)
    ref_pos, ref_rot = mujoco_fk(skeleton, root_pos, root_rot, dofs)
    pos, rot = K.forward_kinematics_dofs(skeleton, t64(root_pos), t64(root_rot), t64(dofs))
    assert pos.shape == (n, skeleton.num_bodies, 3) and rot.shape == (n, skeleton.num_bodies, 4)
    torch.testing.assert_close(pos, t64(ref_pos), atol=1e-9, rtol=0)
    assert_same_rotation(rot, t64(ref_rot), atol=1e-9)


@SETTINGS
@given(skeletons(invertible=True), seeds)
def test_dofs_round_trip(skeleton, seed):
    rng = np.random.default_rng(seed)
    dofs = t64(random_dofs(skeleton, rng, 16))
    local = K.local_rotations_from_dofs(skeleton, dofs)
    assert local.shape == (16, skeleton.num_bodies - 1, 4)
    torch.testing.assert_close(local.norm(dim=-1), torch.ones(local.shape[:-1], dtype=F64))
    back = K.dofs_from_local_rotations(skeleton, local)
    torch.testing.assert_close(back, dofs, atol=1e-9, rtol=0)
    # and the rotations themselves come back (either sign) from the recovered angles
    assert_same_rotation(K.local_rotations_from_dofs(skeleton, back), local, atol=1e-9)


@SETTINGS
@given(skeletons(invertible=False), seeds)
def test_local_rotations_match_hinge_products(skeleton, seed):
    """``L_j = R_{n0}(t0) R_{n1}(t1) ...`` checked with MuJoCo's axis-angle and product routines."""
    rng = np.random.default_rng(seed)
    dofs = random_dofs(skeleton, rng, 3, within_range=False)
    local = K.local_rotations_from_dofs(skeleton, t64(dofs)).numpy()
    for s in range(3):
        for j, body in enumerate(skeleton.bodies[1:], start=1):
            ref = np.array([1.0, 0.0, 0.0, 0.0])
            for h, angle in zip(body.joint.hinges, dofs[s, skeleton.dof_slices[j]]):
                hq, out = np.zeros(4), np.zeros(4)
                mujoco.mju_axisAngle2Quat(hq, np.asarray(h.axis) / np.linalg.norm(h.axis), angle)
                mujoco.mju_mulQuat(out, ref, hq)
                ref = out
            assert_same_rotation(torch.as_tensor(local[s, j - 1]), torch.as_tensor(ref), atol=1e-12)


@SETTINGS
@given(unit_vectors, unit_vectors, st.floats(-3.1, 3.1), st.floats(-3.1, 3.1), st.booleans())
def test_single_hinge_keeps_the_twist(axis, other, twist, swing, swing_first):
    """A 1-hinge joint recovers the twist about its axis and drops the swing."""
    n = np.asarray(axis)
    perp = np.cross(n, other)
    if np.linalg.norm(perp) < 1e-3:
        perp = np.cross(n, [1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0])
    skeleton = Skeleton(
        name="one",
        bodies=(
            Body("root", -1, (0.0, 0.0, 0.0), Joint("fixed"), 1.0, ()),
            Body("link", 0, (0.1, 0.0, 0.0), Joint("hinge", (_hinge("h", axis, 3.14),)), 1.0, ()),
        ),
    )
    q_twist = quat_from_axis_angle(t64(n), torch.tensor(twist, dtype=F64))
    q_swing = quat_from_axis_angle(t64(perp), torch.tensor(swing, dtype=F64))
    q = quat_mul(q_swing, q_twist) if swing_first else quat_mul(q_twist, q_swing)
    dof = K.dofs_from_local_rotations(skeleton, q[None])
    torch.testing.assert_close(dof, torch.tensor([twist], dtype=F64), atol=1e-9, rtol=0)
    dof_neg = K.dofs_from_local_rotations(skeleton, -q[None])  # the sign of the quaternion is irrelevant
    torch.testing.assert_close(dof_neg, dof, atol=1e-12, rtol=0)


def test_broadcasting_dtypes_gradients_and_cache():
    skeleton = Skeleton(
        name="chain",
        bodies=(
            Body("root", -1, (0.0, 0.0, 0.0), Joint("fixed"), 1.0, ()),
            Body("a", 0, (0.0, 0.1, -0.1), Joint("ball", tuple(_hinge(f"a{i}", ax, 1.0) for i, ax in enumerate(YXZ))), 1.0, ()),
            Body("b", 1, (0.0, 0.0, -0.4), Joint("hinge", (_hinge("b", (0.0, 1.0, 0.0), 2.0),)), 1.0, ()),
            Body("c", 2, (0.05, 0.0, -0.4), Joint("fixed"), 1.0, ()),
            Body("d", 0, (0.0, 0.0, 0.3), Joint("fixed"), 1.0, ()),
        ),
    )
    gen = torch.Generator().manual_seed(0)
    root_pos = torch.randn(5, 3, generator=gen, dtype=F64)
    root_rot = quat_normalize(torch.randn(5, 4, generator=gen, dtype=F64))
    dofs = torch.randn(7, 1, 4, generator=gen, dtype=F64)
    # leading dims broadcast: (5,) root with (7, 1) DoFs -> (7, 5)
    pos, rot = K.forward_kinematics_dofs(skeleton, root_pos, root_rot, dofs)
    assert pos.shape == (7, 5, 5, 3) and rot.shape == (7, 5, 5, 4)
    pos_ref, rot_ref = K.forward_kinematics_dofs(skeleton, root_pos[3], root_rot[3], dofs[2, 0])
    torch.testing.assert_close(pos[2, 3], pos_ref)
    torch.testing.assert_close(rot[2, 3], rot_ref)
    # hand-computed: body c at rest hangs 0.8 m below a, the fixed body d 0.3 m above the root
    pos0, rot0 = K.forward_kinematics_dofs(skeleton, torch.zeros(3), torch.tensor([1.0, 0, 0, 0]), torch.zeros(4))
    torch.testing.assert_close(pos0, torch.tensor([[0, 0, 0], [0, 0.1, -0.1], [0, 0.1, -0.5], [0.05, 0.1, -0.9], [0, 0, 0.3]]))
    torch.testing.assert_close(rot0, torch.tensor([[1.0, 0, 0, 0]]).expand(5, 4))
    # knee (body b, hinge about y) bent by +90 deg: c's offset (0.05, 0, -0.4) rotates to (-0.4, 0, -0.05)
    pos1, _ = K.forward_kinematics_dofs(skeleton, torch.zeros(3), torch.tensor([1.0, 0, 0, 0]), torch.tensor([0, 0, 0, math.pi / 2]))
    torch.testing.assert_close(pos1[3], torch.tensor([-0.4, 0.1, -0.55]), atol=1e-6, rtol=0)
    # float32 keeps its dtype and agrees with float64
    p32, r32 = K.forward_kinematics_dofs(skeleton, root_pos.float(), root_rot.float(), dofs.float())
    assert p32.dtype == torch.float32 and r32.dtype == torch.float32
    torch.testing.assert_close(p32.double(), pos, atol=1e-5, rtol=0)
    # gradients flow to every input
    rp, rr, d = root_pos.clone().requires_grad_(), root_rot.clone().requires_grad_(), dofs[:2].clone().requires_grad_()
    p, r = K.forward_kinematics_dofs(skeleton, rp, rr, d)
    (p.square().sum() + r[..., 1:].sum()).backward()
    assert all(x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0 for x in (rp, rr, d))
    assert torch.autograd.gradcheck(
        lambda x: K.forward_kinematics_dofs(skeleton, rp[:1].detach(), rr[:1].detach(), x)[0], (dofs[0, :, :].clone().requires_grad_(),)
    )
    # tables are cached per skeleton object and dropped with it
    tables = K._tables(skeleton)
    assert K._tables(skeleton) is tables
    twin = Skeleton(name="chain", bodies=skeleton.bodies)
    key = id(twin)
    assert K._tables(twin) is not tables and key in K._CACHE
    del twin
    gc.collect()
    # the twin's entry is gone (other tests' skeletons may be collected here too, so no count check)
    assert key not in K._CACHE or K._CACHE[key][0]() is not None


def test_errors():
    skeleton = Skeleton(
        name="bad",
        bodies=(
            Body("root", -1, (0.0, 0.0, 0.0), Joint("fixed"), 1.0, ()),
            Body("a", 0, (0.0, 0.1, 0.0), Joint("ball", (_hinge("a0", (1, 0, 0), 1.0), _hinge("a1", (1, 1, 0), 1.0), _hinge("a2", (0, 0, 1), 1.0))), 1.0, ()),
        ),
    )
    local = K.local_rotations_from_dofs(skeleton, torch.zeros(3))
    with pytest.raises(ValueError, match="non-orthogonal"):
        K.dofs_from_local_rotations(skeleton, local)
    with pytest.raises(ValueError, match="DoFs"):
        K.local_rotations_from_dofs(skeleton, torch.zeros(2))
    with pytest.raises(ValueError, match="joints"):
        K.forward_kinematics(skeleton, torch.zeros(3), torch.tensor([1.0, 0, 0, 0]), torch.zeros(2, 4))
    root_only = Skeleton(name="root", bodies=(Body("root", -1, (0.0, 0.0, 0.0), Joint("fixed"), 1.0, ()),))
    pos, rot = K.forward_kinematics_dofs(root_only, torch.ones(2, 3), torch.tensor([[0.0, 1, 0, 0]]).expand(2, 4), torch.zeros(2, 0))
    assert pos.shape == (2, 1, 3) and torch.equal(pos[:, 0], torch.ones(2, 3)) and torch.equal(rot[:, 0, 1], torch.ones(2))
    assert K.dofs_from_local_rotations(root_only, torch.zeros(2, 0, 4)).shape == (2, 0)
