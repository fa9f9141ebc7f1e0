"""Imitation metrics: zero on identical inputs, invariances, units, masks (hypothesis)."""

from __future__ import annotations

import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.metrics import (
    acceleration_error,
    mpjpe_global,
    mpjpe_local,
    pa_mpjpe,
    procrustes_align,
    success,
    velocity_error,
)
from mocap.rotations import quat_from_rotvec, quat_to_matrix
from mocap.state import Trajectories

seeds = st.integers(0, 2**31 - 1)


def random_traj(seed: int, T=6, N=3, B=5, noise=0.05) -> Trajectories:
    g = torch.Generator().manual_seed(seed)
    ref = torch.randn(T, N, B, 3, generator=g, dtype=torch.float64)
    sim = ref + noise * torch.randn(T, N, B, 3, generator=g, dtype=torch.float64)
    return Trajectories(sim=sim, ref=ref, fps=30.0)


def random_rotation(seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return quat_to_matrix(quat_from_rotvec(torch.randn(3, generator=g, dtype=torch.float64) * 2))


@settings(max_examples=40, deadline=None)
@given(seeds)
def test_identical_trajectories_have_zero_error_and_succeed(seed):
    tr = random_traj(seed)
    same = Trajectories(tr.ref, tr.ref, 30.0)
    for fn in (mpjpe_global, mpjpe_local, velocity_error, acceleration_error):
        assert torch.allclose(fn(same), torch.zeros(3, dtype=torch.float64))
    assert torch.allclose(pa_mpjpe(same), torch.zeros(3, dtype=torch.float64), atol=1e-6)
    assert torch.equal(success(same), torch.ones(3, dtype=torch.float64))


@settings(max_examples=40, deadline=None)
@given(seeds, st.floats(-5, 5), st.floats(-5, 5))
def test_global_translation(seed, dx, dy):
    tr = random_traj(seed, noise=0.0)
    shift = torch.tensor([dx, dy, 0.0], dtype=torch.float64)
    moved = Trajectories(tr.ref + shift, tr.ref, 30.0)
    # a rigid translation: global error = |shift| in mm, root-relative and PA errors vanish
    assert torch.allclose(mpjpe_global(moved), torch.full((3,), 1000 * math.hypot(dx, dy), dtype=torch.float64))
    assert torch.allclose(mpjpe_local(moved), torch.zeros(3, dtype=torch.float64), atol=1e-9)
    assert torch.allclose(velocity_error(moved), torch.zeros(3, dtype=torch.float64), atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(seeds, seeds, st.floats(0.3, 3.0))
def test_pa_mpjpe_invariant_to_similarity_transform_of_sim(seed, rot_seed, scale):
    tr = random_traj(seed, noise=0.1)
    R = random_rotation(rot_seed)
    t = torch.tensor([0.3, -1.0, 2.0], dtype=torch.float64)
    transformed = Trajectories(scale * tr.sim @ R.T + t, tr.ref, 30.0)
    assert torch.allclose(pa_mpjpe(transformed), pa_mpjpe(tr), atol=1e-6)
    assert torch.all(pa_mpjpe(tr) <= mpjpe_global(tr) + 1e-9)  # alignment can only help


@settings(max_examples=40, deadline=None)
@given(seeds, seeds, st.floats(0.3, 3.0))
def test_procrustes_recovers_exact_similarity(seed, rot_seed, scale):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(7, 3, generator=g, dtype=torch.float64)
    R = random_rotation(rot_seed)
    y = scale * x @ R.T + torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    assert torch.allclose(procrustes_align(x, y), y, atol=1e-8)


def test_velocity_and_acceleration_units_are_per_frame():
    T = 10
    t = torch.arange(T, dtype=torch.float64)
    ref = torch.zeros(T, 1, 1, 3, dtype=torch.float64)
    sim = ref.clone()
    sim[..., 0] = 0.002 * t[:, None, None]  # drifts 2 mm per frame
    tr = Trajectories(sim, ref, 30.0)
    assert torch.allclose(velocity_error(tr), torch.tensor([2.0], dtype=torch.float64))
    assert torch.allclose(acceleration_error(tr), torch.tensor([0.0], dtype=torch.float64), atol=1e-9)
    sim2 = ref.clone()
    sim2[..., 0] = 0.001 * t[:, None, None] ** 2  # x = a t^2 -> second difference 2a = 2 mm/frame^2
    assert torch.allclose(acceleration_error(Trajectories(sim2, ref, 30.0)), torch.tensor([2.0], dtype=torch.float64))


def test_success_threshold_grace_and_mask():
    T, N, B = 5, 3, 2
    ref = torch.zeros(T, N, B, 3)
    sim = ref.clone()
    sim[2, 0, :, 0] = 0.6  # env 0 exceeds 0.5 m at frame 2
    sim[0, 1, :, 0] = 0.6  # env 1 exceeds only at frame 0
    sim[4, 2, 0, 0] = 0.8  # env 2: one body 0.8 m off -> mean 0.4 m (passes), max 0.8 (fails L-inf)
    tr = Trajectories(sim, ref, 30.0)
    assert success(tr).tolist() == [0.0, 0.0, 1.0]
    assert success(tr, grace_frames=1).tolist() == [0.0, 1.0, 1.0]
    assert success(tr, reduce="max").tolist() == [0.0, 0.0, 0.0]
    mask = torch.ones(T, N, dtype=torch.bool)
    mask[2:, 0] = False  # env 0 ended before its failure frame
    assert success(Trajectories(sim, ref, 30.0, mask)).tolist() == [1.0, 0.0, 1.0]


def test_masked_frames_are_ignored_in_means():
    T, N, B = 4, 1, 1
    ref = torch.zeros(T, N, B, 3)
    sim = ref.clone()
    sim[3, 0, 0, 0] = 10.0
    mask = torch.tensor([[True], [True], [True], [False]])
    assert mpjpe_global(Trajectories(sim, ref, 30.0, mask)).item() == 0.0
    assert mpjpe_global(Trajectories(sim, ref, 30.0)).item() == 2500.0


@settings(max_examples=40, deadline=None)
@given(seeds, st.floats(0.0, math.pi - 1e-3), st.booleans())
def test_rotation_error_is_the_geodesic_angle(seed, angle, flip):
    """Zero on identical orientations, blind to the quaternion sign, equal to the angle of a
    common relative rotation, invariant to a rotation applied to both sides on the left."""
    from mocap.metrics import rotation_error
    from mocap.rotations import quat_from_axis_angle, quat_mul

    g = torch.Generator().manual_seed(seed)
    T, N, B = 4, 3, 5
    ref_rot = torch.nn.functional.normalize(torch.randn(T, N, B, 4, generator=g, dtype=torch.float64), dim=-1)
    tr = random_traj(seed, T, N, B)
    same = Trajectories(tr.sim, tr.ref, 30.0, None, -ref_rot if flip else ref_rot, ref_rot)
    assert torch.allclose(rotation_error(same), torch.zeros(N, dtype=torch.float64), atol=1e-5)
    axis = torch.nn.functional.normalize(torch.randn(3, generator=g, dtype=torch.float64), dim=0)
    delta = quat_from_axis_angle(axis, torch.tensor(angle, dtype=torch.float64)).expand(T, N, B, 4)
    turned = quat_mul(ref_rot, delta)
    err = rotation_error(Trajectories(tr.sim, tr.ref, 30.0, None, turned, ref_rot))
    assert torch.allclose(err, torch.full((N,), math.degrees(angle), dtype=torch.float64), atol=1e-4)
    world = quat_from_axis_angle(axis.flip(0), torch.tensor(1.0, dtype=torch.float64)).expand(T, N, B, 4)
    both = rotation_error(Trajectories(tr.sim, tr.ref, 30.0, None, quat_mul(world, turned), quat_mul(world, ref_rot)))
    assert torch.allclose(both, err, atol=1e-4)
    assert torch.isnan(rotation_error(tr)).all()  # not recorded


def test_success_over_a_subset_of_bodies():
    """PHC's evaluation on smpl checks its 20 'eval bodies' (no toes, no hands): a hand 3 m off fails
    the all-body mean (0.75 m over 4 bodies) but not the check without it; unknown names are refused."""
    import pytest

    from mocap.errors import UserError
    from mocap.imitation_eval import success_bodies

    sim = torch.zeros(5, 1, 4, 3)
    sim[2, 0, 3, 0] = 3.0  # body 3 (the "hand") far off at one frame
    tr = Trajectories(sim=sim, ref=torch.zeros_like(sim), fps=30.0)
    assert float(success(tr, threshold=0.5)[0]) == 0.0
    assert float(success(tr, threshold=0.5, bodies=[0, 1, 2])[0]) == 1.0

    class Sk:
        name, body_names = "toy", ("Pelvis", "Torso", "Head", "R_Hand")

    assert success_bodies(Sk(), []) is None
    assert success_bodies(Sk(), ["R_Hand"]) == [0, 1, 2]
    with pytest.raises(UserError, match="L_Hand not a body of 'toy'; bodies: Pelvis, Torso"):
        success_bodies(Sk(), ["L_Hand"])
    with pytest.raises(UserError, match="no body"):
        success_bodies(Sk(), list(Sk.body_names))
