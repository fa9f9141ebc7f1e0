"""MJCF generated from a :class:`~mocap.skeleton.Skeleton` (no hand-written model files).

Model layout:

* bodies nest as in the skeleton, each at ``pos = offset`` with identity orientation (every body
  frame is world-aligned at rest); the root carries a ``freejoint`` named ``root`` and starts at
  ``root_height`` (default: the rest pose's lowest geom touching the floor);
* every :class:`~mocap.skeleton.Hinge` becomes a ``hinge`` joint with the hinge's name, axis,
  armature and range (``limited`` when ``joint_limits``), zero damping and zero stiffness: all PD
  lives in the actuators;
* one ``position`` actuator per hinge, named like it, with ``kp``/``kv`` = the hinge's kp/kd,
  ``forcerange`` = +-torque limit (``forcelimited``) and ``ctrlrange`` = the joint range
  (``ctrllimited``: PD targets outside the range are clamped to it). With ``implicitfast`` the kv
  damping is integrated implicitly, which is what keeps kp ~ 1000 stable at a 1/120 s step;
* mass: each geom gets a ``mass`` attribute so that the geoms of a body add up to the body's mass
  (split by volume, see :func:`mocap.humanoids.common.geom_masses`); MuJoCo derives the body's
  inertia and centre of mass from those geoms (``inertiafromgeom``);
* contacts: body geoms have contype 2 / conaffinity 1 and the floor 1 / 1, so body geoms collide
  with the floor and never with each other (no self-collision: it is cheaper, avoids the
  permanent self-contacts of overlapping limb capsules, and imitation references are collision-free
  to begin with). ``self_collision=True`` gives body geoms contype 1 / conaffinity 1 instead
  (MuJoCo still excludes parent/child pairs). Friction is the skeleton's, on body geoms and floor.

Orders: MuJoCo numbers bodies depth-first in XML order. The skeleton's order is parents-first but
not necessarily depth-first, so :class:`ModelIndex` maps skeleton order to MuJoCo ids/addresses;
for the built-in ``amp`` and ``smpl`` skeletons (both depth-first) the orders coincide.

Measured (mujoco 4.0.0, defaults: timestep 1/120, implicitfast, 20/10 iterations):

* ``amp``: total mass 45.0 kg (the URDF's 45 kg). Rest pose: pelvis (root) at 0.8814 m with the
  foot-box soles at z = 0 (hip 0 below the pelvis origin, thigh 0.4215, shin 0.4099, ankle to sole
  0.0500); the lowest non-foot geom (shin capsule) clears the floor by 0.0549 m; head top 1.619 m;
  centre of mass 0.892 m. Standing 10 s with PD targets = rest, the pelvis settles at 0.8809 m.
  Walk clip (``humanoid3d_walk``, mapped as described in :mod:`mocap.humanoids.amp`): pelvis
  0.847-0.874 m, lowest foot point -5.3 to +13.7 mm, neck (head origin) 1.304-1.333 m.
* ``smpl`` (1.70 m, 70 kg): total mass 70.0 kg. Rest (T-pose): pelvis at 0.9520 m, soles at z = 0,
  lowest non-foot geom (shin) 0.0578 m above the floor, head top 1.695 m; standing 10 s it settles
  at 0.9513 m.
* Random PD targets (sigma 0.3, 0.5 and 1.0 rad, resampled at 30 Hz, 4 substeps): no unstable
  episode for ``amp`` (armature 0.05) or ``smpl`` (armature 0.1).
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np

from mocap.humanoids.common import geom_masses, rest_root_height
from mocap.skeleton import Geom, Skeleton

__all__ = ["ModelIndex", "build_mjcf", "build_model", "model_index", "FLOOR_GEOM", "ROOT_JOINT"]

FLOOR_GEOM = "floor"
ROOT_JOINT = "root"


def _f(v: float) -> str:
    return f"{float(v):.9g}"


def _vec(values: tuple[float, ...] | list[float] | np.ndarray) -> str:
    return " ".join(_f(v) for v in values)


def _geom_xml(body_name: str, i: int, geom: Geom, mass: float, contype: int, conaffinity: int, friction: float) -> str:
    attrs = [f'name="{body_name}_geom{i}"', f'type="{geom.type}"']
    if geom.type == "sphere":
        attrs += [f'size="{_f(geom.size[0])}"', f'pos="{_vec(geom.pos)}"']
    elif geom.type == "capsule":
        if geom.fromto is None:
            raise ValueError(f"{body_name}: capsule geom needs fromto")
        attrs += [f'size="{_f(geom.size[0])}"', f'fromto="{_vec(geom.fromto)}"']
    elif geom.type == "box":
        attrs += [f'size="{_vec(geom.size[:3])}"', f'pos="{_vec(geom.pos)}"']
    else:
        raise ValueError(f"{body_name}: unknown geom type {geom.type!r}")
    attrs += [
        f'mass="{_f(mass)}"',
        f'contype="{contype}"',
        f'conaffinity="{conaffinity}"',
        f'friction="{_f(friction)} 0.005 0.0001"',
    ]
    return f"<geom {' '.join(attrs)}/>"


def build_mjcf(
    skeleton: Skeleton,
    *,
    timestep: float = 1.0 / 120.0,
    integrator: str = "implicitfast",
    iterations: int = 20,
    ls_iterations: int = 10,
    floor: bool = True,
    floor_size: float = 50.0,
    root_height: float | None = None,
    joint_limits: bool = True,
    self_collision: bool = False,
    friction: float | None = None,
    extra_worldbody: str = "",
    extra_xml: str = "",
) -> str:
    """The MJCF text of ``skeleton`` (see the module docstring for the layout).

    Args:
        timestep: physics step, s (4 steps per 30 Hz control step at the default 1/120).
        integrator: MuJoCo integrator; ``implicitfast`` integrates the actuators' kv implicitly.
        iterations, ls_iterations: constraint solver and line-search iterations.
        floor: add a ground plane named ``floor`` at z = 0.
        floor_size: half extent of the plane, m (collision is infinite either way).
        root_height: initial root height (``qpos0``); default: the rest pose stands on the floor.
        joint_limits: make hinge ranges hard joint limits (ctrlrange is the range either way).
        self_collision: let body geoms collide with each other (not parent/child).
        friction: sliding friction of body geoms and floor (default: ``skeleton.friction``).
        extra_worldbody: XML inserted into ``<worldbody>`` (props, cameras, lights).
        extra_xml: XML inserted at the end of ``<mujoco>`` (sensors, contact excludes, keyframes...).
    """
    skeleton.validate()
    mu = skeleton.friction if friction is None else friction
    height = rest_root_height(skeleton) if root_height is None else root_height
    contype, conaffinity = (1, 1) if self_collision else (2, 1)
    masses = geom_masses(skeleton)

    children: dict[int, list[int]] = {i: [] for i in range(skeleton.num_bodies)}
    for i, body in enumerate(skeleton.bodies[1:], start=1):
        children[body.parent].append(i)

    lines: list[str] = []

    def emit_body(i: int, depth: int) -> None:
        body = skeleton.bodies[i]
        pad = "  " * depth
        pos = (0.0, 0.0, height) if i == 0 else body.offset
        lines.append(f'{pad}<body name={quoteattr(body.name)} pos="{_vec(pos)}">')
        if i == 0:
            lines.append(f'{pad}  <freejoint name="{ROOT_JOINT}"/>')
        else:
            for h in body.joint.hinges:
                lim = f'limited="true" range="{_f(h.range[0])} {_f(h.range[1])}"' if joint_limits else 'limited="false"'
                lines.append(
                    f'{pad}  <joint name={quoteattr(h.name)} type="hinge" axis="{_vec(h.axis)}" {lim} armature="{_f(h.armature)}" damping="0" stiffness="0"/>'
                )
        if not body.geoms:
            # a massless body would be rejected by MuJoCo; give it an explicit point inertia
            inertia = max(body.mass, 1e-6) * 1e-4
            lines.append(f'{pad}  <inertial pos="0 0 0" mass="{_f(max(body.mass, 1e-6))}" diaginertia="{_vec((inertia,) * 3)}"/>')
        for k, (geom, mass) in enumerate(zip(body.geoms, masses[i])):
            lines.append(f"{pad}  {_geom_xml(body.name, k, geom, mass, contype, conaffinity, mu)}")
        for c in children[i]:
            emit_body(c, depth + 1)
        lines.append(f"{pad}</body>")

    emit_body(0, 2)

    actuators = [
        f'    <position name={quoteattr(h.name)} joint={quoteattr(h.name)} kp="{_f(h.kp)}" kv="{_f(h.kd)}" '
        f'ctrllimited="true" ctrlrange="{_f(h.range[0])} {_f(h.range[1])}" '
        f'forcelimited="true" forcerange="{_f(-h.torque_limit)} {_f(h.torque_limit)}"/>'
        for h in skeleton.hinges
    ]

    floor_xml = (
        f'    <geom name="{FLOOR_GEOM}" type="plane" size="{_f(floor_size)} {_f(floor_size)} 0.1" material="grid" '
        f'contype="1" conaffinity="1" friction="{_f(mu)} 0.005 0.0001"/>'
        if floor
        else ""
    )
    return "\n".join(
        [
            f"<mujoco model={quoteattr(skeleton.name)}>",
            '  <compiler angle="radian" inertiafromgeom="true" autolimits="true"/>',
            f'  <option timestep="{_f(timestep)}" integrator="{integrator}" iterations="{iterations}" ls_iterations="{ls_iterations}" gravity="0 0 -9.81"/>',
            '  <visual><global offwidth="1280" offheight="720"/><headlight ambient="0.3 0.3 0.3" diffuse="0.6 0.6 0.6"/></visual>',
            "  <asset>",
            '    <texture name="grid" type="2d" builtin="checker" rgb1="0.2 0.3 0.4" rgb2="0.3 0.4 0.5" width="256" height="256"/>',
            '    <material name="grid" texture="grid" texrepeat="10 10" reflectance="0.1"/>',
            "  </asset>",
            '  <default><geom rgba="0.8 0.6 0.4 1"/></default>',
            "  <worldbody>",
            '    <light name="sun" pos="0 0 6" dir="0 0 -1" directional="true"/>',
            floor_xml,
            *lines,
            extra_worldbody,
            "  </worldbody>",
            "  <actuator>",
            *actuators,
            "  </actuator>",
            extra_xml,
            "</mujoco>",
        ]
    )


@dataclass(frozen=True)
class ModelIndex:
    """Where the skeleton's bodies and DoFs live in a compiled :class:`mujoco.MjModel`.

    Attributes:
        body_ids: (B,) MuJoCo body id of each skeleton body (skeleton body order).
        dof_qpos: (D,) ``qpos`` address of each hinge (skeleton DoF order).
        dof_qvel: (D,) ``qvel``/``qacc`` address of each hinge.
        joint_ids: (D,) MuJoCo joint id of each hinge.
        actuator_ids: (D,) MuJoCo actuator id driving each hinge (index into ``ctrl``).
        root_qpos: address of the free joint's 7 ``qpos`` (pos xyz, quat wxyz).
        root_qvel: address of its 6 ``qvel`` (linear velocity in world axes, angular velocity in the
            root's local frame, as MuJoCo stores free joints).
        geom_body: (ngeom,) skeleton body index of each geom, -1 for world geoms (floor, props).
        floor_geom: geom id of the floor, -1 without one.
        identity_order: MuJoCo's body/dof/actuator order equals the skeleton's (plain slicing works:
            bodies 1..B, ``qpos[7:]``, ``qvel[6:]``, ``ctrl``).
    """

    body_ids: np.ndarray
    dof_qpos: np.ndarray
    dof_qvel: np.ndarray
    joint_ids: np.ndarray
    actuator_ids: np.ndarray
    root_qpos: int
    root_qvel: int
    geom_body: np.ndarray
    floor_geom: int
    identity_order: bool


def model_index(model: mujoco.MjModel, skeleton: Skeleton) -> ModelIndex:
    """Index maps between ``model`` (built by :func:`build_model`) and ``skeleton``."""
    obj = mujoco.mjtObj
    body_ids = np.array([mujoco.mj_name2id(model, obj.mjOBJ_BODY, b.name) for b in skeleton.bodies], dtype=np.int64)
    joint_ids = np.array([mujoco.mj_name2id(model, obj.mjOBJ_JOINT, h.name) for h in skeleton.hinges], dtype=np.int64)
    act_ids = np.array([mujoco.mj_name2id(model, obj.mjOBJ_ACTUATOR, h.name) for h in skeleton.hinges], dtype=np.int64)
    missing = [n for n, i in zip(skeleton.body_names, body_ids) if i < 0]
    missing += [n for n, i in zip(skeleton.dof_names, joint_ids) if i < 0]
    missing += [f"actuator {n}" for n, i in zip(skeleton.dof_names, act_ids) if i < 0]
    if missing:
        raise ValueError(f"model lacks skeleton elements: {', '.join(missing)}")
    root_joint = mujoco.mj_name2id(model, obj.mjOBJ_JOINT, ROOT_JOINT)
    if root_joint < 0:
        raise ValueError(f"model has no free joint named {ROOT_JOINT!r}")
    body_to_skel = {int(b): i for i, b in enumerate(body_ids)}
    geom_body = np.array([body_to_skel.get(int(b), -1) for b in model.geom_bodyid], dtype=np.int64)
    floor = mujoco.mj_name2id(model, obj.mjOBJ_GEOM, FLOOR_GEOM)
    dof_qpos = model.jnt_qposadr[joint_ids].astype(np.int64)
    dof_qvel = model.jnt_dofadr[joint_ids].astype(np.int64)
    root_qpos = int(model.jnt_qposadr[root_joint])
    root_qvel = int(model.jnt_dofadr[root_joint])
    nb, nd = skeleton.num_bodies, skeleton.num_dofs
    identity = (
        bool(np.array_equal(body_ids, np.arange(1, nb + 1)))
        and root_qpos == 0
        and bool(np.array_equal(dof_qpos, np.arange(7, 7 + nd)))
        and bool(np.array_equal(dof_qvel, np.arange(6, 6 + nd)))
        and bool(np.array_equal(act_ids, np.arange(nd)))
    )
    return ModelIndex(
        body_ids=body_ids,
        dof_qpos=dof_qpos,
        dof_qvel=dof_qvel,
        joint_ids=joint_ids,
        actuator_ids=act_ids,
        root_qpos=root_qpos,
        root_qvel=root_qvel,
        geom_body=geom_body,
        floor_geom=int(floor),
        identity_order=identity,
    )


def build_model(skeleton: Skeleton, **opts: object) -> mujoco.MjModel:
    """Compile :func:`build_mjcf` ``(skeleton, **opts)`` into a :class:`mujoco.MjModel`."""
    xml = build_mjcf(skeleton, **opts)  # type: ignore[arg-type]
    try:
        return mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:
        raise ValueError(f"MuJoCo rejected the MJCF generated for skeleton {skeleton.name!r}: {exc}") from exc
