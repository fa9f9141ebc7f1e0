"""Entry point of the ``mujoco_warp`` simulator plugin (group ``mocap``).

Registers without Warp installed: the factory imports ``warp`` / ``mujoco_warp`` only when a spec
builds the simulator (see :func:`mocap_sim_mujoco_warp.simulator.import_warp`).
"""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap.plugins import lazy
from mocap_sim_mujoco_warp.warp_params import MujocoWarpParams


@hookimpl
def register_simulators(register: Any) -> None:
    register(
        "mujoco_warp",
        lazy("mocap_sim_mujoco_warp.simulator:make_simulator"),
        params=MujocoWarpParams,
        description="MuJoCo Warp: the mujoco simulator's MJCF stepped as nworld = N worlds on a GPU (or Warp's CPU "
        "device), state as torch tensors; needs pip install 'mocap[warp]'",
    )
