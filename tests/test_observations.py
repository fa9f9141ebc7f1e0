"""Property tests of :mod:`mocap.observations` (PHC Sec. 3.1: heading-frame invariances;
dimensions of the official code's ``compute_imitation_observations_v6``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap import observations as O
from mocap.humanoids import amp_skeleton, smpl_skeleton
from mocap.rotations import quat_apply, quat_from_axis_angle, quat_mul, quat_normalize
from mocap.state import HumanoidState

torch.set_num_threads(1)

F64 = torch.float64
SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 2**32 - 1)
SIXD = ("zhou", "tan_norm")


def random_state(rng: np.random.Generator, n: int, b: int) -> HumanoidState:
    """Random bodies; the root's x axis stays well away from vertical (heading well defined)."""
    t = lambda a: torch.as_tensor(a, dtype=F64)  # noqa: E731
    yaw = t(rng.uniform(-math.pi, math.pi, n))
    tilt_axis = t(rng.standard_normal((n, 3)))
    tilt = t(rng.uniform(-0.6, 0.6, n))
    root_rot = quat_mul(quat_from_axis_angle(t([0.0, 0.0, 1.0]).expand(n, 3), yaw), quat_from_axis_angle(tilt_axis, tilt))
    body_rot = quat_normalize(t(rng.standard_normal((n, b, 4))))
    body_rot[:, 0] = root_rot
    body_pos = t(rng.normal(0.0, 0.5, (n, b, 3)))
    body_pos[..., 2] += 1.0
    lin = t(rng.normal(0.0, 2.0, (n, b, 3)))
    ang = t(rng.normal(0.0, 3.0, (n, b, 3)))
    d = 3 * (b - 1)
    return HumanoidState(
        root_pos=body_pos[:, 0].clone(),
        root_rot=root_rot,
        root_lin_vel=lin[:, 0].clone(),
        root_ang_vel=ang[:, 0].clone(),
        dof_pos=t(rng.normal(0.0, 1.0, (n, d))),
        dof_vel=t(rng.normal(0.0, 1.0, (n, d))),
        body_pos=body_pos,
        body_rot=body_rot,
        body_lin_vel=lin,
        body_ang_vel=ang,
    )


def yaw_translate(s: HumanoidState, yaw: float, shift: torch.Tensor) -> HumanoidState:
    """The same motion seen in a world rotated by ``yaw`` about z and translated by ``shift``."""
    qz = quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0], dtype=F64), torch.tensor(yaw, dtype=F64))
    rot = lambda v: quat_apply(qz.expand(*v.shape[:-1], 4), v)  # noqa: E731
    body_pos = rot(s.body_pos) + shift
    body_rot = quat_mul(qz.expand(*s.body_rot.shape), s.body_rot)
    return HumanoidState(
        root_pos=body_pos[:, 0].clone(),
        root_rot=body_rot[:, 0].clone(),
        root_lin_vel=rot(s.root_lin_vel),
        root_ang_vel=rot(s.root_ang_vel),
        dof_pos=s.dof_pos,
        dof_vel=s.dof_vel,
        body_pos=body_pos,
        body_rot=body_rot,
        body_lin_vel=rot(s.body_lin_vel),
        body_ang_vel=rot(s.body_ang_vel),
    )


# ---------------------------------------------------------------------------------- dimensions
@pytest.mark.parametrize(
    "skeleton, dims",
    [(smpl_skeleton(), (358, 576, 216)), (amp_skeleton(), (223, 360, 135))],
    ids=["smpl", "amp"],
)
def test_dimensions(skeleton, dims):
    B = skeleton.num_bodies
    assert (O.proprioception_dim(B), O.imitation_goal_rot_dim(B), O.imitation_goal_keypoint_dim(B)) == dims
    s = random_state(np.random.default_rng(0), 3, B)
    r = random_state(np.random.default_rng(1), 3, B)
    for sixd in SIXD:
        assert O.proprioception(s, sixd).shape == (3, dims[0])
        assert O.imitation_goal_rot(s, r, sixd).shape == (3, dims[1])
    assert O.imitation_goal_keypoint(s, r).shape == (3, dims[2])
    assert O.imitation_goal(s, r, "keypoint").shape == (3, dims[2])
    assert O.imitation_goal_dim(B, "rot") == dims[1]


# ---------------------------------------------------------------------------------- invariance
@SETTINGS
@given(seed=seeds, yaw=st.floats(-math.pi, math.pi), shift=st.tuples(*[st.floats(-5.0, 5.0)] * 3))
def test_yaw_and_translation_invariance(seed, yaw, shift):
    rng = np.random.default_rng(seed)
    B = 24
    s, r = random_state(rng, 4, B), random_state(rng, 4, B)
    sh = torch.tensor(shift, dtype=F64)
    s2, r2 = yaw_translate(s, yaw, sh), yaw_translate(r, yaw, sh)
    for sixd in SIXD:
        p1, p2 = O.proprioception(s, sixd), O.proprioception(s2, sixd)
        # every feature except the root height (column 0) is invariant
        torch.testing.assert_close(p1[:, 1:], p2[:, 1:], atol=1e-9, rtol=1e-9)
        torch.testing.assert_close(p2[:, 0], p1[:, 0] + sh[2], atol=1e-9, rtol=0)
        torch.testing.assert_close(O.imitation_goal_rot(s, r, sixd), O.imitation_goal_rot(s2, r2, sixd), atol=1e-9, rtol=1e-9)
    torch.testing.assert_close(O.imitation_goal_keypoint(s, r), O.imitation_goal_keypoint(s2, r2), atol=1e-9, rtol=1e-9)


# ------------------------------------------------------------------------------- zero residual
@SETTINGS
@given(seed=seeds)
def test_goal_differences_zero_when_sim_equals_reference(seed):
    s = random_state(np.random.default_rng(seed), 5, 15)
    cols = O.ROT_GOAL_COLUMNS
    for sixd, ident in (("zhou", [1.0, 0, 0, 0, 1.0, 0]), ("tan_norm", [1.0, 0, 0, 0, 0, 1.0])):
        g = O.imitation_goal_rot(s, s, sixd).reshape(5, 15, -1)
        for name in ("pos_diff", "vel_diff", "ang_vel_diff"):
            assert torch.equal(g[..., cols[name]], torch.zeros_like(g[..., cols[name]])), name
        torch.testing.assert_close(g[..., cols["rot_diff"]], torch.tensor(ident, dtype=F64).expand(5, 15, 6), atol=1e-12, rtol=0)
        # the reference rotation block equals the proprioception's body rotations
        p = O.proprioception(s, sixd)
        rot_block = p[:, 1 + 3 * 14 : 1 + 3 * 14 + 6 * 15].reshape(5, 15, 6)
        torch.testing.assert_close(g[..., cols["ref_rot"]], rot_block, atol=1e-12, rtol=0)
    k = O.imitation_goal_keypoint(s, s).reshape(5, 15, -1)
    assert torch.equal(k[..., :6], torch.zeros_like(k[..., :6]))


@SETTINGS
@given(seed=seeds)
def test_keypoint_goal_is_the_matching_rotation_goal_blocks(seed):
    rng = np.random.default_rng(seed)
    s, r = random_state(rng, 3, 24), random_state(rng, 3, 24)
    g = O.imitation_goal_rot(s, r, "tan_norm").reshape(3, 24, -1)
    k = O.imitation_goal_keypoint(s, r).reshape(3, 24, -1)
    assert torch.equal(k, g[..., list(O.KEYPOINT_FROM_ROT)])
    assert O.KEYPOINT_FROM_ROT == (0, 1, 2, 9, 10, 11, 15, 16, 17)


# ------------------------------------------------------------------------------ frame sanity
def test_heading_frame_direction_and_sixd_columns():
    """A humanoid facing world +y with a body 1 m ahead of it sees that body at heading-frame +x."""
    s = random_state(np.random.default_rng(3), 1, 2)
    s.root_rot[:] = quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0], dtype=F64), torch.tensor(math.pi / 2, dtype=F64))
    s.body_rot[:] = s.root_rot[:, None]
    s.body_pos[0, 1] = s.root_pos[0] + torch.tensor([0.0, 1.0, 0.0], dtype=F64)
    s.body_lin_vel[0, 0] = torch.tensor([0.0, 2.0, 0.0], dtype=F64)
    p = O.proprioception(s, "zhou")
    torch.testing.assert_close(p[0, 1:4], torch.tensor([1.0, 0.0, 0.0], dtype=F64), atol=1e-12, rtol=0)
    # body rotations in the heading frame are the identity: zhou (e_x, e_y), tan-norm (e_x, e_z)
    torch.testing.assert_close(p[0, 4:10], torch.tensor([1.0, 0, 0, 0, 1, 0], dtype=F64), atol=1e-12, rtol=0)
    pt = O.proprioception(s, "tan_norm")
    torch.testing.assert_close(pt[0, 4:10], torch.tensor([1.0, 0, 0, 0, 0, 1], dtype=F64), atol=1e-12, rtol=0)
    lin = p[0, 1 + 3 + 12 : 1 + 3 + 12 + 3]
    torch.testing.assert_close(lin, torch.tensor([2.0, 0.0, 0.0], dtype=F64), atol=1e-12, rtol=0)
    with pytest.raises(ValueError):
        O.rotation_sixd(s.root_rot, "bogus")  # type: ignore[arg-type]


# ------------------------------------------------ the batched-matmul implementation vs the formulas
def _quaternion_proprioception(state: HumanoidState, sixd: str) -> torch.Tensor:
    """s^p written term by term with quaternions, as the module docstring states it."""
    from mocap.rotations import heading_quat_inv

    n, b = state.body_pos.shape[:2]
    h_inv = heading_quat_inv(state.root_rot)[:, None].expand(-1, b, -1)
    rel = quat_apply(h_inv[:, 1:], state.body_pos[:, 1:] - state.root_pos[:, None, :])
    rot = O.rotation_sixd(quat_mul(h_inv, state.body_rot), sixd)  # type: ignore[arg-type]
    lin, ang = quat_apply(h_inv, state.body_lin_vel), quat_apply(h_inv, state.body_ang_vel)
    return torch.cat((state.root_pos[:, 2:3], rel.reshape(n, -1), rot.reshape(n, -1), lin.reshape(n, -1), ang.reshape(n, -1)), -1)


def _quaternion_goal_rot(state: HumanoidState, ref: HumanoidState, sixd: str) -> torch.Tensor:
    """s^{g-rot} written term by term with quaternions (module docstring)."""
    from mocap.rotations import heading_quat_inv, quat_conjugate

    n, b = state.body_pos.shape[:2]
    h_inv = heading_quat_inv(state.root_rot)[:, None].expand(-1, b, -1)
    h = quat_conjugate(h_inv)
    rot_world = quat_mul(ref.body_rot, quat_conjugate(state.body_rot))
    parts = (
        quat_apply(h_inv, ref.body_pos - state.body_pos),
        O.rotation_sixd(quat_mul(quat_mul(h_inv, rot_world), h), sixd),  # type: ignore[arg-type]
        quat_apply(h_inv, ref.body_lin_vel - state.body_lin_vel),
        quat_apply(h_inv, ref.body_ang_vel - state.body_ang_vel),
        quat_apply(h_inv, ref.body_pos - state.root_pos[:, None, :]),
        O.rotation_sixd(quat_mul(h_inv, ref.body_rot), sixd),  # type: ignore[arg-type]
    )
    return torch.cat(parts, dim=-1).reshape(n, -1)


@SETTINGS
@given(seed=seeds, b=st.integers(2, 24), sixd=st.sampled_from(SIXD))
def test_fused_observations_equal_the_quaternion_formulas(seed, b, sixd):
    rng = np.random.default_rng(seed)
    s, ref = random_state(rng, 5, b), random_state(rng, 5, b)
    p, g = O.proprioception_and_goal(s, ref, "rot", sixd)
    torch.testing.assert_close(p, _quaternion_proprioception(s, sixd), atol=1e-12, rtol=0)
    torch.testing.assert_close(g, _quaternion_goal_rot(s, ref, sixd), atol=1e-12, rtol=0)
    torch.testing.assert_close(O.proprioception(s, sixd), p, atol=0, rtol=0)
    torch.testing.assert_close(O.imitation_goal_rot(s, ref, sixd), g, atol=0, rtol=0)
    _, kp = O.proprioception_and_goal(s, ref, "keypoint", sixd)
    torch.testing.assert_close(kp, O.imitation_goal_keypoint(s, ref), atol=0, rtol=0)


def test_heading_of_a_vertical_x_axis_is_zero():
    """The x axis pointing straight up: heading 0 (cos 1, sin 0), as ``heading_angle``'s atan2(0, 0)."""
    q = quat_from_axis_angle(torch.tensor([0.0, 1.0, 0.0], dtype=F64), torch.tensor(-math.pi / 2, dtype=F64))[None]
    c, s = O.heading_cos_sin(q)
    assert float(c) == 1.0 and float(s) == 0.0
