"""Entry point of the downstream-task plugin (group ``mocap``: ``tasks = "mocap_tasks.plugin"``)."""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap.generation import GENERATION_METRICS
from mocap.metric_display import MetricInfo
from mocap.plugins import lazy
from mocap_tasks.task_params import (
    GenerationTaskParams,
    InbetweenParams,
    PointGoalParams,
    ReachParams,
    SpeedParams,
    StrikeParams,
    TerrainTaskParams,
)
from mocap_tasks.tracking_params import HmdTrackingParams, MotionTrackingParams, VrTrackingParams


#: how reports show the metrics the tasks report (each task's module docstring defines them)
_SHOWN: dict[str, MetricInfo] = {
    "reward": MetricInfo("mean reward"),
    "steps": MetricInfo("control steps"),
    "episodes": MetricInfo("episodes"),
    "speed_error": MetricInfo("speed error", "m/s"),
    "tangent_speed": MetricInfo("sideways speed", "m/s"),
    "velocity_error": MetricInfo("velocity error", "m/s"),
    "heading_error": MetricInfo("heading error", "rad"),
    "distance": MetricInfo("distance to target", "m"),
    "final_distance": MetricInfo("final distance to target", "m"),
    "closest_distance": MetricInfo("closest distance to target", "m"),
    "success_rate": MetricInfo("success rate"),
    "time_to_reach": MetricInfo("time to reach", "s"),
    "goals": MetricInfo("goals"),
    "hit_rate": MetricInfo("hit rate"),
    "time_to_hit": MetricInfo("time to hit", "s"),
    "illegal_contact_rate": MetricInfo("illegal contact rate"),
    "up_dot": MetricInfo("box up-axis dot"),
    "success": MetricInfo("success rate"),
    "mpjpe_g": MetricInfo("MPJPE-g", "mm"),
    "mpjpe_l": MetricInfo("MPJPE-l", "mm"),
    "tracked_error": MetricInfo("tracked-point error", "mm"),
    "traj_error": MetricInfo("trajectory error", "m"),
    "episode_traj_error": MetricInfo("episode trajectory error", "m"),
    "energy": MetricInfo("energy penalty"),
    "far_rate": MetricInfo("off-trajectory rate"),
    "keyframe_gmpjpe_mm": MetricInfo("keyframe MPJPE-g", "mm"),
    "keyframe_mpjpe_mm": MetricInfo("keyframe MPJPE-l", "mm"),
    "keyframe_root_error": MetricInfo("keyframe root error", "m"),
    "keyframe_success_rate": MetricInfo("keyframe success rate"),
    "full_gmpjpe_mm": MetricInfo("full MPJPE-g", "mm"),
    "down_at_end": MetricInfo("down at the end"),
    "diversity_episodes": MetricInfo("diversity episodes"),
    **GENERATION_METRICS,  # fall_rate, time_to_fall_s, survival_s, diversity_m: the same quantities as core's protocol
}
_COMMON = ("reward", "steps")
_GOALS = ("distance", "final_distance", "closest_distance", "success_rate", "time_to_reach", "goals")
_REPORTED: dict[str, tuple[str, ...]] = {
    "speed": ("speed_error", "tangent_speed", "velocity_error", "heading_error"),
    "reach": _GOALS,
    "strike": ("hit_rate", "time_to_hit", "illegal_contact_rate", "up_dot", "episodes"),
    "vr_tracking": ("success", "mpjpe_g", "mpjpe_l", "tracked_error", "episodes"),
    "hmd_tracking": ("success", "mpjpe_g", "mpjpe_l", "tracked_error", "episodes"),
    "motion_tracking": ("success", "mpjpe_g", "mpjpe_l", "episodes"),
    "terrain": ("traj_error", "episode_traj_error", "energy", "fall_rate", "far_rate", "episodes"),
    "point_goal": _GOALS,
    "inbetween": (
        "keyframe_gmpjpe_mm",
        "keyframe_mpjpe_mm",
        "keyframe_root_error",
        "keyframe_success_rate",
        "full_gmpjpe_mm",
        "success_rate",
        "episodes",
    ),
    "generation": ("fall_rate", "time_to_fall_s", "survival_s", "down_at_end", "diversity_m", "diversity_episodes", "episodes"),
}


def _metrics(task: str) -> dict[str, MetricInfo]:
    """The display declarations of the metrics ``task`` reports."""
    return {k: _SHOWN[k] for k in (*_REPORTED[task], *_COMMON)}


@hookimpl
def register_tasks(register: Any) -> None:
    register(
        "speed",
        lazy("mocap_tasks.speed:make_speed"),
        params=SpeedParams,
        description="move the root at a target speed U[0, 5] m/s along a target direction; r = exp(-0.25 ((v* - v.d)^2 + 0.1 (v.d_perp)^2)); goal obs 3",
        metrics=_metrics("speed"),
    )
    register(
        "reach",
        lazy("mocap_tasks.reach:make_reach"),
        params=ReachParams,
        description="bring the right hand to a target point in a 2-m box; r = exp(-5 ||p_hand - c||^2) (code: 4); goal obs 3",
        metrics=_metrics("reach"),
    )
    register(
        "strike",
        lazy("mocap_tasks.strike:make_strike"),
        params=StrikeParams,
        description="knock a standing box over with the right hand (simulator target prop); paper r = 1 - up.u_t, "
        "code 0.6 tilt + 0.4 approach, 1 when toppled; goal obs 15",
        metrics=_metrics("strike"),
    )
    # tasks that follow a reference motion of the library (the env passes motions=; mocap_tasks.tracking)
    register(
        "vr_tracking",
        lazy("mocap_tasks.tracking:make_vr_tracking"),
        params=VrTrackingParams,
        description="PULSE VR 3-point tracking: follow the reference head and hands (goal s^g-vr, 72), full-body "
        "PHC+ imitation reward; metrics success (3 points), mpjpe_g",
        metrics=_metrics("vr_tracking"),
    )
    register(
        "hmd_tracking",
        lazy("mocap_tasks.tracking:make_hmd_tracking"),
        params=HmdTrackingParams,
        description="Hybrid HMD tracking: follow the reference head (goal 5 x 13 head differences), head reward, "
        "terminate at 1 m; metrics success (head), mpjpe_g",
        metrics=_metrics("hmd_tracking"),
    )
    register(
        "motion_tracking",
        lazy("mocap_tasks.tracking:make_motion_tracking"),
        params=MotionTrackingParams,
        description="full-body imitation through the latent space: the imitator's goal, PHC imitation reward; metrics success, mpjpe_g",
        metrics=_metrics("motion_tracking"),
    )
    # terrain, point goal, in-betweening, generation (mocap_tasks.terrain / point_goal / inbetween / generation)
    register(
        "terrain",
        lazy("mocap_tasks.terrain:make_terrain"),
        params=TerrainTaskParams,
        description="PULSE/PACER: follow a 2-D trajectory over a height-field terrain (stairs, slopes, rough, obstacles); "
        "r = exp(-2 ||p - tau||) (code: squared) + energy; goal obs 20 trajectory + 32 x 32 height map",
        metrics=_metrics("terrain"),
    )
    register(
        "point_goal",
        lazy("mocap_tasks.point_goal:make_point_goal"),
        params=PointGoalParams,
        description="Hybrid-RVQ point-goal navigation: reach a 2-D point within 10 m, new every 4 s; "
        "r = 0.7 exp(-0.5 d^2) + 0.3 exp(-max(0, 1 - v.d_hat)^2), 1 on arrival; goal obs 2",
        metrics=_metrics("point_goal"),
    )
    register(
        "inbetween",
        lazy("mocap_tasks.inbetween:make_inbetween"),
        params=InbetweenParams,
        description="Hybrid-RVQ motion in-betweening: reach library keyframes at irregular intervals in a 4-s window; "
        "r = 0.1 r_root + 0.65 r_q + 0.1 r_alpha + 0.15 r_ee; goal obs 2 J 7 (+ time to arrival)",
        metrics=_metrics("inbetween"),
    )
    register(
        "generation",
        lazy("mocap_tasks.generation:make_generation"),
        params=GenerationTaskParams,
        description="unconditional generation: the latent prior is rolled out (task action ignored, reward 0; not with scratch); metrics fall rate, diversity",
        metrics=_metrics("generation"),
    )
