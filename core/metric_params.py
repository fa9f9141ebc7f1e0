"""The torch-free part of :mod:`mocap.metrics` (re-exported there): the protocol id, the built-in
metrics' units, descriptions and display names, and the params of ``success`` / ``success_linf``.
The evaluation plugin registers the metrics from these without importing the metric code.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from mocap.metric_display import MetricInfo

PROTOCOL = "mocap-imitation-v1 (success: mean body error <= 0.5 m at every frame; mm; per-frame units at the stated fps)"

#: name -> (unit, description) of every built-in metric (the functions: :data:`mocap.metrics.BUILTIN_METRICS`)
BUILTIN_INFO: dict[str, tuple[str, str]] = {
    "mpjpe_g": ("mm", "global mean per-body position error"),
    "mpjpe_l": ("mm", "root-relative mean per-body position error"),
    "pa_mpjpe": ("mm", "per-body error after similarity Procrustes alignment"),
    "vel_err": ("mm/frame", "body velocity error per frame at the evaluation fps"),
    "acc_err": ("mm/frame^2", "body acceleration error per frame^2 at the evaluation fps"),
    "rot_err": ("deg", "mean geodesic angle between simulated and reference body orientations"),
}


#: how reports show each built-in metric (declared with its registration)
BUILTIN_DISPLAY: dict[str, MetricInfo] = {
    "mpjpe_g": MetricInfo("MPJPE-g", "mm"),
    "mpjpe_l": MetricInfo("MPJPE-l", "mm"),
    "pa_mpjpe": MetricInfo("PA-MPJPE", "mm"),
    "vel_err": MetricInfo("velocity error", "mm/frame"),
    "acc_err": MetricInfo("acceleration error", "mm/frame²"),
    "rot_err": MetricInfo("rotation error", "°"),
    "success": MetricInfo("success rate"),
    "success_linf": MetricInfo("success rate (max body)"),
}


class SuccessParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    threshold: float = Field(0.5, gt=0, description="m; PHC/PULSE evaluation uses 0.5 (PHC training terminates at 0.25)")
    grace_frames: int = Field(0, ge=0, description="frames at the start that are not checked")


__all__ = ["BUILTIN_DISPLAY", "BUILTIN_INFO", "PROTOCOL", "SuccessParams"]
