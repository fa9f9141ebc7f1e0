"""Saving and restoring a simulator's state inside an env's resumable ``state_dict`` (the imitation,
task, distillation and VMP tracking envs all use these two functions).

A simulator with a full physics state (:meth:`mocap.interfaces.Simulator.get_physics_state`, the
MuJoCo simulator's ``mjSTATE_FULLPHYSICS``) is saved under ``"physics"`` and restored bit-exactly;
any other simulator is saved as the :class:`~mocap.state.HumanoidState` fields it can be reset to
(``"sim_state"``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from mocap.interfaces import Simulator
from mocap.state import HUMANOID_FIELDS, HumanoidState


def save_sim_state(sim: Simulator) -> dict[str, Any]:
    """``{"physics": (N, S) float64}`` or ``{"sim_state": {field: tensor}}`` (module docstring)."""
    physics = sim.get_physics_state()
    if physics is not None:
        return {"physics": torch.from_numpy(np.array(physics, dtype=np.float64, copy=True))}
    s = sim.state
    return {"sim_state": {k: getattr(s, k).cpu().clone() for k in HUMANOID_FIELDS}}


def load_sim_state(sim: Simulator, env_ids: Tensor, state: dict[str, Any], device: Any = "cpu") -> None:
    """Restore what :func:`save_sim_state` wrote (into an env ``state`` dict) to envs ``env_ids``.

    Raises ValueError when ``state`` holds neither form this simulator can use (a full physics state
    saved by another simulator, and no kinematic state)."""
    if "physics" in state and sim.get_physics_state() is not None:
        phys = state["physics"]
        phys = phys.detach().cpu().numpy() if isinstance(phys, Tensor) else np.asarray(phys)
        sim.set_physics_state(env_ids, np.array(phys, dtype=np.float64, copy=True))
    elif "sim_state" in state:
        sim.reset(env_ids, HumanoidState(**{k: v.to(device) for k, v in state["sim_state"].items()}))
    else:
        raise ValueError("the saved env state has no simulator state usable by this simulator")


__all__ = ["load_sim_state", "save_sim_state"]
