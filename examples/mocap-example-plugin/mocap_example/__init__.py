"""An example third-party mocap plugin: a motion source, a metric, a downstream task and a latent space.

Install it with ``pip install ./examples/mocap-example-plugin`` (from the mocap repository);
its ``pyproject.toml`` publishes this module under the ``mocap`` entry-point group, which is all
mocap needs to find it. Then ``mocap plugins`` lists it, and specs can use::

    motions: {name: sway, params: {seconds: 3, amplitude: 0.3}}
    eval:
      trainer: {name: imitation_eval}
      metrics: [{name: root_drift}]

    task: {name: face_heading, ...}        # turn to face a target heading (any latent space)
    latent: {name: tiny_ae, trainer: {name: distill, ...}}   # a tiny autoencoder latent space

This module only declares (params models, registrations) and imports no torch: the
implementations (``sway.py``, ``heading.py``, ``tiny_ae.py``) are imported by ``lazy`` factories
when a spec builds them, so ``mocap --help`` and ``mocap validate`` stay fast.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from mocap.hooks import hookimpl
from mocap.metric_display import MetricInfo
from mocap.plugins import lazy


class SwayParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    seconds: float = Field(4.0, gt=0, description="clip length")
    fps: float = Field(30.0, gt=0)
    amplitude: float = Field(0.25, ge=0, le=1.0, description="joint swing amplitude, rad")
    frequency: float = Field(0.5, gt=0, description="swings per second")


class FaceHeadingParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    seed: int = Field(0, description="seed of the task's generator (target headings); a factory `seed` overrides it")
    max_turn_deg: float = Field(180.0, gt=0, le=180.0, description="target heading = current heading + U[-max, max] at reset, deg")
    change_steps: int = Field(150, ge=1, description="control steps between new target headings")
    fall_height: float = Field(0.5, gt=0, description="terminate when the root is below this height, m")
    episode_steps: int = Field(300, ge=2, description="time limit, control steps")


class TinyAEParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    latent_dim: int = Field(8, ge=1, le=512, description="latent size Z")
    goal_obs: Literal["rot", "keypoint"] = Field("rot", description="the teacher's imitation-goal layout (the imitator's `obs`)")
    hidden: list[int] = Field(default_factory=lambda: [64, 64], min_length=1, description="encoder and decoder MLP hidden sizes")
    task_bound: float = Field(3.0, gt=0, description="task actions (= z) are clamped to [-bound, bound]")
    task_sigma: float = Field(0.3, gt=0, description="initial exploration sigma of a task policy acting in z")
    z_reg: float = Field(1e-3, ge=0, description="weight of the L2 pull of z towards the N(0, I) prior during distillation")


@hookimpl
def register_motion_sources(register):
    register("sway", lazy("mocap_example.sway:SwaySource"), params=SwayParams, description="procedural swinging of every joint (example plugin)")


@hookimpl
def register_metrics(register):
    register(
        "root_drift",
        lazy("mocap_example.sway:RootDrift"),
        description="max horizontal root error, mm (example plugin)",
        metrics={"root_drift": MetricInfo("root drift", "mm")},
    )


@hookimpl
def register_tasks(register):
    register(
        "face_heading",
        lazy("mocap_example.heading:make_face_heading"),
        params=FaceHeadingParams,
        description="turn to face a target heading; r = cos(heading error); goal obs 2 (example plugin)",
        metrics={
            "heading_error_deg": MetricInfo("heading error", "deg"),
            "facing_rate": MetricInfo("facing rate"),
            "fall_rate": MetricInfo("fall rate"),
        },
    )


@hookimpl
def register_latent_spaces(register):
    register(
        "tiny_ae",
        lazy("mocap_example.tiny_ae:make_tiny_ae"),
        params=TinyAEParams,
        description="tiny deterministic autoencoder: encoder (proprio, goal) -> z, decoder (proprio, z) -> actions, prior N(0, I); "
        "task action = z (example plugin)",
    )
