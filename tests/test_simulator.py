"""The ``mujoco`` simulator: reset fidelity, env independence, stability, instability handling,
contacts, props and terrain queries."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from mocap.kinematics import forward_kinematics_dofs
from mocap.rotations import quat_from_rotvec, quat_mul, quat_normalize, quat_to_rotvec, quat_conjugate
from mocap.state import HumanoidState, SimState
from mocap.termination import allowed_contact_mask, fallen
from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator, TargetParams
from mocap_sim_mujoco.terrain import TerrainParams

F64 = torch.float64


@pytest.fixture(scope="module")
def library(amp):
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins

    motions = get_plugins().get("motion_source", "deepmimic").build({}).load(amp)
    return MotionLibrary(motions, amp, dtype=F64)


def make(skeleton, n, dtype=F64, **params):
    return MujocoSimulator(MujocoParams(**params), skeleton=skeleton, num_envs=n, dtype=dtype)


def frame_refs(library, clip_names, per_clip, seed=0):
    """Reference frames at exact frame times (where bodies are exactly the FK of the DoFs)."""
    rng = np.random.default_rng(seed)
    ids, times = [], []
    for name in clip_names:
        c = library.clip_names.index(name)
        clip = library.clips[c]
        frames = rng.choice(clip.num_frames - 1, size=per_clip, replace=False)
        ids += [c] * per_clip
        times += list(frames / clip.fps)
    return library.frames(torch.tensor(ids), torch.tensor(times, dtype=F64))


def still(state: HumanoidState) -> HumanoidState:
    """``state`` with every velocity zeroed."""
    from dataclasses import replace

    return replace(
        state,
        root_lin_vel=torch.zeros_like(state.root_lin_vel),
        root_ang_vel=torch.zeros_like(state.root_ang_vel),
        dof_vel=torch.zeros_like(state.dof_vel),
    )


def quat_err(a, b):
    return (1.0 - (a * b).sum(-1).abs()).abs()


def assert_finite(state: SimState):
    for name in ("root_pos", "root_rot", "root_lin_vel", "root_ang_vel", "dof_pos", "dof_vel", "body_pos", "body_rot", "contact_forces"):
        assert torch.isfinite(getattr(state, name)).all(), name


# ------------------------------------------------------------------------------ reset fidelity
def test_reset_reproduces_reference_frames(amp, library):
    ref = frame_refs(library, ["walk", "spin", "cartwheel", "backflip", "roll", "dance_a"], per_clip=6)
    n = ref.num_envs
    sim = make(amp, n, threads=1)
    sim.reset(torch.arange(n), ref)
    s = sim.state
    assert (s.body_pos - ref.body_pos).norm(dim=-1).max() < 1e-3  # 1 mm (observed ~1e-7 m)
    assert quat_err(s.body_rot, ref.body_rot).max() < 1e-8
    assert torch.allclose(s.dof_pos, ref.dof_pos, atol=1e-9)
    assert torch.allclose(s.dof_vel, ref.dof_vel, atol=1e-9)
    # root velocities: world linear, world angular (MuJoCo stores the free joint's angular velocity
    # in the root frame; the simulator must convert both ways)
    assert torch.allclose(s.root_pos, ref.root_pos, atol=1e-9)
    assert torch.allclose(s.root_lin_vel, ref.root_lin_vel, atol=1e-7)
    assert torch.allclose(s.root_ang_vel, ref.root_ang_vel, atol=1e-7)
    assert ref.root_ang_vel.norm(dim=-1).max() > 1.0  # the check is not vacuous

    # body velocities are the time derivative of FK along (root velocity, dof_vel): finite differences
    eps = 1e-6
    rot1 = quat_mul(quat_from_rotvec(ref.root_ang_vel * eps), ref.root_rot)
    p0, r0 = forward_kinematics_dofs(amp, ref.root_pos, ref.root_rot, ref.dof_pos)
    p1, r1 = forward_kinematics_dofs(amp, ref.root_pos + eps * ref.root_lin_vel, rot1, ref.dof_pos + eps * ref.dof_vel)
    lin_fd = (p1 - p0) / eps
    ang_fd = quat_to_rotvec(quat_mul(r1, quat_conjugate(r0))) / eps
    scale = 1.0 + lin_fd.norm(dim=-1)
    assert ((s.body_lin_vel - lin_fd).norm(dim=-1) / scale).max() < 1e-3
    assert ((s.body_ang_vel - ang_fd).norm(dim=-1) / (1.0 + ang_fd.norm(dim=-1))).max() < 1e-3

    # and close to the library's own (forward-difference) body velocities on a smooth clip
    walk = ref.clip_ids == library.clip_names.index("walk")
    assert (s.body_lin_vel[walk] - ref.body_lin_vel[walk]).norm(dim=-1).median() < 0.02
    assert (s.body_ang_vel[walk] - ref.body_ang_vel[walk]).norm(dim=-1).median() < 0.05
    sim.close()


def test_root_angular_velocity_frame_conversion(smpl):
    """A tilted, spinning root: world angular velocity in, the same world angular velocity out."""
    n = 8
    g = torch.Generator().manual_seed(1)
    sim = make(smpl, n, threads=1)
    st = sim.state
    rot = quat_normalize(torch.randn(n, 4, generator=g, dtype=F64))
    st.root_rot = rot
    st.root_pos = st.root_pos + torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    st.root_ang_vel = torch.randn(n, 3, generator=g, dtype=F64) * 3
    st.root_lin_vel = torch.randn(n, 3, generator=g, dtype=F64)
    sim.reset(torch.arange(n), st)
    s = sim.state
    assert quat_err(s.root_rot, rot).max() < 1e-12
    assert torch.allclose(s.root_ang_vel, st.root_ang_vel, atol=1e-10)
    assert torch.allclose(s.root_lin_vel, st.root_lin_vel, atol=1e-10)
    # MuJoCo's qvel holds R^T omega (local): check the raw layout too
    local = sim.qvel[:, sim.index.root_qvel + 3 : sim.index.root_qvel + 6]
    from mocap.rotations import quat_apply

    assert np.allclose(local, quat_apply(quat_conjugate(rot), st.root_ang_vel).numpy(), atol=1e-12)
    sim.close()


# ------------------------------------------------------------------------ env independence
def test_reset_subset_leaves_other_envs_bit_identical(amp, library):
    ref = frame_refs(library, ["walk", "run", "jump", "kick"], per_clip=2, seed=3)
    other = frame_refs(library, ["crawl", "punch"], per_clip=1, seed=4)
    n = ref.num_envs
    a, b = make(amp, n, threads=2), make(amp, n, threads=1)  # thread count must not matter either
    for sim in (a, b):
        sim.reset(torch.arange(n), ref)
    targets = ref.dof_pos
    for _ in range(5):
        sa, sb = a.step(targets), b.step(targets)
    for name in ("body_pos", "body_lin_vel", "dof_pos", "contact_forces"):
        assert torch.equal(getattr(sa, name), getattr(sb, name)), name
    sub = torch.tensor([1, 6])
    b.reset(sub, other)
    keep = torch.tensor([i for i in range(n) if i not in (1, 6)])
    for _ in range(10):
        sa, sb = a.step(targets), b.step(targets)
    for name in (
        "root_pos",
        "root_rot",
        "body_pos",
        "body_rot",
        "body_lin_vel",
        "body_ang_vel",
        "dof_pos",
        "dof_vel",
        "contact_forces",
        "body_contact",
        "dof_force",
    ):
        assert torch.equal(getattr(sa, name)[keep], getattr(sb, name)[keep]), name
    assert not torch.equal(sa.body_pos[sub], sb.body_pos[sub])
    # after a step the bodies are the forward kinematics of the returned root and DoFs (no lag)
    fk_pos, fk_rot = forward_kinematics_dofs(amp, sb.root_pos, sb.root_rot, sb.dof_pos)
    assert (fk_pos - sb.body_pos).norm(dim=-1).max() < 1e-9
    assert quat_err(fk_rot, sb.body_rot).max() < 1e-12
    # ... and the velocities are MuJoCo's own for that state (body origin, world frame)
    d = mujoco.MjData(b.model)
    v6 = np.zeros(6)
    for i in (0, 1):
        b.write_mjdata(i, d)
        for k, bid in enumerate(b.index.body_ids):
            mujoco.mj_objectVelocity(b.model, d, mujoco.mjtObj.mjOBJ_XBODY, int(bid), v6, 0)
            assert np.allclose(v6[3:], sb.body_lin_vel[i, k].numpy(), atol=1e-9)
            assert np.allclose(v6[:3], sb.body_ang_vel[i, k].numpy(), atol=1e-9)
    a.close()
    b.close()


# ------------------------------------------------------------------------------- stability
def test_every_deepmimic_clip_holds_its_reference_poses_for_2s(amp, library):
    ref = still(frame_refs(library, library.clip_names, per_clip=8, seed=5))
    n = ref.num_envs
    assert n == 8 * 15
    sim = make(amp, n, dtype=torch.float32)
    sim.reset(torch.arange(n), ref)
    targets = ref.dof_pos.float()
    for _ in range(60):
        s = sim.step(targets)
        assert not s.unstable.any()
    assert_finite(s)
    assert sim.instability_count == 0
    sim.close()


def test_smpl_random_poses_within_limits_for_2s(smpl):
    n = 48
    g = torch.Generator().manual_seed(6)
    lo = torch.tensor([h.range[0] for h in smpl.hinges], dtype=F64)
    hi = torch.tensor([h.range[1] for h in smpl.hinges], dtype=F64)
    dof = lo + (hi - lo) * torch.rand(n, smpl.num_dofs, generator=g, dtype=F64)
    sim = make(smpl, n, dtype=torch.float32)
    st = sim.state
    yaw = torch.rand(n, generator=g, dtype=F64) * 2 * math.pi
    st.root_rot = torch.stack([torch.cos(yaw / 2), 0 * yaw, 0 * yaw, torch.sin(yaw / 2)], -1)
    st.root_pos = torch.tensor([0.0, 0.0, 1.4], dtype=F64).expand(n, 3)  # high enough for any limb pose
    st.dof_pos = dof
    st.dof_vel = torch.zeros_like(dof)
    sim.reset(torch.arange(n), st)
    for _ in range(60):
        s = sim.step(dof.float())
        assert not s.unstable.any()
    assert_finite(s)
    assert sim.instability_count == 0
    sim.close()


@pytest.mark.parametrize("name", ["amp", "smpl"])
def test_standing_at_rest_pose_stays_up_10s(name, amp, smpl):
    sk = amp if name == "amp" else smpl
    sim = make(sk, 2, threads=1)
    h0 = float(sim.state.root_pos[0, 2])
    rest = torch.zeros(2, sk.num_dofs)
    allowed = allowed_contact_mask(sk)
    for _ in range(300):
        s = sim.step(rest)
        assert not fallen(s, allowed, 0.8 * h0).any()
    assert abs(float(s.root_pos[0, 2]) - h0) < 0.01
    assert s.root_pos[:, :2].norm(dim=-1).max() < 0.05
    assert sim.instability_count == 0
    sim.close()


# -------------------------------------------------------------------------------- instability
def test_instability_is_flagged_reset_and_counted(amp):
    n = 4
    a, b = make(amp, n, threads=1), make(amp, n, threads=1)
    rest = torch.zeros(n, amp.num_dofs)
    for _ in range(3):
        a.step(rest), b.step(rest)
    s = b.get_physics_state()
    s[2, b._qv : b._qv + b.model.nv] = 1e6  # absurd velocities, not a reset state
    b.set_physics_state(torch.tensor([2]), s[2:3], as_reset=False)
    sa, sb = a.step(rest), b.step(rest)
    assert sb.unstable.tolist() == [False, False, True, False]
    assert b.instability_count == 1 and a.instability_count == 0
    init = make(amp, 1, threads=1)
    assert np.array_equal(b.get_physics_state()[2], init.get_physics_state()[0])  # back to its last reset state
    assert np.isfinite(b.get_physics_state()).all()
    keep = [0, 1, 3]
    assert torch.equal(sa.body_pos[keep], sb.body_pos[keep])
    assert torch.equal(sa.dof_vel[keep], sb.dof_vel[keep])
    sb = b.step(rest)  # the run goes on
    assert not sb.unstable.any() and b.instability_count == 1
    for sim in (a, b, init):
        sim.close()


def test_nan_state_is_flagged(amp):
    sim = make(amp, 2, threads=1)
    s = sim.get_physics_state()
    s[1, sim._qp + 3] = float("nan")
    sim.set_physics_state(torch.tensor([1]), s[1:2], as_reset=False)
    st = sim.step(torch.zeros(2, amp.num_dofs))
    assert st.unstable.tolist() == [False, True]
    assert torch.isfinite(st.body_pos).all()
    sim.close()


# ----------------------------------------------------------------------------------- contacts
@pytest.mark.parametrize("name", ["amp", "smpl"])
def test_standing_contact_forces_carry_body_weight(name, amp, smpl):
    sk = amp if name == "amp" else smpl
    sim = make(sk, 1, threads=1)
    rest = torch.zeros(1, sk.num_dofs)
    for _ in range(30):
        s = sim.step(rest)
    weight = sk.total_mass * 9.81
    fz = float(s.contact_forces[0, :, 2].sum())
    assert abs(fz - weight) < 0.1 * weight
    feet = allowed_contact_mask(sk)
    assert not s.body_contact[0, ~feet].any()
    assert s.body_contact[0, feet].any()
    assert s.contact_forces[0, ~feet].abs().max() == 0
    assert s.contact_forces[0, feet, 2].min() >= 0  # the ground pushes up
    assert s.dof_force.shape == (1, sk.num_dofs) and torch.isfinite(s.dof_force).all()
    sim.close()


def test_lying_humanoid_has_fallen(amp):
    sim = make(amp, 1, threads=1)
    st = sim.state
    st.root_pos = torch.tensor([[0.0, 0.0, 0.2]], dtype=F64)
    st.root_rot = torch.tensor([[math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0]], dtype=F64)  # on its side
    sim.reset(torch.tensor([0]), st)
    for _ in range(10):
        s = sim.step(torch.zeros(1, amp.num_dofs))
    allowed = allowed_contact_mask(amp)
    assert s.body_contact[0, ~allowed].any()
    assert fallen(s, allowed, 0.5).all()
    sim.close()


# ------------------------------------------------------------------------------------- props
def test_target_prop_state_push_and_fall(amp):
    sim = make(amp, 2, threads=1, target=TargetParams(position=(2.0, 0.0)))
    t = sim.target_state()
    assert torch.allclose(t.pos, torch.tensor([2.0, 0.0, 0.8], dtype=F64).expand(2, 3))
    assert not t.fallen.any()
    sim.set_target(torch.tensor([1]), torch.tensor([[3.0, 1.0, 0.8]], dtype=F64))
    assert torch.allclose(sim.target_state().pos[1], torch.tensor([3.0, 1.0, 0.8], dtype=F64))
    # push env 0's box hard: it slides along +x and, being a tall pillar, topples
    s = sim.get_physics_state()
    s[0, sim._target_qvel] = 3.0
    sim.set_physics_state(torch.tensor([0]), s[0:1], as_reset=False)
    rest = torch.zeros(2, amp.num_dofs)
    sim.step(rest)
    assert sim.target_state().lin_vel[0, 0] > 1.0
    for _ in range(45):
        sim.step(rest)
    t = sim.target_state()
    assert t.pos[0, 0] > 2.2
    assert t.fallen.tolist() == [True, False]
    assert torch.allclose(t.pos[1], torch.tensor([3.0, 1.0, 0.8], dtype=F64), atol=1e-3)
    # a box laid on its side has fallen
    side = torch.tensor([[math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0]], dtype=F64)
    sim.set_target(torch.tensor([1]), torch.tensor([[3.0, 1.0, 0.2]], dtype=F64), side)
    assert sim.target_state().fallen.tolist() == [True, True]
    sim.close()


def test_markers_reach_mjdata(amp):
    sim = make(amp, 2, threads=1, markers=2)
    pos = torch.tensor([[[1.0, 2.0, 0.5], [0.0, -1.0, 1.0]]], dtype=F64)
    sim.set_markers(torch.tensor([1]), pos)
    d = sim.write_mjdata(1, mujoco.MjData(sim.model))
    assert np.allclose(d.mocap_pos, pos[0].numpy())
    assert torch.equal(sim.markers[1], pos[0])
    sim.close()


# ------------------------------------------------------------------------------------ terrain
@pytest.mark.parametrize("kind", ["rough", "stairs", "slopes"])
def test_terrain_height_matches_mujoco_ray(kind, amp):
    params = TerrainParams(kind=kind, size=3.0, resolution=0.1, amplitude=0.08, smoothing=2)
    sim = make(amp, 1, threads=1, terrain=params)
    d = sim.write_mjdata(0, mujoco.MjData(sim.model))
    rng = np.random.default_rng(7)
    r = rng.uniform(1.3, 2.9, 200)
    a = rng.uniform(0, 2 * np.pi, 200)
    pts = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    pts = pts[np.abs(pts).max(1) < 2.95]
    ours = sim.height_at(torch.tensor(pts, dtype=F64)).numpy()
    geom = np.zeros(1, np.int32)
    ray = np.array([5.0 - mujoco.mj_ray(sim.model, d, np.array([x, y, 5.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom) for x, y in pts])
    assert np.abs(ours - ray).max() < 1e-5
    assert ours.max() > 0.02  # not flat
    # the local height map is height_at on a rotated grid
    center = torch.tensor([[1.5, -0.5]], dtype=F64)
    heading = torch.tensor([0.7], dtype=F64)
    hm = sim.height_map(center, heading, shape=(5, 7), spacing=0.2)
    assert hm.shape == (1, 5, 7)
    i, j = 4, 1  # local offset ((4 - 2) * 0.2, (1 - 3) * 0.2) = (0.4, -0.4)
    c, s_ = math.cos(0.7), math.sin(0.7)
    p = center[0] + torch.tensor([c * 0.4 + s_ * 0.4, s_ * 0.4 - c * 0.4], dtype=F64)
    assert torch.allclose(hm[0, i, j], sim.height_at(p[None])[0])
    sim.close()


def test_terrain_profiles():
    from mocap_sim_mujoco.terrain import Terrain

    st = Terrain(TerrainParams(kind="stairs", size=5.0, resolution=0.05, flat_radius=1.0, step_height=0.1, step_width=0.4))
    x = torch.tensor([[0.0, 0.3], [1.1, 0.0], [1.5, 0.0], [1.0 + 0.4 * 5 + 0.2, 0.0], [-1.5, 2.0]], dtype=F64)
    assert torch.allclose(st.height_at(x), torch.tensor([0.0, 0.0, 0.1, 0.5, 0.1], dtype=F64), atol=1e-6)
    sl = Terrain(TerrainParams(kind="slopes", size=5.0, resolution=0.05, flat_radius=1.0, slope=0.2, slope_length=2.0))
    x = torch.tensor([[2.0, 0.0], [3.0, 1.0], [4.0, 0.0], [-2.0, 0.0]], dtype=F64)
    assert torch.allclose(sl.height_at(x), torch.tensor([0.2, 0.4, 0.2, 0.2], dtype=F64), atol=1e-6)
    flat = Terrain(TerrainParams(kind="flat", size=2.0))
    assert flat.height_at(torch.rand(10, 2, dtype=F64)).abs().max() == 0


def test_humanoid_stands_on_terrain_spawn_area(amp):
    sim = make(amp, 1, threads=1, terrain=TerrainParams(kind="rough", size=3.0))
    for _ in range(30):
        s = sim.step(torch.zeros(1, amp.num_dofs))
    assert not fallen(s, allowed_contact_mask(amp), 0.7).any()
    assert abs(float(s.contact_forces[0, :, 2].sum()) - amp.total_mass * 9.81) < 0.1 * amp.total_mass * 9.81
    sim.close()


# ----------------------------------------------------------------------------------- registry
def test_registry_builds_the_simulator(amp):
    from pydantic import ValidationError

    from mocap.plugins import get_plugins

    comp = get_plugins().get("simulator", "mujoco")
    sim = comp.build({"threads": 1, "substeps": 2}, skeleton=amp, num_envs=3, seed=1, device="cpu")
    assert isinstance(sim, MujocoSimulator) and sim.num_envs == 3
    assert sim.dt == pytest.approx(2 / 120)
    s = sim.step(torch.zeros(3, amp.num_dofs))
    assert s.body_pos.shape == (3, amp.num_bodies, 3) and s.body_pos.dtype == torch.float32
    assert s.contact_forces.shape == (3, amp.num_bodies, 3) and s.body_contact.dtype == torch.bool
    assert s.unstable.shape == (3,) and s.dof_force.shape == (3, amp.num_dofs)
    with pytest.raises(ValidationError):
        comp.validate_params({"timestep": 0.01, "bogus": 1})
    with pytest.raises(ValueError):
        sim.step(torch.zeros(2, amp.num_dofs))
    sim.close()
