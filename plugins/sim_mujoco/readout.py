"""State extraction of :class:`~mocap_sim_mujoco.simulator.MujocoSimulator` (its module docstring:
"State extraction", "Warm start", "Instability"): the layout constants of the rollout state and control
arrays and the :class:`StateReadout` mixin, which turns the rollout outputs into contacts, body frames,
the solver warm start, the instability flags and the :class:`~mocap.state.SimState` tensors."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np
import numpy.typing as npt
import torch
from torch import Tensor

from mocap.state import SimState

if TYPE_CHECKING:  # pragma: no cover
    from mujoco import rollout as mj_rollout

    from mocap.skeleton import Skeleton
    from mocap_sim_mujoco.mujoco_params import MujocoParams

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_XFRC = int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
_KIN_FIELDS = 13  # framepos 3, framequat 4, framelinvel 3, frameangvel 3


class StateReadout:
    """Mixin of :class:`~mocap_sim_mujoco.simulator.MujocoSimulator`: the per-step state extraction."""

    # set by MujocoSimulator.__init__ (declared here for the type checker only)
    params: MujocoParams
    skeleton: Skeleton
    num_envs: int
    device: torch.device
    dtype: torch.dtype
    _np_dtype: npt.DTypeLike
    model: mujoco.MjModel
    nstate: int
    _qv: int
    _dof_qpos: np.ndarray
    _dof_qvel: np.ndarray
    _n_contact: int
    _num_partners: int
    _ground_partners: list[int]
    _pool: mj_rollout.Rollout  # None after close()
    _kin_model: mujoco.MjModel
    _kin_models: list[mujoco.MjModel]
    _kin_datas: list[mujoco.MjData]
    _kin_chunk: int
    _S: np.ndarray
    _warm: np.ndarray
    _ctrl1: np.ndarray
    _traj: np.ndarray
    _sens: np.ndarray
    _kin_state: np.ndarray
    _kin_sens: np.ndarray
    _contact_force: np.ndarray
    _body_contact: np.ndarray
    _ground_contact: np.ndarray
    _dof_force: np.ndarray
    _unstable: np.ndarray

    def _update_warmstart(self, bad: np.ndarray) -> None:
        """Next step's solver warm start: the last substep's acceleration, ``(qvel_end - qvel_before) / h``
        (what ``mj_step`` would carry over in ``qacc_warmstart``; ``rollout`` does not return it)."""
        qv = slice(self._qv, self._qv + self.model.nv)
        before = self._traj[:, -2, qv] if self.params.substeps > 1 else self._S[:, qv]
        np.subtract(self._traj[:, -1, qv], before, out=self._warm)
        self._warm *= 1.0 / self.params.timestep
        if bad.any():
            self._warm[bad] = 0.0

    def _detect_unstable(self) -> np.ndarray:
        """(N,) bool: the new state has a NaN/inf or an entry above ``max_qvel`` in magnitude, or
        changed by more than ``max_qacc * dt`` over the control step (a mean ``|qacc|`` above
        ``max_qacc``).

        Whole state rows (qpos, qvel; time is kept at 0) are checked with max/min reductions:
        qpos entries (m, rad) are far below ``max_qvel`` in a sane state and their change far below
        ``max_qacc * dt``. NaN fails every comparison, so it is caught too. A blow-up grows by
        orders of magnitude per substep, so the end of the step is where it shows."""
        p = self.params
        new = self._traj[:, -1]
        lim = p.max_qacc * p.timestep * p.substeps
        with np.errstate(invalid="ignore", over="ignore"):
            ok = (new.max(axis=1) <= p.max_qvel) & (new.min(axis=1) >= -p.max_qvel)
            d = new - self._S
            ok &= (d.max(axis=1) <= lim) & (d.min(axis=1) >= -lim)
        return ~ok

    def _read_contacts(self) -> None:
        N, B, D = self.num_envs, self.skeleton.num_bodies, self.skeleton.num_dofs
        # mean over the substeps first: forces average to impulse / dt, and a mean contact count
        # above zero means a contact in some substep
        c = self._sens[:, :, : self._n_contact].mean(axis=1).reshape(N, self._num_partners, B, 4)
        found = c[..., 0] > 0
        if self._num_partners == 1:
            self._body_contact[:] = found[:, 0]
            self._ground_contact[:] = found[:, 0]
            self._contact_force[:] = c[:, 0, :, 1:4]
        else:
            self._body_contact[:] = found.any(axis=1)
            self._ground_contact[:] = found[:, self._ground_partners].any(axis=1)
            self._contact_force[:] = c[..., 1:4].sum(axis=1)
        self._dof_force[:] = self._sens[:, -1, self._n_contact : self._n_contact + D]

    def _kinematics(self, ids: np.ndarray | None = None) -> None:
        """Body frames and velocities of the current states (all envs, or rows ``ids``)."""
        if ids is None:
            self._pool.rollout(
                self._kin_models,
                self._kin_datas,
                self._S,
                self._ctrl1,
                control_spec=_CTRL,
                skip_checks=True,
                nstep=1,
                state=self._kin_state,
                sensordata=self._kin_sens,
                chunk_size=self._kin_chunk,
            )
            return
        K = len(ids)
        sens = np.zeros((K, 1, self._kin_model.nsensordata))
        self._pool.rollout(
            [self._kin_model] * K,
            self._kin_datas,
            np.ascontiguousarray(self._S[ids]),
            np.zeros((K, 1, self.model.nu)),
            control_spec=_CTRL,
            skip_checks=True,
            nstep=1,
            state=np.zeros((K, 1, self.nstate)),
            sensordata=sens,
            chunk_size=None,
        )
        self._kin_sens[ids] = sens

    def _tensor(self, a: np.ndarray) -> Tensor:
        """A fresh tensor (never a view of simulator buffers) of ``a`` in the output dtype/device."""
        out = torch.from_numpy(a.astype(self._np_dtype, order="C"))  # astype copies
        return out if self.device.type == "cpu" and out.dtype == self.dtype else out.to(self.device, self.dtype)

    def _build_state(self) -> SimState:
        N, B = self.num_envs, self.skeleton.num_bodies
        kin = self._kin_sens.reshape(N, B, _KIN_FIELDS)
        body_pos = self._tensor(kin[..., 0:3])
        body_rot = self._tensor(kin[..., 3:7])
        body_lin_vel = self._tensor(kin[..., 7:10])
        body_ang_vel = self._tensor(kin[..., 10:13])
        return SimState(
            root_pos=self._tensor(kin[:, 0, 0:3]),
            root_rot=self._tensor(kin[:, 0, 3:7]),
            root_lin_vel=self._tensor(kin[:, 0, 7:10]),
            root_ang_vel=self._tensor(kin[:, 0, 10:13]),
            dof_pos=self._tensor(self._S[:, self._dof_qpos]),
            dof_vel=self._tensor(self._S[:, self._dof_qvel]),
            body_pos=body_pos,
            body_rot=body_rot,
            body_lin_vel=body_lin_vel,
            body_ang_vel=body_ang_vel,
            contact_forces=self._tensor(self._contact_force),
            body_contact=torch.from_numpy(self._body_contact.copy()).to(self.device),
            unstable=torch.from_numpy(self._unstable.copy()).to(self.device),
            dof_force=self._tensor(self._dof_force),
        )
