"""Built-in humanoids (plugin module of the ``mocap`` entry-point group).

* ``amp``: the DeepMimic/AMP humanoid, 15 bodies, 28 DoF, 45 kg (:func:`~mocap.humanoids.amp.amp_skeleton`);
* ``smpl``: the SMPL kinematic tree in PHC's body order, 24 bodies, 69 DoF, own anthropometric
  proportions (:func:`~mocap.humanoids.smpl.smpl_skeleton`).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from mocap.hooks import hookimpl
from mocap.humanoids.amp import amp_skeleton
from mocap.humanoids.smpl import smpl_skeleton
from mocap.skeleton import Skeleton

__all__ = ["AmpParams", "SmplParams", "amp_skeleton", "make_amp", "make_smpl", "smpl_skeleton"]


class AmpParams(BaseModel):
    """Parameters of the ``amp`` humanoid (geometry and masses are DeepMimic's, not tunable)."""

    model_config = ConfigDict(extra="forbid")

    armature: float = Field(0.05, ge=0.0, description="rotor inertia added to every hinge, kg m^2")
    gain_scale: float = Field(1.0, gt=0.0, description="multiplies every kp and kd of DeepMimic's table")
    torque_scale: float = Field(1.0, gt=0.0, description="multiplies every torque limit")
    friction: float = Field(0.9, gt=0.0, description="sliding friction of the body geoms")
    shoulder_turns: float = Field(
        0.5,
        gt=0.0,
        le=64.0,
        description="range of the shoulders' y and z hinges in full turns each way (0.5: +-180 deg, the checkpoints up to "
        "imitator_amp_v5). The DeepMimic clips cross the y-x-z decomposition's singularity, and the unwrapped shoulder "
        "angles of punch, spinkick, backflip, dance_a, dance_b and spin leave +-180 deg within 0.8 s; 8 "
        "(mocap.humanoids.amp.FREE_SHOULDER_TURNS) admits every bundled clip, and looping clips then carry their "
        "per-cycle winding on (MotionLibrary)",
    )
    shoulder_order: Literal["yxz", "xzy"] = Field(
        "yxz",
        description="hinge order of the shoulders: 'yxz' (every ball joint's; the checkpoints up to imitator_amp_v5) or "
        "'xzy', whose singularity the clips stay away from (at most 34 rad/s asked of a shoulder hinge instead of 81; "
        "mocap.humanoids.amp.SHOULDER_ORDERS)",
    )


class SmplParams(BaseModel):
    """Parameters of the ``smpl`` humanoid."""

    model_config = ConfigDict(extra="forbid")

    height: float = Field(1.70, gt=0.5, lt=2.5, description="standing height, m (all lengths scale with it)")
    mass: float = Field(70.0, gt=10.0, lt=250.0, description="total mass, kg (all segment masses scale with it)")
    armature: float = Field(0.1, ge=0.0, description="rotor inertia added to every hinge, kg m^2")
    gain_scale: float = Field(1.0, gt=0.0, description="multiplies every kp and kd of PHC's table")
    torque_limit: float = Field(500.0, gt=0.0, description="actuator torque limit of every hinge, N m")
    friction: float = Field(1.0, gt=0.0, description="sliding friction of the body geoms")


def make_amp(params: AmpParams) -> Skeleton:
    return amp_skeleton(**params.model_dump())


def make_smpl(params: SmplParams) -> Skeleton:
    return smpl_skeleton(**params.model_dump())


@hookimpl
def register_humanoids(register):  # type: ignore[no-untyped-def]
    register(
        "amp",
        make_amp,
        params=AmpParams,
        description="DeepMimic/AMP humanoid from pybullet's humanoid.urdf: 15 bodies, 28 DoF, 45 kg",
    )
    register(
        "smpl",
        make_smpl,
        params=SmplParams,
        description="SMPL kinematic tree (PHC body order): 24 bodies, 69 DoF, own adult proportions",
    )
