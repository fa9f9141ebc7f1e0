"""Entry point of the downstream-task plugin (group ``mocap``: ``tasks = "mocap_tasks.plugin"``)."""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap_tasks.reach import ReachParams, make_reach
from mocap_tasks.speed import SpeedParams, make_speed
from mocap_tasks.strike import StrikeParams, make_strike


@hookimpl
def register_tasks(register: Any) -> None:
    register(
        "speed",
        make_speed,
        params=SpeedParams,
        description="move the root at a target speed U[0, 5] m/s along a target direction; "
        "r = exp(-0.25 ((v* - v.d)^2 + 0.1 (v.d_perp)^2)); goal obs 3",
    )
    register(
        "reach",
        make_reach,
        params=ReachParams,
        description="bring the right hand to a target point in a 2-m box; r = exp(-5 ||p_hand - c||^2) (code: 4); goal obs 3",
    )
    register(
        "strike",
        make_strike,
        params=StrikeParams,
        description="knock a standing box over with the right hand (simulator target prop); paper r = 1 - up.u_t, "
        "code 0.6 tilt + 0.4 approach, 1 when toppled; goal obs 15",
    )
