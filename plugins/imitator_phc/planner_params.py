"""Parameters of the get-up planner (:mod:`mocap_phc.recovery_planner`), in a module that imports no
torch, so that the pmcp trainer's params (``recovery.distill.planner``) stay light to import."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class GetUpPlannerParams(BaseModel):
    """The get-up planner (module docstring)."""

    model_config = ConfigDict(extra="forbid")
    clips: list[str] = Field(default_factory=lambda: ["getup*"], min_length=1, description="get-up clips, as fnmatch patterns of clip names")
    fallen_ratio: float = Field(0.5, gt=0, lt=1, description="fallen: root height below this x the standing root height")
    up_ratio: float = Field(
        0.8, gt=0, le=1, description="up: root height at least this x the standing root height; a get-up ends when its clip has ended and the humanoid is up"
    )
    fallen_steps: int = Field(
        10, ge=1, description="control steps a trial must stay fallen before a new get-up starts (a trial that starts down starts at once)"
    )
    approach_clip: str | None = Field("walk", description="looping clip walked toward the reference after a get-up (None: no approach)")
    approach_distance: float = Field(0.4, gt=0, description="the approach ends when the root is this close to the reference root, m")
    approach_start_rate: float = Field(0.3, gt=0, le=1, description="the approach clip starts played at this rate (1: at its own speed)")
    approach_ramp_s: float = Field(1.0, ge=0, description="seconds over which the approach's rate rises to 1 (0: no ramp)")
    max_turn_deg: float = Field(
        30.0, gt=0, le=180, description="at each re-aiming the clip faces the humanoid's heading turned toward the goal by at most this, deg"
    )
    replan_steps: int = Field(15, ge=1, description="control steps between two re-aimings of the approach clip")


__all__ = ["GetUpPlannerParams"]
