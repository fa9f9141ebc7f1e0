"""The parameter models of the ``mujoco`` simulator: :class:`MujocoParams` and its
:class:`TargetParams` (the ``strike`` task's prop); :mod:`mocap_sim_mujoco.simulator` re-exports both."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from mocap.bounds import ThreadCount
from mocap_sim_mujoco.actuators import ActuatorModelParams
from mocap_sim_mujoco.terrain import TerrainParams

__all__ = ["MujocoParams", "TargetParams"]


class TargetParams(BaseModel):
    """A movable box standing on the ground in every env (the ``strike`` task's target)."""

    model_config = ConfigDict(extra="forbid")

    half_size: tuple[float, float, float] = Field((0.2, 0.2, 0.8), description="box half extents x, y, z, m")
    mass: float = Field(20.0, gt=0.0, description="kg")
    friction: float = Field(0.9, gt=0.0)
    position: tuple[float, float] = Field((2.0, 0.0), description="initial xy of the box centre, m (it stands on the ground)")
    fallen_angle: float = Field(45.0, gt=0.0, lt=180.0, description="tilt of the box's z axis beyond which it counts as fallen, deg")
    rgba: tuple[float, float, float, float] = (0.9, 0.3, 0.2, 1.0)


class MujocoParams(BaseModel):
    """Parameters of the ``mujoco`` simulator (module docstring). Control period = ``timestep * substeps``."""

    model_config = ConfigDict(extra="forbid")

    timestep: float = Field(1.0 / 120.0, gt=0.0, le=0.05, description="physics step, s")
    substeps: int = Field(4, ge=1, le=64, description="physics steps per control step (1/30 s by default)")
    threads: ThreadCount | None = Field(None, description="rollout worker threads (default: all cores)")
    chunk_size: int | None = Field(None, ge=1, description="envs per thread-pool task (default: MuJoCo's N / (10 threads))")
    iterations: int = Field(20, ge=1, description="constraint solver iterations")
    ls_iterations: int = Field(10, ge=1, description="solver line-search iterations")
    self_collision: bool = Field(False, description="let body geoms collide with each other")
    joint_limits: bool = Field(True, description="hinge ranges are hard limits (PD targets are clamped to them either way)")
    max_qvel: float = Field(1000.0, gt=0.0, description="instability: any |qvel| (or |qpos|) entry above this (rad/s, m/s)")
    max_qacc: float = Field(1.0e6, gt=0.0, description="instability: |change of qvel| / dt over a control step above this")
    terrain: TerrainParams | None = Field(None, description="height-field ground (default: the plane z = 0)")
    target: TargetParams | None = Field(None, description="a movable box per env (strike task)")
    markers: int = Field(0, ge=0, le=256, description="visual-only marker spheres per env")
    marker_radius: float = Field(0.05, gt=0.0)
    marker_rgba: tuple[float, float, float, float] = (0.95, 0.15, 0.15, 1.0)
    actuator_model: ActuatorModelParams | None = Field(
        None,
        description="VMP's actuator model (Eqs. 9-11: PD, Coulomb + viscous friction, torque-speed envelope) computed by the "
        "simulator at every physics step on motor actuators (mocap_sim_mujoco.actuators); default None = MuJoCo position "
        "actuators. The PD damping becomes explicit: needs timestep <= ~1/555 s on amp (refused above; use timestep 0.0016667, "
        "substeps 20 for a 30 Hz control step)",
    )

    @property
    def dt(self) -> float:
        return self.timestep * self.substeps
