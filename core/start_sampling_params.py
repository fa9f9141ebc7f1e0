"""The params of :mod:`mocap.start_sampling` (re-exported there; its docstring documents them), torch-free
so that the imitators' params import without torch (``mocap validate``)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class StartSamplingParams(BaseModel):
    """Where in a clip episodes start (module docstring)."""

    model_config = ConfigDict(extra="forbid")
    mode: Literal["uniform", "adaptive"] = Field(
        "uniform", description="'uniform' (DeepMimic RSI: uniform in the clip) or 'adaptive' (failure-driven bins, BeyondMimic)"
    )
    bin_s: float = Field(1.0, gt=0.0, le=30.0, description="'adaptive': bin width, s")
    floor: float = Field(0.2, ge=0.0, le=1.0, description="'adaptive': share of the start mass spread uniformly over the bins")
    decay: float = Field(0.99, gt=0.0, le=1.0, description="'adaptive': a clip's bin counts are multiplied by this before each new failure")
    lookback: int = Field(1, ge=0, le=10, description="'adaptive': bins before a failure that share its weight")


__all__ = ["StartSamplingParams"]
