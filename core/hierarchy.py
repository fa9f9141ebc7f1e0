"""Hierarchical control: the ``hierarchy`` plugin registers the ``scratch`` latent space (the no-latent
baseline: the task action is the normalized PD target) and defines its params.

The task env (a task policy acting in the task action space of any latent space, the ``task``
stage's RL env) and ``scratch``'s module live in :mod:`mocap.task_env`, imported only when a spec
builds them: loading this plugin imports no torch. Their names are still reachable here
(``mocap.hierarchy.TaskEnv``).
"""

from __future__ import annotations

import importlib
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from mocap.hooks import hookimpl
from mocap.plugins import lazy


# ---------------------------------------------------------------------------------- scratch
class ScratchParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    range_scale: float = Field(1.0, gt=0, description="a = ±1 reaches this fraction of each joint's half range around its midpoint (PHC absolute map: 1.0)")


@hookimpl
def register_latent_spaces(register):  # type: ignore[no-untyped-def]
    register(
        "scratch",
        lazy("mocap.task_env:make_scratch"),
        params=ScratchParams,
        description="no latent space: task actions are normalized PD targets (baseline)",
    )


#: names defined in :mod:`mocap.task_env`, reachable from here too (imported on first use)
_MOVED = ("STATE_FORMAT", "ScratchLatent", "TaskEnv", "make_scratch", "make_task_env")


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        return getattr(importlib.import_module("mocap.task_env"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ScratchParams"]
