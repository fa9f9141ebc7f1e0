"""Ground-plane transforms of reference frames (:mod:`mocap.motion.transform`): property tests
against geometric identities (rigid motions keep distances, heights and joint angles; turning by
``a`` then ``b`` is turning by ``a + b``) and a brute-force search for the best yaw."""

from __future__ import annotations

import math

import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap.motion.transform import best_yaw, yaw_frames, yaw_quat
from mocap.rotations import quat_angle_between, quat_mul, quat_normalize
from mocap.state import MotionFrames

torch.set_num_threads(1)
F64 = torch.float64
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 2**32 - 1)


def rand_quat(g: torch.Generator, *shape: int) -> torch.Tensor:
    return quat_normalize(torch.randn(*shape, 4, generator=g, dtype=F64))


def rand_frames(seed: int, n: int = 3, bodies: int = 4, dofs: int = 5, ahead: int = 0) -> MotionFrames:
    g = torch.Generator().manual_seed(seed)

    def r(*s: int) -> torch.Tensor:
        return torch.randn(*s, generator=g, dtype=F64)

    body_pos, body_rot = r(n, bodies, 3), rand_quat(g, n, bodies)
    f = MotionFrames(
        root_pos=body_pos[:, 0].clone(),
        root_rot=body_rot[:, 0].clone(),
        root_lin_vel=r(n, 3),
        root_ang_vel=r(n, 3),
        dof_pos=r(n, dofs),
        dof_vel=r(n, dofs),
        body_pos=body_pos,
        body_rot=body_rot,
        body_lin_vel=r(n, bodies, 3),
        body_ang_vel=r(n, bodies, 3),
        clip_ids=torch.arange(n),
        times=torch.rand(n, generator=g, dtype=F64),
    )
    if ahead:
        f.ahead = tuple(rand_frames(seed + 1 + k, n, bodies, dofs) for k in range(ahead))
    return f


@SETTINGS
@given(seed=seeds)
def test_best_yaw_beats_every_other_turn_and_finds_a_pure_turn(seed):
    g = torch.Generator().manual_seed(seed)
    target, source = rand_quat(g, 8), rand_quat(g, 8)
    yaw, resid = best_yaw(target, source)
    assert bool((yaw.abs() <= math.pi + 1e-12).all())
    torch.testing.assert_close(resid, quat_angle_between(quat_mul(yaw_quat(yaw), source), target), atol=1e-9, rtol=0)
    for psi in torch.linspace(-math.pi, math.pi, 73, dtype=F64):  # brute force over turns
        other = quat_angle_between(quat_mul(yaw_quat(psi.expand(8)), source), target)
        assert bool((resid <= other + 1e-9).all())
    a = (torch.rand(8, generator=g, dtype=F64) * 2 - 1) * math.pi
    yaw2, resid2 = best_yaw(quat_mul(yaw_quat(a), source), source)
    assert float(resid2.abs().max()) < 1e-6
    torch.testing.assert_close(torch.cos(yaw2), torch.cos(a)) and torch.testing.assert_close(torch.sin(yaw2), torch.sin(a))


@SETTINGS
@given(seed=seeds)
def test_yaw_frames_is_a_rigid_ground_motion(seed):
    g = torch.Generator().manual_seed(seed)
    f = rand_frames(seed, ahead=1)
    yaw = (torch.rand(3, generator=g, dtype=F64) * 2 - 1) * math.pi
    pivot, target = torch.randn(3, 3, generator=g, dtype=F64), torch.randn(3, 2, generator=g, dtype=F64)
    out = yaw_frames(f, yaw, pivot, target)
    torch.testing.assert_close(torch.cdist(out.body_pos, out.body_pos), torch.cdist(f.body_pos, f.body_pos))  # distances kept
    torch.testing.assert_close(out.body_pos[..., 2], f.body_pos[..., 2])  # heights kept
    torch.testing.assert_close(out.dof_pos, f.dof_pos) and torch.testing.assert_close(out.dof_vel, f.dof_vel)
    for k in ("body_lin_vel", "body_ang_vel", "root_lin_vel", "root_ang_vel"):
        torch.testing.assert_close(torch.linalg.vector_norm(getattr(out, k), dim=-1), torch.linalg.vector_norm(getattr(f, k), dim=-1))
        torch.testing.assert_close(getattr(out, k)[..., 2], getattr(f, k)[..., 2])
    # the pivot lands on the target: a body at the pivot's xy ends at the target's xy
    at_pivot = rand_frames(seed)
    at_pivot.body_pos[:, 0, :2] = pivot[:, :2]
    torch.testing.assert_close(yaw_frames(at_pivot, yaw, pivot, target).body_pos[:, 0, :2], target)
    # rotations turn by yaw: the angle to the original is |yaw| about z (up to the double cover)
    d = quat_mul(out.body_rot, torch.cat((f.body_rot[..., :1], -f.body_rot[..., 1:]), -1))
    torch.testing.assert_close(d[..., 1:3], torch.zeros_like(d[..., 1:3]), atol=1e-9, rtol=0)
    assert len(out.ahead) == 1
    torch.testing.assert_close(out.ahead[0].body_pos, yaw_frames(f.ahead[0], yaw, pivot, target).body_pos)
    torch.testing.assert_close(out.times, f.times) and torch.testing.assert_close(out.clip_ids, f.clip_ids)


@SETTINGS
@given(seed=seeds)
def test_two_turns_compose_and_a_zero_turn_in_place_is_the_identity(seed):
    g = torch.Generator().manual_seed(seed)
    f = rand_frames(seed)
    a, b = ((torch.rand(3, generator=g, dtype=F64) * 2 - 1) * math.pi for _ in range(2))
    p, t, u = (torch.randn(3, 2, generator=g, dtype=F64) for _ in range(3))
    two = yaw_frames(yaw_frames(f, a, p, t), b, t, u)
    one = yaw_frames(f, a + b, p, u)
    for k in ("body_pos", "root_pos", "body_lin_vel", "root_ang_vel"):
        torch.testing.assert_close(getattr(two, k), getattr(one, k))
    torch.testing.assert_close(quat_angle_between(two.body_rot, one.body_rot), torch.zeros(3, 4, dtype=F64), atol=1e-6, rtol=0)
    same = yaw_frames(f, torch.zeros(3, dtype=F64), p, p)
    for k in ("body_pos", "body_rot", "root_lin_vel"):
        torch.testing.assert_close(getattr(same, k), getattr(f, k))


@SETTINGS
@given(seed=seeds, pick=st.integers(0, 2))
def test_match_first_frames_finds_the_clip_a_turned_copy_lies_like(seed, pick):
    from mocap.motion.transform import match_first_frames

    g = torch.Generator().manual_seed(seed)
    first = rand_quat(g, 3)
    a = (torch.rand(4, generator=g, dtype=F64) * 2 - 1) * math.pi
    lying = quat_mul(yaw_quat(a), first[pick].expand(4, 4))
    clips = torch.tensor([7, 8, 9])
    clip, yaw, resid = match_first_frames(first, clips, lying)
    assert bool((clip == 7 + pick).all()) or float(resid.max()) < 1e-6  # another candidate may match exactly too (measure zero)
    assert float(resid.max()) < 1e-6
    torch.testing.assert_close(torch.cos(yaw), torch.cos(a)) and torch.testing.assert_close(torch.sin(yaw), torch.sin(a))
    # every returned residual is the smallest over the candidates
    other = torch.stack([best_yaw(lying, first[j].expand(4, 4))[1] for j in range(3)], -1)
    torch.testing.assert_close(resid, other.min(-1).values)
