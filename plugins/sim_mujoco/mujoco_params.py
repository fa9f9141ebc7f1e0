"""The parameter models of the ``mujoco`` simulator: :class:`MujocoParams`, its :class:`TargetParams`
(the ``strike`` task's prop) and :class:`TerrainParams` (:mod:`mocap_sim_mujoco.terrain` documents and
re-exports it); :mod:`mocap_sim_mujoco.simulator` re-exports the first two. Torch- and MuJoCo-free, so
that validating a spec imports neither."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from mocap.bounds import ThreadCount
from mocap_sim_mujoco.actuators import ActuatorModelParams

__all__ = ["MujocoParams", "TargetParams", "TerrainParams"]


class TerrainParams(BaseModel):
    """A height-field terrain (module docstring)."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["flat", "rough", "stairs", "slopes", "obstacles"] = "rough"
    size: float = Field(10.0, gt=0.5, description="half extent of the square terrain, m")
    resolution: float = Field(0.1, gt=0.005, description="grid spacing, m")
    flat_radius: float = Field(1.0, ge=0.0, description="half side of the flat spawn square around the origin, m")
    amplitude: float = Field(0.05, ge=0.0, description="rough: maximum height, m")
    smoothing: int = Field(1, ge=1, description="rough: box-filter width in cells (1 = none)")
    step_height: float = Field(0.1, ge=0.0, description="stairs: rise per step, m")
    step_width: float = Field(0.4, gt=0.0, description="stairs: depth per step, m")
    steps_per_flight: int = Field(5, ge=1, description="stairs: steps up before the flight goes down again")
    slope: float = Field(0.15, ge=0.0, le=2.0, description="slopes: gradient, rise / run")
    slope_length: float = Field(2.0, gt=0.0, description="slopes: horizontal length of one ramp, m")
    obstacle_count: int = Field(100, ge=0, description="obstacles: number of blocks")
    obstacle_size: tuple[float, float] = Field((0.3, 1.0), description="obstacles: side length U[min, max], m")
    obstacle_height: tuple[float, float] = Field((0.05, 0.3), description="obstacles: height U[min, max], m")
    seed: int | None = Field(None, description="rough / obstacles: random seed (default: the simulator's seed)")


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
