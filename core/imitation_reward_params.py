"""The torch-free constants and types of :mod:`mocap.imitation_rewards` (re-exported there), which
params classes use as defaults and field types (they import without torch: ``mocap validate``)."""

from __future__ import annotations

from typing import Literal

RewardForm = Literal["paper", "code"]
EnergyForm = Literal["paper", "code"]

#: names of the four imitation terms, in the order of weights and scales
TERMS: tuple[str, ...] = ("pos", "rot", "vel", "ang_vel")
DEFAULT_WEIGHTS: tuple[float, float, float, float] = (0.5, 0.3, 0.1, 0.1)
DEFAULT_SCALES: tuple[float, float, float, float] = (100.0, 10.0, 0.1, 0.1)
#: steps at the start of an episode with no energy penalty in the code form (``progress_buf <= 3``)
CODE_ENERGY_WARMUP = 3


__all__ = ["CODE_ENERGY_WARMUP", "DEFAULT_SCALES", "DEFAULT_WEIGHTS", "TERMS", "EnergyForm", "RewardForm"]
