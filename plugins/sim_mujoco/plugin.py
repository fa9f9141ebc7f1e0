"""Entry point of the ``mujoco`` simulator plugin (group ``mocap``)."""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap.plugins import lazy
from mocap_sim_mujoco.mujoco_params import MujocoParams


@hookimpl
def register_simulators(register: Any) -> None:
    register(
        "mujoco",
        lazy("mocap_sim_mujoco.simulator:make_simulator"),
        params=MujocoParams,
        description="MuJoCo: N humanoids stepped by mujoco.rollout on all cores, PD position actuators, 1/120 s x 4 substeps, optional terrain/target/markers",
    )


from mocap_sim_mujoco.commands import register_commands  # noqa: E402,F401  (adds `mocap render`)
