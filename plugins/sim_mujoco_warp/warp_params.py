"""The params of the ``mujoco_warp`` simulator (:class:`MujocoWarpParams`, re-exported by
:mod:`mocap_sim_mujoco_warp.simulator`, whose docstring documents the backend). Imports neither
MuJoCo, Warp nor torch, so that validating a spec does not.
"""

from __future__ import annotations

from mocap_sim_mujoco.mujoco_params import MujocoParams
from pydantic import Field, model_validator


class MujocoWarpParams(MujocoParams):
    """Parameters of the ``mujoco_warp`` simulator: those of ``mujoco`` (module docstring: ``threads``
    and ``chunk_size`` are ignored) plus the Warp device and the per-world contact buffers."""

    device: str | None = Field(None, description="Warp device: 'cuda', 'cuda:1', 'cpu' (default: cuda if available, else cpu)")
    nconmax: int | None = Field(None, ge=1, description="contacts allocated per world (default: 96, 128 with a target prop, 256 on terrain)")
    njmax: int | None = Field(None, ge=1, description="constraint rows allocated per world (default: 4 * nconmax + number of dofs)")
    cuda_graph: bool = Field(True, description="on CUDA, replay one physics step as a captured CUDA graph")
    state_device: str | None = Field(
        None,
        description="where SimState tensors live (default: the Warp device, zero-copy reads there); 'cpu' for envs whose "
        "motion library stays on the CPU while Warp runs on a GPU",
    )

    @model_validator(mode="after")
    def _supported(self) -> MujocoWarpParams:
        # options the mujoco plugin has that this backend does not implement (e.g. a host-side actuator model)
        if getattr(self, "actuator_model", None) is not None:
            raise ValueError("actuator_model is not supported by the mujoco_warp simulator (use simulator 'mujoco')")
        return self


__all__ = ["MujocoWarpParams"]
