"""The optional parts of :class:`~mocap_sim_mujoco.simulator.MujocoSimulator`'s API (its module
docstring: "Props"): the :class:`SimulatorExtras` mixin with the physics-state access (``qpos``,
``get_physics_state``, ``write_mjdata``, ...), the target and marker props and the terrain queries,
and the :class:`TargetState` it returns."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable

import mujoco
import numpy as np
import torch
from torch import Tensor

from mocap.rotations import quat_apply, quat_normalize
from mocap.state import TargetState
from mocap_sim_mujoco.readout import _FULL
from mocap_sim_mujoco.terrain import height_map

if TYPE_CHECKING:  # pragma: no cover
    from mocap.state import SimState
    from mocap_sim_mujoco.mujoco_params import MujocoParams
    from mocap_sim_mujoco.terrain import Terrain

__all__ = ["SimulatorExtras"]


class SimulatorExtras:
    """Mixin of :class:`~mocap_sim_mujoco.simulator.MujocoSimulator`: state access, props and terrain."""

    # set or defined by MujocoSimulator (declared here for the type checker only)
    params: MujocoParams
    device: torch.device
    dtype: torch.dtype
    model: mujoco.MjModel
    terrain: Terrain | None
    _qp: int
    _qv: int
    _target_qpos: int
    _target_qvel: int
    _S: np.ndarray
    _reset_S: np.ndarray
    _ground_contact: np.ndarray
    _markers: np.ndarray
    _cached: SimState | None
    _ids: Callable[[Tensor | np.ndarray | list[int]], np.ndarray]
    _after_set: Callable[[np.ndarray], None]
    _tensor: Callable[[np.ndarray], Tensor]

    # --------------------------------------------------------------------- extras
    @property
    def ground_contact(self) -> Tensor:
        """(N, B) bool: like ``SimState.body_contact`` but for the ground only (not props)."""
        return torch.from_numpy(self._ground_contact.copy()).to(self.device)

    @property
    def qpos(self) -> np.ndarray:
        """(N, nq) current MuJoCo ``qpos`` of every env (a copy)."""
        return self._S[:, self._qp : self._qp + self.model.nq].copy()

    @property
    def qvel(self) -> np.ndarray:
        """(N, nv) current MuJoCo ``qvel`` of every env (a copy)."""
        return self._S[:, self._qv : self._qv + self.model.nv].copy()

    def get_physics_state(self) -> np.ndarray:
        """(N, nstate) copy of the full MuJoCo states (``mjSTATE_FULLPHYSICS``)."""
        return self._S.copy()

    def set_physics_state(self, env_ids: Tensor, states: np.ndarray, *, as_reset: bool = True) -> None:
        """Write full MuJoCo states (K, nstate) (from :meth:`get_physics_state`) into envs ``env_ids``.

        With ``as_reset`` (default) they also become the states an instability falls back to;
        ``as_reset=False`` changes only the current state (e.g. to inject a perturbation)."""
        ids = self._ids(env_ids)
        self._S[ids] = states
        self._S[ids, 0] = 0.0
        if as_reset:
            self._reset_S[ids] = states
        self._after_set(ids)

    def write_mjdata(self, env_id: int, data: mujoco.MjData) -> mujoco.MjData:
        """Put env ``env_id`` (state and markers) into ``data`` of :attr:`model` and run ``mj_forward``
        (for rendering or inspection)."""
        mujoco.mj_setState(self.model, data, self._S[env_id], _FULL)
        if self.params.markers:
            data.mocap_pos[:] = self._markers[env_id]
        mujoco.mj_forward(self.model, data)
        return data

    # ------------------------------------------------------------------------- props
    @property
    def has_target(self) -> bool:
        """True when the simulator was built with a target prop (``params.target``)."""
        return self.params.target is not None

    def _need_target(self) -> None:
        if self.params.target is None:
            raise RuntimeError("this simulator has no target prop (set params.target)")

    def set_target(self, env_ids: Tensor, pos: Tensor, rot: Tensor | None = None) -> None:
        """Place the target box of envs ``env_ids`` (K,) at ``pos`` (K, 3) (box centre), ``rot`` (K, 4)
        (default upright), at rest. Also becomes part of those envs' instability-reset state."""
        self._need_target()
        ids = self._ids(env_ids)
        K = len(ids)
        if K == 0:
            return
        q = np.zeros((K, 4))
        q[:, 0] = 1.0
        if rot is not None:
            q = quat_normalize(rot.detach().to("cpu", torch.float64)).numpy().reshape(K, 4)
        a, v = self._target_qpos, self._target_qvel
        for buf in (self._S, self._reset_S):
            rows = buf[ids]
            rows[:, a : a + 3] = pos.detach().to("cpu", torch.float64).numpy().reshape(K, 3)
            rows[:, a + 3 : a + 7] = q
            rows[:, v : v + 6] = 0.0
            buf[ids] = rows
        self._cached = None

    def target_state(self) -> TargetState:
        """Pose, velocities (world) and fallen flag of every env's target box."""
        self._need_target()
        target = self.params.target
        assert target is not None  # _need_target() raised otherwise
        a, v = self._target_qpos, self._target_qvel
        S = torch.from_numpy(self._S)
        pos, rot = S[:, a : a + 3], quat_normalize(S[:, a + 3 : a + 7])
        lin, ang = S[:, v : v + 3], quat_apply(rot, S[:, v + 3 : v + 6])  # free-joint angular velocity is local
        up_z = 1.0 - 2.0 * (rot[:, 1] ** 2 + rot[:, 2] ** 2)  # z component of the box's z axis
        fallen = up_z < math.cos(math.radians(target.fallen_angle))
        pos, rot, lin, ang = (t.to(self.device, self.dtype) for t in (pos, rot, lin, ang))
        return TargetState(pos, rot, lin, ang, fallen=fallen.to(self.device))

    def set_markers(self, env_ids: Tensor, positions: Tensor) -> None:
        """Marker positions (K, M, 3) of envs ``env_ids`` (visual only)."""
        ids = self._ids(env_ids)
        M = self.params.markers
        self._markers[ids] = positions.detach().to("cpu", torch.float64).numpy().reshape(len(ids), M, 3)

    @property
    def markers(self) -> Tensor:
        """(N, M, 3) marker positions."""
        return self._tensor(self._markers)

    # ------------------------------------------------------------------------ terrain
    def height_at(self, xy: Tensor) -> Tensor:
        """Ground height (...) at world points ``xy`` (..., 2) (0 on the plane)."""
        if self.terrain is None:
            return torch.zeros(xy.shape[:-1], dtype=xy.dtype if xy.is_floating_point() else self.dtype, device=xy.device)
        return self.terrain.height_at(xy)

    def height_map(self, center: Tensor, heading: Tensor, shape: tuple[int, int] = (11, 11), spacing: float = 0.1) -> Tensor:
        """(N, H, W) ground heights on a grid around ``center`` (N, 2) turned by ``heading`` (N,)
        (:meth:`mocap_sim_mujoco.terrain.Terrain.height_map`)."""
        return height_map(self.height_at, center, heading, shape, spacing)
