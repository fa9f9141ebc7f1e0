"""Parameters of the get-up planner (:mod:`mocap_phc.recovery_planner`), in a module that imports no
torch, so that the pmcp trainer's params (``recovery.distill.planner``) stay light to import."""

from __future__ import annotations

from typing import Literal

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
    getup_clock: Literal["time", "pose"] = Field(
        "time",
        description="how a get-up clip's time runs: 'time', one control step per step from its first frame; 'pose', paced "
        "by the humanoid: each step the clip time near the clock whose pose (joint angles, root height, root up axis) is "
        "closest to the humanoid's is found, and the clock runs faster (up to pose_max_rate) when the humanoid is ahead "
        "of it, slower when it leads that pose by more than pose_lead_s. imitator_amp_v14 over seeds 0-9: recovery 56.9% "
        "with 'time', 59.8% with 'pose' (paired +3.0 +- 1.9 points; bench/results/planner_pose_clock.md)",
    )
    pose_back_s: float = Field(0.5, ge=0, description="with getup_clock 'pose': how far back of the clock the pose search goes, s")
    pose_ahead_s: float = Field(0.25, ge=0, description="with getup_clock 'pose': how far ahead of the clock the pose search goes, s")
    pose_lead_s: float | None = Field(
        None,
        ge=0,
        description="with getup_clock 'pose': the clock slows when it leads the matched pose by more than this, s "
        "(None: it never slows; slowing measured worse)",
    )
    pose_tau_s: float = Field(
        0.3, gt=0, description="with getup_clock 'pose': the clock's rate changes by 1 per this many seconds of lead (stopped at pose_lead_s + pose_tau_s), s"
    )
    pose_max_rate: float = Field(1.5, ge=1, description="with getup_clock 'pose': the clock's highest rate, when the humanoid is ahead of it")


__all__ = ["GetUpPlannerParams"]
