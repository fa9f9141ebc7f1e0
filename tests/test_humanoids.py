"""Built-in humanoids (``amp``, ``smpl``) and the MJCF generated from them."""

from __future__ import annotations

import importlib.util
import math
from functools import lru_cache

import mujoco
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from mocap.humanoids import AmpParams, SmplParams, amp_skeleton, smpl_skeleton
from mocap.humanoids.common import rest_body_positions, rest_root_height
from mocap.skeleton import Body, Geom, Hinge, Joint, Skeleton
from mocap_sim_mujoco.mjcf import ROOT_JOINT, build_mjcf, build_model, model_index

AMP_BODIES = (
    "pelvis", "torso", "head", "right_upper_arm", "right_lower_arm", "right_hand",
    "left_upper_arm", "left_lower_arm", "left_hand", "right_thigh", "right_shin", "right_foot",
    "left_thigh", "left_shin", "left_foot",
)  # fmt: skip
SMPL_BODIES = (
    "Pelvis", "L_Hip", "L_Knee", "L_Ankle", "L_Toe", "R_Hip", "R_Knee", "R_Ankle", "R_Toe",
    "Torso", "Spine", "Chest", "Neck", "Head", "L_Thorax", "L_Shoulder", "L_Elbow", "L_Wrist",
    "L_Hand", "R_Thorax", "R_Shoulder", "R_Elbow", "R_Wrist", "R_Hand",
)  # fmt: skip
EXPECTED = {"amp": (AMP_BODIES, 28, 45.0), "smpl": (SMPL_BODIES, 69, 70.0)}


@lru_cache(maxsize=None)
def skeleton(name: str) -> Skeleton:
    return amp_skeleton() if name == "amp" else smpl_skeleton()


@lru_cache(maxsize=None)
def model(name: str) -> mujoco.MjModel:
    return build_model(skeleton(name))


# ------------------------------------------------------------------------------- skeletons
@pytest.mark.parametrize("name", ["amp", "smpl"])
def test_skeleton_shape(name: str) -> None:
    sk = skeleton(name)
    sk.validate()
    bodies, dofs, mass = EXPECTED[name]
    assert sk.name == name
    assert sk.body_names == bodies
    assert sk.num_bodies == len(bodies) and sk.num_dofs == dofs
    assert sk.total_mass == pytest.approx(mass)
    for h in sk.hinges:
        assert h.range[0] < h.range[1] and h.kp > 0 and h.kd > 0 and h.torque_limit > 0
        assert math.isclose(sum(a * a for a in h.axis), 1.0)
    assert len(sk.feet) >= 2 and len(sk.end_effectors) == 5


def test_amp_facts() -> None:
    sk = skeleton("amp")
    assert [b.parent for b in sk.bodies] == [-1, 0, 1, 1, 3, 4, 1, 6, 7, 0, 9, 10, 0, 12, 13]
    kinds = {b.name: (b.joint.kind, len(b.joint.hinges)) for b in sk.bodies[1:]}
    assert kinds["right_hand"] == ("fixed", 0) and kinds["left_hand"] == ("fixed", 0)
    assert kinds["right_lower_arm"] == ("hinge", 1) and kinds["left_shin"] == ("hinge", 1)
    for ball in ("torso", "head", "right_upper_arm", "left_thigh", "right_foot"):
        assert kinds[ball] == ("ball", 3)
    assert sk.dof_names[:3] == ("chest_y", "chest_x", "chest_z")
    assert "right_hip_y" in sk.dof_names and "right_knee" in sk.dof_names and "left_elbow" in sk.dof_names
    # URDF joint origins x 0.25, rotated y-up -> z-up
    b = {x.name: x for x in sk.bodies}
    assert b["torso"].offset == pytest.approx((0.0, 0.0, 0.944604 * 0.25))
    assert b["right_thigh"].offset == pytest.approx((0.0, -0.339548 * 0.25, 0.0))  # right is -y
    assert b["left_upper_arm"].offset == pytest.approx((-0.0962 * 0.25, 0.73244 * 0.25, 0.974 * 0.25))
    knee = b["right_shin"].joint.hinges[0]
    assert knee.axis == (0.0, -1.0, 0.0) and knee.range == pytest.approx((-3.14, 0.0))
    assert b["right_lower_arm"].joint.hinges[0].range == pytest.approx((0.0, 3.14))
    # DeepMimic gains, mirrored ranges
    assert (knee.kp, knee.kd, knee.torque_limit) == (500.0, 50.0, 150.0)
    rx = {h.name: h.range for h in sk.hinges}
    assert rx["left_hip_x"] == pytest.approx((-rx["right_hip_x"][1], -rx["right_hip_x"][0]))
    assert sk.end_effectors == ("head", "right_hand", "left_hand", "right_foot", "left_foot")
    assert sk.feet == ("right_foot", "left_foot")
    assert rest_root_height(sk) == pytest.approx(0.881416)


def test_smpl_facts() -> None:
    sk = skeleton("smpl")
    assert all(b.joint.kind == "ball" and len(b.joint.hinges) == 3 for b in sk.bodies[1:])
    assert sk.dof_names[:3] == ("L_Hip_x", "L_Hip_y", "L_Hip_z")
    pos = dict(zip(sk.body_names, rest_body_positions(sk)))
    assert pos["L_Hip"][1] > 0 > pos["R_Hip"][1]  # left is +y
    assert pos["L_Wrist"][1] > pos["L_Elbow"][1] > pos["L_Shoulder"][1]  # T-pose
    h = rest_root_height(sk)
    assert 0.9 < h < 1.0
    tall = smpl_skeleton(height=1.87, mass=90.0)
    assert rest_root_height(tall) == pytest.approx(h * 1.1)
    assert tall.total_mass == pytest.approx(90.0)


def test_registered_as_plugins() -> None:
    from mocap.plugins import load_plugins

    pset = load_plugins()
    assert {"amp", "smpl"} <= set(pset.names("humanoid"))
    assert pset.get("humanoid", "amp").build({"gain_scale": 2.0}).hinges[0].kp == 2000.0
    assert pset.get("humanoid", "smpl").build(None).num_dofs == 69
    with pytest.raises(ValidationError):
        AmpParams.model_validate({"scale": 2.0})
    with pytest.raises(ValidationError):
        SmplParams.model_validate({"height": -1.0})


# ----------------------------------------------------------------------------------- MJCF
@pytest.mark.parametrize("name", ["amp", "smpl"])
def test_model_matches_skeleton(name: str) -> None:
    sk, m = skeleton(name), model(name)
    idx = model_index(m, sk)
    assert idx.identity_order
    assert m.nbody == sk.num_bodies + 1 and m.nu == sk.num_dofs and m.nv == 6 + sk.num_dofs
    assert [m.body(i).name for i in range(1, m.nbody)] == list(sk.body_names)
    assert [m.joint(i).name for i in range(m.njnt)] == [ROOT_JOINT, *sk.dof_names]
    assert [m.actuator(i).name for i in range(m.nu)] == list(sk.dof_names)
    np.testing.assert_allclose(m.body_mass[idx.body_ids], [b.mass for b in sk.bodies], rtol=1e-9)
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert m.opt.timestep == pytest.approx(1 / 120)
    for j, h in enumerate(sk.hinges):
        a = idx.actuator_ids[j]
        assert m.actuator_gainprm[a, 0] == pytest.approx(h.kp)
        assert m.actuator_biasprm[a, 1] == pytest.approx(-h.kp)
        assert m.actuator_biasprm[a, 2] == pytest.approx(-h.kd)
        np.testing.assert_allclose(m.actuator_forcerange[a], (-h.torque_limit, h.torque_limit))
        np.testing.assert_allclose(m.actuator_ctrlrange[a], h.range)
        np.testing.assert_allclose(m.jnt_range[idx.joint_ids[j]], h.range)
        assert m.dof_armature[idx.dof_qvel[j]] == pytest.approx(h.armature)
        assert m.dof_damping[idx.dof_qvel[j]] == 0.0
    # body geoms touch the floor only; at rest the soles touch the floor
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert d.ncon > 0
    for c in d.contact[: d.ncon]:
        assert idx.floor_geom in (c.geom1, c.geom2)
        other = c.geom2 if c.geom1 == idx.floor_geom else c.geom1
        assert sk.bodies[idx.geom_body[other]].name in sk.feet
        assert abs(c.dist) < 1e-6


def test_model_index_for_non_depth_first_skeleton() -> None:
    hinge = lambda n: Joint("hinge", (Hinge(n, (0.0, 1.0, 0.0), (-1.0, 1.0), 10.0, 1.0, 10.0),))  # noqa: E731
    ball = (Geom("sphere", (0.05,)),)
    sk = Skeleton(
        "toy",
        (
            Body("root", -1, (0, 0, 0), Joint("fixed"), 1.0, ball),
            Body("a", 0, (0, 0.2, 0), hinge("ja"), 1.0, ball),
            Body("b", 0, (0, -0.2, 0), hinge("jb"), 1.0, ball),
            Body("c", 1, (0, 0, -0.3), hinge("jc"), 1.0, ball),  # MuJoCo puts c before b
        ),
    )
    m = build_model(sk)
    idx = model_index(m, sk)
    assert not idx.identity_order
    assert [m.body(int(i)).name for i in idx.body_ids] == ["root", "a", "b", "c"]
    assert [m.joint(int(i)).name for i in idx.joint_ids] == ["ja", "jb", "jc"]
    assert [m.actuator(int(i)).name for i in idx.actuator_ids] == ["ja", "jb", "jc"]
    assert list(idx.dof_qpos) == [int(m.jnt_qposadr[i]) for i in idx.joint_ids]
    assert "<freejoint" in build_mjcf(sk) and 'name="floor"' not in build_mjcf(sk, floor=False)


@pytest.mark.parametrize("name", ["amp", "smpl"])
def test_stands_at_rest(name: str) -> None:
    """PD targets = rest pose for 10 s (1200 steps at 1/120): no NaN, no fall."""
    m = model(name)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    h0 = float(d.qpos[2])
    d.ctrl[:] = 0.0
    heights = np.empty(1200)
    for k in range(1200):
        mujoco.mj_step(m, d)
        heights[k] = d.qpos[2]
    assert np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()
    assert heights.min() > 0.7 * h0
    assert abs(heights[-1] - h0) < 0.01  # it stands still, not merely stays up


# ------------------------------------------------------------------- FK vs MuJoCo (last)
def _unit_quat(u: list[float]) -> np.ndarray:
    q = np.asarray(u, dtype=np.float64)
    n = np.linalg.norm(q)
    return np.array([1.0, 0.0, 0.0, 0.0]) if n < 1e-3 else q / n


@pytest.mark.skipif(importlib.util.find_spec("mocap.kinematics") is None, reason="mocap.kinematics not written yet")
@pytest.mark.parametrize("name", ["amp", "smpl"])
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_forward_kinematics_matches_mujoco(name: str, data: st.DataObject) -> None:
    import torch

    from mocap import kinematics as kin

    sk, m = skeleton(name), model(name)
    idx = model_index(m, sk)
    unit = st.floats(0.0, 1.0, allow_nan=False)
    fracs = np.array(data.draw(st.lists(unit, min_size=sk.num_dofs, max_size=sk.num_dofs)))
    low, high = np.array([h.range for h in sk.hinges]).T
    dofs = low + fracs * (high - low)
    root_pos = np.array(data.draw(st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3)))
    root_rot = _unit_quat(data.draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))

    d = mujoco.MjData(m)
    d.qpos[idx.root_qpos : idx.root_qpos + 3] = root_pos
    d.qpos[idx.root_qpos + 3 : idx.root_qpos + 7] = root_rot
    d.qpos[idx.dof_qpos] = dofs
    mujoco.mj_kinematics(m, d)

    t = lambda a: torch.as_tensor(a, dtype=torch.float64)[None]  # noqa: E731
    pos, rot = kin.forward_kinematics_dofs(sk, t(root_pos), t(root_rot), t(dofs))
    pos, rot = pos[0].numpy(), rot[0].numpy()
    np.testing.assert_allclose(pos, d.xpos[idx.body_ids], atol=1e-3)
    dots = np.abs(np.sum(rot * d.xquat[idx.body_ids], axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-6)  # equal up to sign
