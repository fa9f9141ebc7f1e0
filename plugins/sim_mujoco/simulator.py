"""The ``mujoco`` simulator: N humanoids of one skeleton, stepped in C on every core.

Stepping. Every env is one row of a (N, nstate) array of MuJoCo ``mjSTATE_FULLPHYSICS`` states
(time, qpos, qvel, ...; time is kept at 0). A control step is ONE call of
:class:`mujoco.rollout.Rollout` (a persistent C++ thread pool with ``threads`` workers, the GIL
released): all N states advance ``substeps`` physics steps with the PD targets held, and the pool
returns the N x substeps states and sensor values. No Python runs per env or per substep.

Why rollout and not per-env ``MjData`` stepped from a ``ThreadPoolExecutor``: both were measured
by ``bench/sim_throughput.py --threadpool`` on the 2-core machine while other jobs loaded it (runs
vary by +-15%). The thread-pool variant (``mj_step(m, d, substeps)`` + ``mj_kinematics`` /
``mj_comPos`` / ``mj_comVel`` + copies per env, without the tensor conversion this simulator
also pays) was within that noise at N = 16..256 (amp N = 64: 8.6k vs 9.6k env steps/s; smpl
N = 256: 4.6k vs 4.0k in the same run, the reverse in another). Rollout has no per-env Python at
all, is deterministic, and keeps every env independent of the others and of the thread count
(tested), so it is the design.

Cost. Against one long ``rollout`` of the same states and targets without sensors (the raw limit)
the simulator reached 0.71-0.81 of the env steps/s at N >= 64 in wall-clock and 0.75-0.89 in CPU
time (bench results, noisy). What the rest goes to (amp, N = 64, 2 threads): the kinematics pass
below (5-10%: a second pool dispatch plus ~7 us of MuJoCo per env), the numpy/torch state
extraction (3-8%, ~0.2-0.5 ms per step), and waking the pool's threads for every call (a long
rollout never lets other processes take the cores between control steps).

PD control: actions are (N, D) hinge targets in skeleton DoF order, written to the ``position``
actuators' ``ctrl`` (through :class:`~mocap_sim_mujoco.mjcf.ModelIndex`); MuJoCo clamps them to
the joint ranges and runs the PD law at every physics step (``kp``/``kv`` of the actuator,
``kv`` implicit with ``implicitfast``).

State extraction. MuJoCo evaluates sensors inside ``mj_step`` *before* integrating, so sensor
values recorded after a step describe the state one physics step earlier. Contact quantities
are taken from the stepping pass (they are what acted during the step). Kinematic quantities are
computed for the final state by a second, cheap rollout of one step of a *kinematics model*: the
same bodies with timestep 0, Euler, and contacts, constraints and actuation disabled, whose
sensors are ``framepos/framequat/framelinvel/frameangvel`` of every body frame (``xbody``). So
``body_pos``/``body_rot`` are exactly the forward kinematics of the returned ``qpos`` and the
velocities are MuJoCo's own (world frame, at the body origin). The two passes return arrays that
are turned into the :class:`~mocap.state.SimState` tensors with a handful of batched numpy/torch
operations (no per-env loop). (A batched NumPy forward kinematics + velocity recursion from
qpos/qvel matched MuJoCo to 1e-14 but took longer than this pass at N = 64, so it was dropped.)

* ``contact_forces`` (N, B, 3): net contact force on each body from the ground and the target
  prop, world frame, averaged over the substeps of the control step (an impulse / dt), N;
  MuJoCo ``contact`` sensors, ``reduce="netforce"``, the partner as object 1;
* ``body_contact`` (N, B): the body touched the ground or the prop in any substep;
  :attr:`MujocoSimulator.ground_contact` is the same for the ground alone (for fall detection
  when a task has props);
* ``dof_force`` (N, D): actuator torque of each hinge in the last substep (``actuatorfrc``);
* after :meth:`reset` the contact fields of the reset envs are zero (no step has happened).

Warm start: ``rollout`` does not return MuJoCo's ``qacc_warmstart``, and starting each control step
with a cold constraint solver cost 4-9% of the stepping time (measured). The simulator passes
``initial_warmstart`` = the last substep's finite-difference acceleration ``(qvel_4 - qvel_3) / h``
instead (zero after a reset), which recovers it. Results are deterministic and independent of the
other envs and of the thread count (tested).

Instability: after each step an env is *unstable* if its new state has a NaN/inf, a ``|qvel|``
(or ``|qpos|``) entry above ``max_qvel``, or a mean ``|qacc|`` over the control step
(``|change of qvel| / dt``) above ``max_qacc``. Such an env
is put back into the state of its last :meth:`reset` (or :meth:`set_target`), its row of
``SimState.unstable`` is True for this step and :attr:`instability_count` grows; the other envs
are untouched. MuJoCo's own auto-reset is disabled (it would silently teleport an env to the
model's rest state).

Options for VMP (both off by default, :class:`MujocoParams`): ``actuator_model`` computes the joint
torques of VMP's Eqs. 9-11 at every physics step on motor actuators (one rollout call per substep;
:mod:`mocap_sim_mujoco.actuators`, with its measured stability limits); :meth:`set_external_wrench`
holds external forces / torques on bodies (pushes) and :meth:`env_models` gives per-env model copies
(mass and friction randomization).

Props (all optional, per env, see :class:`MujocoParams`):

* ``target``: a free box (a pillar by default) for the ``strike`` task: :meth:`set_target`,
  :meth:`target_state` (pos, rot, velocities, ``fallen`` = tilted more than ``fallen_angle``);
* ``markers``: visual-only spheres (mocap bodies that collide with nothing) whose positions
  :meth:`set_markers` stores per env, for rendering goals (:meth:`write_mjdata`);
* ``terrain``: a height field shared by all envs (:mod:`mocap_sim_mujoco.terrain`) with
  :meth:`height_at` and :meth:`height_map` queries; without one the ground is the plane z = 0.

Code layout: the parameter models live in :mod:`mocap_sim_mujoco.mujoco_params`, the state extraction in
:mod:`mocap_sim_mujoco.readout` and the state access, props and terrain queries in :mod:`mocap_sim_mujoco.props`
(mixins of :class:`MujocoSimulator`); every name is still importable from here.
"""

from __future__ import annotations

import copy
from typing import Any
import os
from dataclasses import replace

import mujoco
import numpy as np
import torch
from mujoco import rollout as mj_rollout
from torch import Tensor

from mocap.interfaces import Simulator
from mocap.rotations import quat_apply, quat_conjugate, quat_normalize
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, SimState
from mocap_sim_mujoco.actuators import ActuatorModel, explicit_stability_ratio, to_motor_actuators
from mocap_sim_mujoco.mjcf import FLOOR_GEOM, ModelIndex, build_mjcf, model_index
from mocap_sim_mujoco.mujoco_params import MujocoParams, TargetParams
from mocap.state import TargetState
from mocap_sim_mujoco.props import SimulatorExtras
from mocap_sim_mujoco.readout import _CTRL, _FULL, _XFRC, StateReadout
from mocap_sim_mujoco.terrain import Terrain, TerrainParams

__all__ = ["MujocoParams", "MujocoSimulator", "TargetParams", "TargetState", "TerrainParams", "make_simulator"]

TARGET_BODY = "target"
TARGET_JOINT = "target_root"
MARKER_PREFIX = "marker"


def _f(v: float) -> str:
    return f"{float(v):.9g}"


class MujocoSimulator(StateReadout, SimulatorExtras, Simulator):
    """``num_envs`` humanoids of ``skeleton`` in MuJoCo (module docstring for the design).

    Args:
        params: :class:`MujocoParams`.
        skeleton: the humanoid (MJCF generated by :func:`~mocap_sim_mujoco.mjcf.build_mjcf`).
        num_envs: N.
        seed: seeds the terrain generation (the physics itself is deterministic).
        device: where the returned tensors live.
        dtype: their floating-point type.
    """

    def __init__(
        self,
        params: MujocoParams | None = None,
        *,
        skeleton: Skeleton,
        num_envs: int,
        seed: int = 0,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
    ):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.params = p = params or MujocoParams()
        self.skeleton = skeleton
        self.num_envs = N = int(num_envs)
        self.seed = seed
        self.device = torch.device(device)
        self.dtype = dtype
        self._np_dtype = torch.empty(0, dtype=dtype).numpy().dtype if dtype in (torch.float32, torch.float64) else np.float64
        self.terrain = Terrain(p.terrain, seed=seed) if p.terrain is not None else None
        B, D = skeleton.num_bodies, skeleton.num_dofs

        # ------------------------------------------------------------------------ models
        mu = skeleton.friction
        world, assets = [], ""
        partners = [f'geom1="{FLOOR_GEOM}"']
        self._ground_partners = [0]
        if self.terrain is not None:
            world.append(self.terrain.geom_xml(FLOOR_GEOM, mu))
            assets = self.terrain.asset_xml()
        if p.target is not None:
            t = p.target
            gz = float(self.height_at(torch.tensor([t.position], dtype=torch.float64))[0]) if self.terrain else 0.0
            world.append(
                f'<body name="{TARGET_BODY}" pos="{_f(t.position[0])} {_f(t.position[1])} {_f(gz + t.half_size[2])}">'
                f'<freejoint name="{TARGET_JOINT}"/>'
                f'<geom name="target_geom" type="box" size="{" ".join(_f(v) for v in t.half_size)}" mass="{_f(t.mass)}" '
                f'rgba="{" ".join(_f(v) for v in t.rgba)}" contype="1" conaffinity="1" friction="{_f(t.friction)} 0.005 0.0001"/>'
                "</body>"
            )
            partners.append(f'body1="{TARGET_BODY}"')
        for k in range(p.markers):
            world.append(
                f'<body name="{MARKER_PREFIX}{k}" mocap="true" pos="0 0 -10"><geom type="sphere" size="{_f(p.marker_radius)}" '
                f'rgba="{" ".join(_f(v) for v in p.marker_rgba)}" contype="0" conaffinity="0" group="2"/></body>'
            )
        contact_sensors = [
            f'<contact {partner} body2="{b.name}" num="1" reduce="netforce" data="found force"/>' for partner in partners for b in skeleton.bodies
        ]
        force_sensors = [f'<actuatorfrc actuator="{h.name}"/>' for h in skeleton.hinges]
        kin_sensors = [
            f'<framepos objtype="xbody" objname="{b.name}"/><framequat objtype="xbody" objname="{b.name}"/>'
            f'<framelinvel objtype="xbody" objname="{b.name}"/><frameangvel objtype="xbody" objname="{b.name}"/>'
            for b in skeleton.bodies
        ]
        common: dict[str, Any] = dict(
            timestep=p.timestep,
            iterations=p.iterations,
            ls_iterations=p.ls_iterations,
            floor=self.terrain is None,
            joint_limits=p.joint_limits,
            self_collision=p.self_collision,
            extra_worldbody="\n".join(world),
        )
        self.mjcf = build_mjcf(skeleton, extra_xml=assets + "<sensor>" + "".join(contact_sensors + force_sensors) + "</sensor>", **common)
        kin_xml = build_mjcf(skeleton, extra_xml=assets + "<sensor>" + "".join(kin_sensors) + "</sensor>", **common)
        self.model = self._compile(self.mjcf)
        self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        self._kin_model = kin = self._compile(kin_xml)
        kin.opt.timestep = 0.0
        kin.opt.integrator = int(mujoco.mjtIntegrator.mjINT_EULER)
        dis = mujoco.mjtDisableBit
        for flag in ("mjDSBL_CONSTRAINT", "mjDSBL_CONTACT", "mjDSBL_ACTUATION", "mjDSBL_GRAVITY", "mjDSBL_AUTORESET", "mjDSBL_WARMSTART"):
            kin.opt.disableflags |= int(getattr(dis, flag))
        if self.terrain is not None:
            self.terrain.write_model(self.model)
            self.terrain.write_model(kin)
        m = self.model
        self.index: ModelIndex = model_index(m, skeleton)
        self._num_partners = len(partners)

        # ------------------------------------------------------------------- state layout
        self.nstate = mujoco.mj_stateSize(m, _FULL)
        if mujoco.mj_stateSize(kin, _FULL) != self.nstate or kin.nu != m.nu:
            raise RuntimeError("kinematics model does not match the simulation model")
        self._qp = 1  # mjSTATE_FULLPHYSICS starts with time, then qpos, then qvel
        self._qv = 1 + m.nq
        self._check_state_layout()
        idx = self.index
        self._root_qpos = self._qp + idx.root_qpos
        self._root_qvel = self._qv + idx.root_qvel
        self._dof_qpos = self._qp + idx.dof_qpos
        self._dof_qvel = self._qv + idx.dof_qvel
        self._act = idx.actuator_ids
        self.actuators: ActuatorModel | None = None
        if p.actuator_model is not None:
            self.actuators = ActuatorModel.for_skeleton(skeleton, p.actuator_model)
            to_motor_actuators(m, self._act)
            ratio = explicit_stability_ratio(m, idx.dof_qvel, self.actuators.kd, p.timestep)
            if ratio > p.actuator_model.max_stability_ratio:
                raise ValueError(
                    f"actuator_model: timestep {p.timestep:.6g} s is too large for explicit PD damping on this humanoid "
                    f"(max timestep kd / M_jj = {ratio:.3g} > {p.actuator_model.max_stability_ratio}); use timestep <= "
                    f"{p.timestep * p.actuator_model.max_stability_ratio / ratio:.6g} s (more substeps)"
                )
        if p.target is not None:
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, TARGET_JOINT)
            self._target_qpos = self._qp + int(m.jnt_qposadr[jid])
            self._target_qvel = self._qv + int(m.jnt_dofadr[jid])
        self._n_contact = self._num_partners * B * 4

        # ----------------------------------------------------------------------- threads
        self.threads = int(p.threads or os.cpu_count() or 1)
        self._pool = mj_rollout.Rollout(nthread=self.threads if self.threads > 1 else 0)
        nd = max(1, self.threads)
        self._datas = [mujoco.MjData(m) for _ in range(nd)]
        self._kin_datas = [mujoco.MjData(kin) for _ in range(nd)]
        self._models = [m] * N
        self._kin_models = [kin] * N
        # the kinematics pass costs the same for every env: few, large chunks (4 per thread, so that
        # one descheduled thread on a shared machine does not hold up the whole pass)
        self._kin_chunk = max(1, N // (4 * self.threads))

        # ----------------------------------------------------------------------- buffers
        d0 = mujoco.MjData(m)
        mujoco.mj_resetData(m, d0)
        s0 = np.zeros(self.nstate)
        mujoco.mj_getState(m, d0, s0, _FULL)
        self._S = np.ascontiguousarray(np.tile(s0, (N, 1)))
        self._reset_S = self._S.copy()
        self._ctrl = np.zeros((N, p.substeps, m.nu))
        self._warm = np.zeros((N, m.nv))
        self._ctrl1 = np.zeros((N, 1, m.nu))
        self._traj = np.zeros((N, p.substeps, self.nstate))
        self._sens = np.zeros((N, p.substeps, m.nsensordata))
        self._kin_state = np.zeros((N, 1, self.nstate))
        self._kin_sens = np.zeros((N, 1, kin.nsensordata))
        self._contact_force = np.zeros((N, B, 3))
        self._body_contact = np.zeros((N, B), dtype=bool)
        self._ground_contact = np.zeros((N, B), dtype=bool)
        self._dof_force = np.zeros((N, D))
        self._unstable = np.zeros(N, dtype=bool)
        self._markers = np.zeros((N, p.markers, 3))
        self._markers[..., 2] = -10.0
        self._instability_count = 0
        self._cached: SimState | None = None
        self._xfrc = np.zeros((N, m.nbody, 6))  # external wrenches (set_external_wrench), world frame
        self._xfrc_used = False
        self._own_models = False
        self._kinematics()

    # ------------------------------------------------------------------------------ setup
    @staticmethod
    def _compile(xml: str) -> mujoco.MjModel:
        try:
            return mujoco.MjModel.from_xml_string(xml)
        except ValueError as exc:  # pragma: no cover - generated XML
            raise ValueError(f"MuJoCo rejected the simulator's MJCF: {exc}") from exc

    def _check_state_layout(self) -> None:
        m = self.model
        d = mujoco.MjData(m)
        d.time = 0.25
        d.qpos[:] = np.arange(m.nq) + 1.0
        d.qvel[:] = -(np.arange(m.nv) + 1.0)
        s = np.zeros(self.nstate)
        mujoco.mj_getState(m, d, s, _FULL)
        ok = s[0] == 0.25 and np.array_equal(s[self._qp : self._qp + m.nq], d.qpos) and np.array_equal(s[self._qv : self._qv + m.nv], d.qvel)
        if not ok:  # pragma: no cover - guards against a MuJoCo layout change
            raise RuntimeError("unexpected mjSTATE_FULLPHYSICS layout (time, qpos, qvel, ...)")

    # ----------------------------------------------------------------------- interface
    @property
    def dt(self) -> float:
        return self.params.timestep * self.params.substeps

    @property
    def instability_count(self) -> int:
        return self._instability_count

    @property
    def state(self) -> SimState:
        """The current state (built once per step/reset; each access returns a shallow copy, so
        rebinding its fields is harmless, but do not modify its tensors in place)."""
        if self._cached is None:
            self._cached = self._build_state()
        return replace(self._cached)

    def step(self, actions: Tensor) -> SimState:
        N, D = self.num_envs, self.skeleton.num_dofs
        if self._pool is None:
            raise RuntimeError("the simulator was closed")
        if tuple(actions.shape) != (N, D):
            raise ValueError(f"actions must be ({N}, {D}) PD targets, got {tuple(actions.shape)}")
        a = actions.detach().to(device="cpu", dtype=torch.float64).numpy()
        if self.actuators is not None:
            self._rollout_actuated(a)
        else:
            if self.index.identity_order and self.model.nu == D:
                self._ctrl[:] = a[:, None, :]
            else:
                self._ctrl[:, :, self._act] = a[:, None, :]
            control, spec = self._control(self._ctrl)
            self._pool.rollout(
                self._models,
                self._datas,
                self._S,
                control,
                control_spec=spec,
                skip_checks=True,
                nstep=self.params.substeps,
                initial_warmstart=self._warm,
                state=self._traj,
                sensordata=self._sens,
                chunk_size=self.params.chunk_size,
            )
        bad = self._detect_unstable()
        self._update_warmstart(bad)
        np.copyto(self._S, self._traj[:, -1])
        self._S[:, 0] = 0.0  # MuJoCo time is not tracked (it would grow without bound in the checks)
        self._read_contacts()
        if bad.any():
            self._S[bad] = self._reset_S[bad]
            self._contact_force[bad] = 0.0
            self._body_contact[bad] = False
            self._ground_contact[bad] = False
            self._dof_force[bad] = 0.0
            self._instability_count += int(bad.sum())
        self._unstable = bad
        self._kinematics()
        self._cached = None
        return self.state

    def _rollout_actuated(self, targets: np.ndarray) -> None:
        """The control step with the actuator model: one rollout call per physics substep, the joint
        torques (Eq. 11) computed in between from that substep's qpos / qvel, the targets held.
        Fills ``_traj`` and ``_sens`` like the single rollout call."""
        assert self.actuators is not None
        N, h = self.num_envs, self.params.timestep
        qv = slice(self._qv, self._qv + self.model.nv)
        S = self._S.copy()
        warm = self._warm.copy()
        ctrl = np.zeros((N, 1, self.model.nu))
        out = np.zeros((N, 1, self.nstate))
        sens = np.zeros((N, 1, self.model.nsensordata))
        for k in range(self.params.substeps):
            ctrl[:, 0, self._act] = self.actuators.torque(targets, S[:, self._dof_qpos], S[:, self._dof_qvel])
            control, spec = self._control(ctrl)
            self._pool.rollout(
                self._models,
                self._datas,
                S,
                control,
                control_spec=spec,
                skip_checks=True,
                nstep=1,
                initial_warmstart=warm,
                state=out,
                sensordata=sens,
                chunk_size=self.params.chunk_size,
            )
            self._traj[:, k] = out[:, 0]
            self._sens[:, k] = sens[:, 0]
            np.subtract(out[:, 0, qv], S[:, qv], out=warm)
            warm *= 1.0 / h
            np.nan_to_num(warm, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
            S[:] = out[:, 0]
            S[:, 0] = 0.0

    def _control(self, ctrl: np.ndarray) -> tuple[np.ndarray, int]:
        """The rollout control array and spec: ``ctrl`` alone, or (once :meth:`set_external_wrench`
        was used) ``ctrl`` plus every body's ``xfrc_applied``, held over the substeps."""
        if not self._xfrc_used:
            return ctrl, _CTRL
        N, T = ctrl.shape[:2]
        x = np.broadcast_to(self._xfrc.reshape(N, 1, -1), (N, T, self._xfrc[0].size))
        return np.ascontiguousarray(np.concatenate((ctrl, x), -1)), _CTRL | _XFRC

    def set_external_wrench(self, env_ids: Tensor, wrench: Tensor | np.ndarray) -> None:
        """Hold external wrenches on envs ``env_ids`` (K,) until changed or reset: ``wrench`` (K, B, 6)
        per skeleton body, force (N) then torque (N m), world frame, at the body's centre of mass
        (MuJoCo ``xfrc_applied``). A reset of an env clears its wrenches."""
        ids = self._ids(env_ids)
        w = np.asarray(torch.as_tensor(wrench).detach().to("cpu", torch.float64)).reshape(len(ids), self.skeleton.num_bodies, 6)
        rows = self._xfrc[ids]
        rows[:, self.index.body_ids] = w
        self._xfrc[ids] = rows
        self._xfrc_used = True

    @property
    def external_wrench(self) -> Tensor:
        """(N, B, 6) the wrenches held by :meth:`set_external_wrench`."""
        return self._tensor(self._xfrc[:, self.index.body_ids])

    def env_models(self) -> list[mujoco.MjModel]:
        """The N per-env models the stepping uses, made independent copies of :attr:`model` on the
        first call (for per-env physical parameters: domain randomization). Edit them only between
        steps; call ``mujoco.mj_setConst`` after changing masses."""
        if not self._own_models:
            self._models = [copy.copy(self.model) for _ in range(self.num_envs)]
            self._own_models = True
        return self._models

    def reset(self, env_ids: Tensor, state: HumanoidState) -> None:
        ids = self._ids(env_ids)
        K = len(ids)
        if state.num_envs != K:
            raise ValueError(f"reset got {K} env ids but a state with {state.num_envs} rows")
        if K == 0:
            return

        def arr(t: Tensor) -> np.ndarray:
            return t.detach().to(device="cpu", dtype=torch.float64).numpy()

        rot = quat_normalize(state.root_rot.detach().to("cpu", torch.float64))
        ang_local = quat_apply(quat_conjugate(rot), state.root_ang_vel.detach().to("cpu", torch.float64))
        rows = self._S[ids].copy()
        rows[:, 0] = 0.0
        r, v = self._root_qpos, self._root_qvel
        rows[:, r : r + 3] = arr(state.root_pos)
        rows[:, r + 3 : r + 7] = rot.numpy()
        rows[:, v : v + 3] = arr(state.root_lin_vel)
        rows[:, v + 3 : v + 6] = ang_local.numpy()
        rows[:, self._dof_qpos] = arr(state.dof_pos)
        rows[:, self._dof_qvel] = arr(state.dof_vel)
        self._S[ids] = rows
        self._reset_S[ids] = rows
        self._after_set(ids)

    def make_recorder(self, *, ghost: bool = False, **options: Any) -> Any:
        """A :class:`~mocap_sim_mujoco.render.VideoRecorder` for this humanoid (``add_frame(state,
        ghost=reference)`` records env 0; ``save(path)`` writes MP4 or GIF)."""
        from mocap_sim_mujoco.render import VideoRecorder

        return VideoRecorder(self.skeleton, ghost=ghost, **options)

    def close(self) -> None:
        pool, self._pool = getattr(self, "_pool", None), None
        if pool is not None:
            pool.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass

    # ------------------------------------------------------------------------ internals
    def _ids(self, env_ids: Tensor | np.ndarray | list[int]) -> np.ndarray:
        ids = torch.as_tensor(env_ids).detach().to("cpu").long().reshape(-1).numpy()
        if ids.size and (ids.min() < 0 or ids.max() >= self.num_envs):
            raise IndexError(f"env ids must be in [0, {self.num_envs}), got {ids.min()}..{ids.max()}")
        return ids

    def _after_set(self, ids: np.ndarray) -> None:
        """Envs ``ids`` were written: recompute their kinematics, clear their step outputs."""
        self._contact_force[ids] = 0.0
        self._body_contact[ids] = False
        self._ground_contact[ids] = False
        self._dof_force[ids] = 0.0
        self._unstable[ids] = False
        self._warm[ids] = 0.0
        self._xfrc[ids] = 0.0
        self._kinematics(ids)
        self._cached = None


def make_simulator(
    params: MujocoParams | None = None,
    *,
    skeleton: Skeleton,
    num_envs: int,
    seed: int = 0,
    device: torch.device | str = "cpu",
) -> MujocoSimulator:
    """Registry factory of the ``mujoco`` simulator."""
    return MujocoSimulator(params, skeleton=skeleton, num_envs=num_envs, seed=seed, device=device)
