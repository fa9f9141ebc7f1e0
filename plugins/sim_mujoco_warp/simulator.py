"""The ``mujoco_warp`` simulator: the ``mujoco`` simulator's model stepped by MuJoCo Warp.

Same model. The MJCF (humanoid, floor or height field, target prop, markers, contact and
actuator-force sensors) is the one the ``mujoco`` plugin generates: the constructor builds a
one-env :class:`~mocap_sim_mujoco.simulator.MujocoSimulator` with the same parameters, takes its
compiled ``MjModel`` (terrain heights written), closes it, and hands the model to
``mujoco_warp.put_model``. Only ``mjDSBL_AUTORESET`` is cleared (MuJoCo Warp does not know the flag
and never auto-resets). Position actuators, ``implicitfast``, 20/10 solver iterations, the same
timestep and substeps: a spec switches backend with ``simulator: {name: mujoco_warp}`` alone.

Batched stepping. The N envs are MuJoCo Warp's ``nworld`` = N worlds of one ``Data``. A control
step writes the (N, D) PD targets into ``ctrl`` and calls ``mujoco_warp.step`` ``substeps`` times
(on CUDA, one physics step is captured once as a CUDA graph and replayed), summing the contact
sensors after each substep. Then ``kinematics``/``com_pos``/``com_vel`` are run once more so that
body frames and velocities describe the *returned* state (MuJoCo computes them before
integrating), exactly what the ``mujoco`` plugin's kinematics pass gives. MuJoCo Warp keeps its
solver warm start (``qacc_warmstart``) in ``Data`` from step to step.

State. ``wp.to_torch`` views of the Warp arrays (zero-copy, on the Warp device) are read with a
few batched torch operations into a fresh :class:`~mocap.state.SimState` (float32: MuJoCo Warp
simulates in float32, the ``mujoco`` plugin in float64), on ``device`` (default: the Warp device;
a tensor already there is not copied again). Same layout as ``mujoco``: body ``pos``/``rot`` from
``xpos``/``xquat`` (wxyz), world velocities of the body origins from ``cvel`` (shifted from the
subtree centre of mass to ``xpos``), ``contact_forces`` (N, B, 3) = net contact force on each body
from the ground and the target prop averaged over the substeps, ``body_contact`` = a contact in any
substep, ``dof_force`` = the actuator torque of the last substep, ``unstable``.

Resets write ``qpos``/``qvel`` rows of the given envs (free-joint angular velocity turned to the
root frame as MuJoCo stores it), zero their warm start and recompute the kinematics; the other
worlds are not touched.

Instability: as in ``mujoco``: after a step an env whose ``qpos``/``qvel`` has a NaN/inf, an entry
above ``max_qvel``, or changed by more than ``max_qacc * dt`` over the control step (a mean
``|qacc|`` above ``max_qacc``) is put back into the state of its last :meth:`reset` (or
:meth:`set_target`); ``SimState.unstable`` flags it and :attr:`instability_count` grows.

Props and what is not supported:

* ``target`` (the strike task's box), ``markers`` and ``terrain`` (height field) work: the model is
  the ``mujoco`` one and MuJoCo Warp collides boxes, capsules and spheres with planes and height
  fields. Markers are visual only and kept on the host (:meth:`write_mjdata` for rendering).
* ``threads`` and ``chunk_size`` are accepted (a spec written for ``mujoco`` validates) and
  ignored: Warp schedules the worlds itself.
* Contacts per world are bounded: ``nconmax`` contacts and ``njmax`` constraint rows are
  allocated per world (MuJoCo Warp drops contacts beyond them). The defaults hold a humanoid lying
  flat on the ground; raise them for rough terrain.
* ``get_physics_state``/``set_physics_state`` of the ``mujoco`` plugin (full ``mjSTATE`` rows) are
  not offered; :attr:`qpos`/:attr:`qvel` are.
* Results are float32 and, on GPU, contact order is not deterministic, so runs are close to but
  not bitwise equal to ``mujoco`` (tests/test_sim_mujoco_warp.py measures the gap).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import replace
from typing import Any

import mujoco
import numpy as np
import torch
from mocap.interfaces import Simulator
from mocap.plugins import PluginError
from mocap.rotations import quat_apply, quat_conjugate, quat_normalize
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, SimState, TargetState
from mocap_sim_mujoco.simulator import (
    TARGET_JOINT,
    MujocoParams,
    MujocoSimulator,
)
from mocap_sim_mujoco.terrain import height_map
from mocap_sim_mujoco_warp.warp_params import MujocoWarpParams
from torch import Tensor

__all__ = ["MISSING_MESSAGE", "MissingMujocoWarp", "MujocoWarpParams", "MujocoWarpSimulator", "import_warp", "make_simulator"]

MISSING_MESSAGE = "simulator 'mujoco_warp' needs MuJoCo Warp: pip install 'mocap[warp]'"


class MissingMujocoWarp(PluginError, ImportError):
    """``warp`` / ``mujoco_warp`` cannot be imported (printed by the CLI as one line, exit code 2)."""

    def format(self) -> str:
        """The message as the CLI prints it (rich markup: ``[warp]`` must not be read as a tag)."""
        from rich.markup import escape

        return escape(str(self))


def import_warp() -> tuple[Any, Any]:
    """``(warp, mujoco_warp)``, imported on first use; :class:`MissingMujocoWarp` when not installed."""
    try:
        import mujoco_warp as mjw
        import warp as wp
    except ImportError as exc:
        raise MissingMujocoWarp(MISSING_MESSAGE) from exc
    return wp, mjw


class MujocoWarpSimulator(Simulator):
    """``num_envs`` humanoids of ``skeleton`` as MuJoCo Warp worlds (module docstring for the design).

    Args:
        params: :class:`MujocoWarpParams`.
        skeleton: the humanoid.
        num_envs: N (``nworld``).
        seed: seeds the terrain generation.
        device: where the returned tensors live (default: ``params.state_device``, else the Warp device).
        dtype: their floating-point type (float32 by default, MuJoCo Warp's own).
    """

    def __init__(
        self,
        params: MujocoWarpParams | None = None,
        *,
        skeleton: Skeleton,
        num_envs: int,
        seed: int = 0,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
    ):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        wp, mjw = import_warp()
        self._wp, self._mjw = wp, mjw
        self._torch_stream: Any = None  # CUDA: the simulator's own stream (set with the device below)
        self.params = p = params or MujocoWarpParams()
        self.skeleton = skeleton
        self.num_envs = N = int(num_envs)
        self.seed = seed
        self.dtype = dtype
        B, D = skeleton.num_bodies, skeleton.num_dofs

        # ----------------------------------------------------- the mujoco plugin's model
        host_params = MujocoParams.model_validate(p.model_dump(include=set(MujocoParams.model_fields)) | {"threads": 1, "chunk_size": None})
        host = MujocoSimulator(host_params, skeleton=skeleton, num_envs=1, seed=seed)
        try:
            self.mjcf = host.mjcf
            self.model = m = host.model
            self.index = host.index
            self.terrain = host.terrain
        finally:
            host.close()
        m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        self._num_partners = 2 if p.target is not None else 1
        n_contact_sensors = self._num_partners * B
        self._n_contact = int(m.sensor_adr[n_contact_sensors])  # contact sensors come first, 4 values each
        if self._n_contact != 4 * n_contact_sensors or m.nsensor != n_contact_sensors + D:
            raise RuntimeError("unexpected sensor layout of the mujoco plugin's model")
        self._force_adr = torch.as_tensor(m.sensor_adr[n_contact_sensors:], dtype=torch.long)
        if p.target is not None:
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, TARGET_JOINT)
            self._target_qpos, self._target_qvel = int(m.jnt_qposadr[jid]), int(m.jnt_dofadr[jid])

        # ---------------------------------------------------------------- warp device/data
        wp.init()
        name = p.device or ("cuda" if wp.is_cuda_available() else "cpu")
        try:
            self.wp_device = wp.get_device(name)
        except Exception as exc:  # warp raises RuntimeError/ValueError for unknown devices
            raise PluginError(f"simulator 'mujoco_warp': Warp device {name!r} is not available ({exc})") from exc
        self.sim_device = torch.device(wp.device_to_torch(self.wp_device))
        out = device if device is not None else p.state_device
        self.device = torch.device(out) if out is not None else self.sim_device
        self._is_cuda = self.wp_device.is_cuda
        # CUDA: a stream of the simulator's own. A CUDA graph cannot be captured on the legacy default
        # stream, torch's current stream unless a program switches (Warp: "unknown stream").
        if self._is_cuda:
            self._torch_stream = torch.cuda.Stream(self.sim_device)
        self._stream = wp.stream_from_torch(self._torch_stream) if self._torch_stream is not None else None
        nconmax = p.nconmax or (256 if self.terrain is not None else 128 if p.target is not None else 96)
        njmax = p.njmax or 4 * nconmax + m.nv
        with self._scope():
            self._mw = mjw.put_model(m)
            self._d = d = mjw.make_data(m, nworld=N, nconmax=nconmax, njmax=njmax)
            mjw.reset_data(self._mw, d)
        self.nconmax, self.njmax = nconmax, njmax

        # zero-copy torch views of the Warp arrays
        t = wp.to_torch
        self._qpos, self._qvel, self._ctrl = t(d.qpos), t(d.qvel), t(d.ctrl)
        self._warm, self._time, self._sens = t(d.qacc_warmstart), t(d.time), t(d.sensordata)
        self._xpos, self._xquat, self._cvel, self._subtree_com = t(d.xpos), t(d.xquat), t(d.cvel), t(d.subtree_com)
        dev = self.sim_device
        self._body_ids = torch.as_tensor(self.index.body_ids, dtype=torch.long, device=dev)
        self._root_of = torch.as_tensor(m.body_rootid, dtype=torch.long, device=dev)[self._body_ids]
        self._dof_qpos = torch.as_tensor(self.index.dof_qpos, dtype=torch.long, device=dev)
        self._dof_qvel = torch.as_tensor(self.index.dof_qvel, dtype=torch.long, device=dev)
        self._act = torch.as_tensor(self.index.actuator_ids, dtype=torch.long, device=dev)
        self._force_adr = self._force_adr.to(dev)
        self._identity_ctrl = bool(self.index.identity_order and m.nu == D)

        # host-side fallbacks and step outputs (on the Warp device)
        f32: dict[str, Any] = {"device": dev, "dtype": torch.float32}
        self._reset_qpos = self._qpos.clone()
        self._reset_qvel = self._qvel.clone()
        self._acc = torch.zeros(N, self._n_contact, **f32)
        self._contact_force = torch.zeros(N, B, 3, **f32)
        self._body_contact = torch.zeros(N, B, dtype=torch.bool, device=dev)
        self._ground_contact = torch.zeros(N, B, dtype=torch.bool, device=dev)
        self._dof_force = torch.zeros(N, D, **f32)
        self._unstable = torch.zeros(N, dtype=torch.bool, device=dev)
        self._markers = torch.zeros(N, p.markers, 3, dtype=torch.float64)
        self._markers[..., 2] = -10.0
        self._instability_count = 0
        self._graph: Any = None
        self._cached: SimState | None = None
        self._closed = False
        self._kinematics()

    # ----------------------------------------------------------------------- interface
    @property
    def dt(self) -> float:
        return self.params.timestep * self.params.substeps

    @property
    def instability_count(self) -> int:
        return self._instability_count

    @property
    def state(self) -> SimState:
        """The current state (built once per step/reset; each access returns a shallow copy)."""
        if self._cached is None:
            self._cached = self._build_state()
        return replace(self._cached)

    def step(self, actions: Tensor) -> SimState:
        N, D = self.num_envs, self.skeleton.num_dofs
        if self._closed:
            raise RuntimeError("the simulator was closed")
        if tuple(actions.shape) != (N, D):
            raise ValueError(f"actions must be ({N}, {D}) PD targets, got {tuple(actions.shape)}")
        a = actions.detach().to(device=self.sim_device, dtype=torch.float32)
        p = self.params
        with self._scope():
            if self._identity_ctrl:
                self._ctrl.copy_(a)
            else:
                self._ctrl[:, self._act] = a
            old_q, old_v = self._qpos.clone(), self._qvel.clone()
            self._acc.zero_()
            for _ in range(p.substeps):
                self._physics_step()
                self._acc += self._sens[:, : self._n_contact]
            self._dof_force.copy_(self._sens[:, self._force_adr])
            self._time.zero_()  # time is not tracked (as in the mujoco plugin)
            bad = self._detect_unstable(old_q, old_v)
            self._read_contacts()
            nbad = int(bad.sum())
            if nbad:
                self._qpos[bad] = self._reset_qpos[bad]
                self._qvel[bad] = self._reset_qvel[bad]
                self._warm[bad] = 0.0
                for buf in (self._contact_force, self._body_contact, self._ground_contact, self._dof_force):
                    buf[bad] = 0
                self._instability_count += nbad
            self._unstable = bad
            self._kinematics()
        self._cached = None
        return self.state

    def reset(self, env_ids: Tensor, state: HumanoidState) -> None:
        ids = self._ids(env_ids)
        K = len(ids)
        if state.num_envs != K:
            raise ValueError(f"reset got {K} env ids but a state with {state.num_envs} rows")
        if K == 0:
            return
        dev = self.sim_device

        def arr(x: Tensor) -> Tensor:
            return x.detach().to(device=dev, dtype=torch.float32)

        rot64 = quat_normalize(state.root_rot.detach().to("cpu", torch.float64))
        ang_local = quat_apply(quat_conjugate(rot64), state.root_ang_vel.detach().to("cpu", torch.float64))
        idx = self.index
        with self._scope():
            q, v = self._qpos[ids], self._qvel[ids]
            r, rv = idx.root_qpos, idx.root_qvel
            q[:, r : r + 3] = arr(state.root_pos)
            q[:, r + 3 : r + 7] = arr(rot64)
            v[:, rv : rv + 3] = arr(state.root_lin_vel)
            v[:, rv + 3 : rv + 6] = arr(ang_local)
            q[:, self._dof_qpos] = arr(state.dof_pos)
            v[:, self._dof_qvel] = arr(state.dof_vel)
            self._qpos[ids] = q
            self._qvel[ids] = v
            self._reset_qpos[ids] = q
            self._reset_qvel[ids] = v
            self._after_set(ids)

    def make_recorder(self, *, ghost: bool = False, **options: Any) -> Any:
        """The ``mujoco`` plugin's :class:`~mocap_sim_mujoco.render.VideoRecorder` (renders env 0 of a state)."""
        from mocap_sim_mujoco.render import VideoRecorder

        return VideoRecorder(self.skeleton, ghost=ghost, **options)

    def close(self) -> None:
        self._closed = True
        self._graph = None

    # ------------------------------------------------------------------------ internals
    @contextmanager
    def _scope(self) -> Iterator[None]:
        """Warp calls run on the Warp device and, on CUDA, on the simulator's stream, with torch's
        work inside on that stream too (reads and writes of the zero-copy views are ordered with the
        kernels). That stream first waits for the caller's stream (its writes to the views or the
        actions), and the caller's stream waits for it on exit (the state it reads next)."""
        if self._torch_stream is None:
            with self._wp.ScopedDevice(self.wp_device) if hasattr(self, "wp_device") else nullcontext():
                yield
            return
        caller = torch.cuda.current_stream(self.sim_device)
        self._torch_stream.wait_stream(caller)
        try:
            with torch.cuda.stream(self._torch_stream), self._wp.ScopedStream(self._stream):
                yield
        finally:
            caller.wait_stream(self._torch_stream)

    def _physics_step(self) -> None:
        wp, mjw = self._wp, self._mjw
        if not (self._is_cuda and self.params.cuda_graph):
            mjw.step(self._mw, self._d)
            return
        if self._graph is None:
            mjw.step(self._mw, self._d)  # compiles/loads the kernels outside the capture
            with wp.ScopedCapture(device=self.wp_device, stream=self._stream) as capture:
                mjw.step(self._mw, self._d)
            self._graph = capture.graph
            return
        wp.capture_launch(self._graph, stream=self._stream)

    def _ids(self, env_ids: Tensor | np.ndarray | list[int]) -> Tensor:
        ids = torch.as_tensor(env_ids).detach().to("cpu").long().reshape(-1)
        if ids.numel() and (int(ids.min()) < 0 or int(ids.max()) >= self.num_envs):
            raise IndexError(f"env ids must be in [0, {self.num_envs}), got {int(ids.min())}..{int(ids.max())}")
        return ids.to(self.sim_device)

    def _after_set(self, ids: Tensor) -> None:
        """Envs ``ids`` were written: clear their warm start and step outputs, recompute kinematics."""
        self._warm[ids] = 0.0
        for buf in (self._contact_force, self._body_contact, self._ground_contact, self._dof_force, self._unstable):
            buf[ids] = 0
        self._kinematics()
        self._cached = None

    def _detect_unstable(self, old_q: Tensor, old_v: Tensor) -> Tensor:
        """(N,) bool, the ``mujoco`` plugin's rule on the ``qpos``/``qvel`` rows (NaN fails every
        comparison, so it is caught too)."""
        p = self.params
        lim = p.max_qacc * p.timestep * p.substeps
        ok = torch.ones(self.num_envs, dtype=torch.bool, device=self.sim_device)
        for new, old in ((self._qpos, old_q), (self._qvel, old_v)):
            ok &= (new.abs() <= p.max_qvel).all(dim=1) & ((new - old).abs() <= lim).all(dim=1)
        return ~ok

    def _read_contacts(self) -> None:
        N, B = self.num_envs, self.skeleton.num_bodies
        c = (self._acc / self.params.substeps).reshape(N, self._num_partners, B, 4)
        found = c[..., 0] > 0
        self._body_contact.copy_(found.any(dim=1))
        self._ground_contact.copy_(found[:, 0])
        self._contact_force.copy_(c[..., 1:4].sum(dim=1))

    def _kinematics(self) -> None:
        """Body frames and velocities of the current ``qpos``/``qvel`` (all worlds)."""
        with self._scope():
            self._mjw.kinematics(self._mw, self._d)
            self._mjw.com_pos(self._mw, self._d)
            self._mjw.com_vel(self._mw, self._d)

    def _out(self, x: Tensor) -> Tensor:
        """A fresh tensor (never a view of the Warp arrays) on the output device/dtype."""
        y = x.to(device=self.device, dtype=self.dtype)
        return y.clone() if y.data_ptr() == x.data_ptr() else y

    def _build_state(self) -> SimState:
        bid = self._body_ids
        with self._scope():
            pos = self._xpos[:, bid]
            rot = self._xquat[:, bid]
            cvel = self._cvel[:, bid]  # (N, B, 6): angular, linear at the subtree centre of mass
            com = self._subtree_com[:, self._root_of]
            ang = cvel[..., 0:3]
            lin = cvel[..., 3:6] + torch.cross(ang, pos - com, dim=-1)
            return SimState(
                root_pos=self._out(pos[:, 0]),
                root_rot=self._out(rot[:, 0]),
                root_lin_vel=self._out(lin[:, 0]),
                root_ang_vel=self._out(ang[:, 0]),
                dof_pos=self._out(self._qpos[:, self._dof_qpos]),
                dof_vel=self._out(self._qvel[:, self._dof_qvel]),
                body_pos=self._out(pos),
                body_rot=self._out(rot),
                body_lin_vel=self._out(lin),
                body_ang_vel=self._out(ang),
                contact_forces=self._out(self._contact_force),
                body_contact=self._body_contact.to(self.device, copy=True),
                unstable=self._unstable.to(self.device, copy=True),
                dof_force=self._out(self._dof_force),
            )

    # --------------------------------------------------------------------- extras
    @property
    def ground_contact(self) -> Tensor:
        """(N, B) bool: like ``SimState.body_contact`` but for the ground only (not props)."""
        return self._ground_contact.to(self.device, copy=True)

    @property
    def qpos(self) -> np.ndarray:
        """(N, nq) current ``qpos`` of every world (a float64 copy)."""
        return self._qpos.detach().cpu().double().numpy()

    @property
    def qvel(self) -> np.ndarray:
        """(N, nv) current ``qvel`` of every world (a float64 copy)."""
        return self._qvel.detach().cpu().double().numpy()

    def write_mjdata(self, env_id: int, data: mujoco.MjData) -> mujoco.MjData:
        """Put world ``env_id`` (state and markers) into ``data`` of :attr:`model` and run ``mj_forward``."""
        data.qpos[:] = self.qpos[env_id]
        data.qvel[:] = self.qvel[env_id]
        if self.params.markers:
            data.mocap_pos[:] = self._markers[env_id].numpy()
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
        """Place the target box of envs ``env_ids`` (K,) at ``pos`` (K, 3), ``rot`` (K, 4) (default
        upright), at rest; also part of those envs' instability-reset state."""
        self._need_target()
        ids = self._ids(env_ids)
        K = len(ids)
        if K == 0:
            return
        dev = self.sim_device
        q = torch.zeros(K, 4, dtype=torch.float64)
        q[:, 0] = 1.0
        if rot is not None:
            q = quat_normalize(rot.detach().to("cpu", torch.float64)).reshape(K, 4)
        a, v = self._target_qpos, self._target_qvel
        with self._scope():
            for qbuf, vbuf in ((self._qpos, self._qvel), (self._reset_qpos, self._reset_qvel)):
                rows, vel = qbuf[ids], vbuf[ids]
                rows[:, a : a + 3] = pos.detach().to(dev, torch.float32).reshape(K, 3)
                rows[:, a + 3 : a + 7] = q.to(dev, torch.float32)
                vel[:, v : v + 6] = 0.0
                qbuf[ids], vbuf[ids] = rows, vel
            self._warm[ids] = 0.0
            self._kinematics()
        self._cached = None

    def target_state(self) -> TargetState:
        """Pose, velocities (world) and fallen flag of every env's target box."""
        self._need_target()
        target = self.params.target
        assert target is not None  # _need_target() raised otherwise
        a, v = self._target_qpos, self._target_qvel
        qp, qv = self._qpos.detach().double(), self._qvel.detach().double()
        pos, rot = qp[:, a : a + 3], quat_normalize(qp[:, a + 3 : a + 7])
        lin, ang = qv[:, v : v + 3], quat_apply(rot, qv[:, v + 3 : v + 6])
        up_z = 1.0 - 2.0 * (rot[:, 1] ** 2 + rot[:, 2] ** 2)
        fallen = up_z < math.cos(math.radians(target.fallen_angle))
        pos, rot, lin, ang = (x.to(self.device, self.dtype) for x in (pos, rot, lin, ang))
        return TargetState(pos, rot, lin, ang, fallen=fallen.to(self.device))

    def set_markers(self, env_ids: Tensor, positions: Tensor) -> None:
        """Marker positions (K, M, 3) of envs ``env_ids`` (visual only, kept on the host)."""
        ids = self._ids(env_ids).cpu()
        self._markers[ids] = positions.detach().to("cpu", torch.float64).reshape(len(ids), self.params.markers, 3)

    @property
    def markers(self) -> Tensor:
        """(N, M, 3) marker positions."""
        return self._markers.to(self.device, self.dtype)

    # ------------------------------------------------------------------------ terrain
    def height_at(self, xy: Tensor) -> Tensor:
        """Ground height (...) at world points ``xy`` (..., 2) (0 on the plane)."""
        if self.terrain is None:
            return torch.zeros(xy.shape[:-1], dtype=xy.dtype if xy.is_floating_point() else self.dtype, device=xy.device)
        return self.terrain.height_at(xy)

    def height_map(self, center: Tensor, heading: Tensor, shape: tuple[int, int] = (11, 11), spacing: float = 0.1) -> Tensor:
        """(N, H, W) ground heights on a grid around ``center`` (N, 2) turned by ``heading`` (N,)."""
        return height_map(self.height_at, center, heading, shape, spacing)


def make_simulator(
    params: MujocoWarpParams | None = None,
    *,
    skeleton: Skeleton,
    num_envs: int,
    seed: int = 0,
    device: torch.device | str | None = None,
) -> MujocoWarpSimulator:
    """Registry factory of the ``mujoco_warp`` simulator (clear error when Warp is not installed)."""
    return MujocoWarpSimulator(params, skeleton=skeleton, num_envs=num_envs, seed=seed, device=device)
