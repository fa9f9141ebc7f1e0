"""Downstream tasks of PULSE (Luo et al., ICLR 2024, Sec. 4.3 / App. C, following ASE): ``speed``,
``reach`` and ``strike``, for any skeleton and any action space (a task never knows which latent
space drives the humanoid).

Modules:

* :mod:`mocap_tasks.common`: fall termination, body lookup, seeded sampling, metric sums;
* :mod:`mocap_tasks.speed`: move at a target speed along a target direction;
* :mod:`mocap_tasks.reach`: bring the right hand to a target point;
* :mod:`mocap_tasks.strike`: knock a standing box over with the hand (the simulator's target prop);
* :mod:`mocap_tasks.terrain`: follow a trajectory over a height-field terrain (PULSE / PACER);
* :mod:`mocap_tasks.point_goal`: walk to a 2-D point (hybrid-RVQ navigation);
* :mod:`mocap_tasks.inbetween`: reach library keyframes at irregular intervals (hybrid-RVQ in-betweening);
* :mod:`mocap_tasks.generation`: roll out a latent space's prior (no reward; fall rate, diversity);
* :mod:`mocap_tasks.tracking`: follow a library clip through the latent space: ``vr_tracking`` (PULSE,
  head + hands), ``hmd_tracking`` (hybrid-RVQ, head only), ``motion_tracking`` (full body);
* :mod:`mocap_tasks.task_params`, :mod:`mocap_tasks.tracking_params`: every task's params (torch-free);
* :mod:`mocap_tasks.plugin`: the entry point registering the tasks.

Every task follows :class:`mocap.interfaces.Task`: ``reset(env_ids, state)`` samples goals with the
task's seeded ``torch.Generator``; ``observe(state)`` is the goal in the root's heading frame;
``reward(state, actions)`` is bounded by ``max_reward``; ``terminated(state)`` is a fall (plus, for
strike, a forbidden contact with the box), never a time limit; ``step(state)`` is the per-control-step
hook (goal changes, counters); ``metrics()`` returns and clears the task metrics documented in each
module. Each parameter that differs between the paper ([P]) and the official code ([CODE]) says so.
"""

import importlib
from typing import Any

from mocap_tasks.task_params import ReachParams, SpeedParams, StrikeParams

#: the tasks' classes and factories, imported on first use (importing this package imports no torch)
_LAZY = {
    "ReachTask": "mocap_tasks.reach",
    "make_reach": "mocap_tasks.reach",
    "SpeedTask": "mocap_tasks.speed",
    "make_speed": "mocap_tasks.speed",
    "StrikeTask": "mocap_tasks.strike",
    "make_strike": "mocap_tasks.strike",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "ReachParams",
    "ReachTask",
    "SpeedParams",
    "SpeedTask",
    "StrikeParams",
    "StrikeTask",
    "make_reach",
    "make_speed",
    "make_strike",
]
