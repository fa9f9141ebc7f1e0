"""The params of :mod:`mocap.fail_states` (re-exported there) and :mod:`mocap.getup_starts`, torch-free so that the params of the
PHC imitator and of ``distill`` import without torch (``mocap validate``)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class FailStateParams(BaseModel):
    """Episode starts away from the reference (PHC Sec. 3.2 "Fail-state Recovery"; official code
    phc/env/tasks/humanoid_im_getup.py), for recovery training."""

    model_config = ConfigDict(extra="forbid")
    fall_init_prob: float = Field(0.0, ge=0.0, le=1.0, description="share of resets from a fallen state ([C] 0.3; 1.0 in the code's first get-up phase)")
    far_init_prob: float = Field(0.0, ge=0.0, le=1.0, description="share of the other resets moved away from the reference ([P] far states)")
    far_init_range: tuple[float, float] = Field((2.0, 5.0), description="distance of a far start from the reference root, m ([P] 2-5)")
    recovery_episode_prob: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="chance that a terminated episode becomes a 'bonus' recovery episode (it goes on, with a recovery "
        "window, instead of being reset) ([C] recoveryEpisodeProb 0.5 in phase 2 and for the composer)",
    )
    recovery_steps: int = Field(
        90, ge=0, description="control steps after a fallen or far start during which tracking failures do not terminate ([C] 90 = 3 s)"
    )
    pool_size: int | None = Field(None, ge=1, description="fallen states generated at start (None: one per env)")
    settle_steps: int = Field(75, ge=1, description="control steps each fallen state is simulated for ([C] 150 physics steps at 60 Hz = 2.5 s)")
    action_range: float = Field(0.5, gt=0.0, le=1.0, description="held random normalized PD action in U(-r, r) while falling ([C] 0.5)")
    drop_height: float = Field(1.2, gt=0.0, description="root height the humanoid is dropped from with a random orientation, m")


class GetUpStartParams(BaseModel):
    """Fallen starts with a get-up clip as the reference (:mod:`mocap.getup_starts`)."""

    model_config = ConfigDict(extra="forbid")
    clips: list[str] = Field(default_factory=lambda: ["getup*"], min_length=1, description="the get-up clips, as fnmatch patterns of clip names")
    hold_s: float = Field(2.0, ge=0.0, description="seconds the get-up's last frame is held at rest before the episode is truncated")


def check_getup_starts(getup: GetUpStartParams | None, fail: FailStateParams | None) -> None:
    """``getup_starts`` needs fallen starts to act on: a clear error otherwise."""
    if getup is not None and (fail is None or fail.fall_init_prob <= 0):
        raise ValueError("getup_starts needs fallen starts: set fail_states.fall_init_prob > 0")


__all__ = ["FailStateParams", "GetUpStartParams", "check_getup_starts"]
