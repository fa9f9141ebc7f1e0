"""The parameter models of the tracking tasks of :mod:`mocap_tasks.tracking` (which re-exports them):
:class:`VrTrackingParams`, :class:`HmdTrackingParams` and :class:`MotionTrackingParams`."""

from __future__ import annotations

from typing import Literal

from mocap.imitation_reward_params import DEFAULT_SCALES, DEFAULT_WEIGHTS, RewardForm
from mocap_tasks.task_params import FallParams
from pydantic import BaseModel, ConfigDict, Field, model_validator

#: PHC imitation reward (re-exported by :mod:`mocap_tasks.tracking_functions`): (position, rotation, linear velocity, angular velocity)
PHC_WEIGHTS: tuple[float, float, float, float] = DEFAULT_WEIGHTS
PHC_SCALES: tuple[float, float, float, float] = DEFAULT_SCALES
#: Hybrid HMD head reward ([DEFAULT], our choice: App. C.2 gives no formula): (position, rotation, linear velocity, angular velocity)
HMD_WEIGHTS: tuple[float, float, float, float] = (0.4, 0.3, 0.15, 0.15)
HMD_SCALES: tuple[float, float, float, float] = (40.0, 2.0, 0.5, 0.1)


# ---------------------------------------------------------------------------------- params
def _no_fall() -> FallParams:
    return FallParams(early_termination=False)


_FALL_DESCRIPTION = "fall termination, off by default (imitation terminates on the tracking error only; a reference may lie on the ground)"


class _TrackingParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    seed: int = Field(0, description="seed of the task's generator (starts drawn without the env); a factory `seed` overrides it")
    success_threshold: float = Field(0.5, gt=0.0, description="m: an episode fails once the mean error of the success bodies exceeds it ([P] 0.5)")
    fall: FallParams = Field(default_factory=_no_fall, description=_FALL_DESCRIPTION)


class VrTrackingParams(_TrackingParams):
    """Parameters of ``vr_tracking`` (module docstring)."""

    bodies: tuple[str, str, str] | None = Field(
        None,
        description="the tracked headset and controllers: (head, left hand, right hand) body names; None: the "
        "skeleton's (amp: head, left_hand, right_hand; smpl: Head, L_Hand, R_Hand)",
    )
    goal: Literal["rot", "keypoint"] = Field("rot", description="per point: 'rot' = PULSE s^g-vr, 24 dims ([P], [CODE] 72 for 3 points); 'keypoint' = 9 dims")
    sixd: Literal["zhou", "tan_norm"] = Field("zhou", description="6-D rotation convention of the goal")
    reward_form: RewardForm = Field(
        "code",
        description="PHC+ imitation reward errors: [CODE] 'code' = exp(-k mean squared component), the default: what PHC, "
        "PULSE and the committed imitator trained with (r_pos 0.92 at a 5 cm error with k = 100); [P] 'paper' = "
        "exp(-k ||x^ - x||) as printed (mean per-body norm; r_pos 0.007 at 5 cm with the same k)",
    )
    reward_bodies: Literal["all", "tracked"] = Field(
        "all", description="bodies the reward scores: 'all' ([P] the same full-body reward as PHC+) or the 3 'tracked'"
    )
    reward_weights: tuple[float, float, float, float] = Field(PHC_WEIGHTS, description="(position, rotation, velocity, angular velocity) weights ([P] Table 4)")
    reward_scales: tuple[float, float, float, float] = Field(
        PHC_SCALES, description="(position, rotation, velocity, angular velocity) kernel scales k ([P] Table 4)"
    )
    termination: Literal["paper", "code"] = Field(
        "code",
        description="tracking termination: [CODE] 'code' = any of the 3 points farther than 0.25 m after the first "
        "step; [P] defines none for training, 'paper' = its success criterion, mean of the 3 errors > 0.5 m",
    )
    termination_threshold: float | None = Field(None, gt=0.0, description="m; None: 0.25 (code) or 0.5 (paper)")
    episode_steps: int = Field(300, ge=1, description="time limit, control steps ([CODE] 300 = 10 s)")

    @model_validator(mode="after")
    def _weights(self) -> VrTrackingParams:
        if any(w < 0 for w in self.reward_weights) or sum(self.reward_weights) <= 0:
            raise ValueError(f"reward_weights must be >= 0 and not all 0, got {self.reward_weights}")
        return self


class HmdTrackingParams(_TrackingParams):
    """Parameters of ``hmd_tracking`` (module docstring)."""

    head: str | None = Field(None, description="the head body; None: the skeleton's (amp: head, smpl: Head)")
    frames: int = Field(5, ge=1, description="reference frames observed, t+1 .. t+frames ([P] the next and 4 more)")
    reward_weights: tuple[float, float, float, float] = Field(
        HMD_WEIGHTS,
        description="(position, rotation, velocity, angular velocity) weights; [P] gives none (App. C.2); [DEFAULT], our choice",
    )
    reward_scales: tuple[float, float, float, float] = Field(HMD_SCALES, description="kernel scales k of exp(-k |d|^2) ([DEFAULT]: Eq. 10's 40, 2, 0.5, 0.1)")
    termination_threshold: float = Field(1.0, gt=0.0, description="m: head farther than this terminates ([P] 1 m)")
    episode_steps: int = Field(150, ge=1, description="time limit, control steps ([P] 5 s = 150)")

    @model_validator(mode="after")
    def _weights(self) -> HmdTrackingParams:
        if any(w < 0 for w in self.reward_weights) or sum(self.reward_weights) <= 0:
            raise ValueError(f"reward_weights must be >= 0 and not all 0, got {self.reward_weights}")
        return self


class MotionTrackingParams(_TrackingParams):
    """Parameters of ``motion_tracking`` (module docstring)."""

    goal: Literal["rot", "keypoint"] = Field("rot", description="imitation goal: 'rot' = PHC s^g-rot (24 B dims), 'keypoint' = s^g-kp (9 B)")
    sixd: Literal["zhou", "tan_norm"] = Field("zhou", description="6-D rotation convention of the goal")
    reward_form: RewardForm = Field(
        "code",
        description="imitation reward errors: [CODE] 'code' = exp(-k mean squared component), the default: what the "
        "committed imitator trained with (r_pos 0.92 at 5 cm, k = 100); [P] 'paper' = exp(-k ||x^ - x||) as printed "
        "(mean per-body norm; r_pos 0.007 at 5 cm)",
    )
    reward_weights: tuple[float, float, float, float] = Field(
        PHC_WEIGHTS, description="(position, rotation, velocity, angular velocity) weights (PHC/PULSE Table 4)"
    )
    reward_scales: tuple[float, float, float, float] = Field(
        PHC_SCALES, description="(position, rotation, velocity, angular velocity) kernel scales k (PHC/PULSE Table 4)"
    )
    termination: Literal["paper", "code"] = Field(
        "paper",
        description="[P] 'paper' = mean distance of the checked bodies > 0.5 m (Relaxed Early Termination); [CODE] "
        "'code' = any checked body > 0.25 m after the first step",
    )
    termination_threshold: float | None = Field(None, gt=0.0, description="m; None: 0.5 (paper) or 0.25 (code)")
    termination_exclude: tuple[str, ...] | None = Field(None, description="bodies not checked by the termination (None: the skeleton's feet, as PHC)")
    episode_steps: int = Field(300, ge=1, description="time limit, control steps (10 s)")

    @model_validator(mode="after")
    def _weights(self) -> MotionTrackingParams:
        if any(w < 0 for w in self.reward_weights) or sum(self.reward_weights) <= 0:
            raise ValueError(f"reward_weights must be >= 0 and not all 0, got {self.reward_weights}")
        return self
