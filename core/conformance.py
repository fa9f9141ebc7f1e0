"""Conformance checks of the role contracts (:mod:`mocap.interfaces`), for plugin authors' test suites.

Each ``check_*`` drives a component through what the framework calls and raises
:class:`ContractViolation` naming the first broken promise (a shape, a dtype, a non-finite value,
a state that does not round-trip); it returns a short report of what it checked. The built-in
simulator, tasks and latent spaces pass them in mocap's own suite (``tests/test_conformance.py``).
Re-exported by :mod:`mocap.testing`::

    from mocap.testing import check_task, fake_sim_state

    def test_my_task_keeps_the_contract(amp_skeleton):
        check_task(MyTask(MyParams(), skeleton=amp_skeleton, num_envs=4), amp_skeleton)

:func:`fake_sim_state` builds a consistent batched :class:`~mocap.state.SimState` (standing
rest pose, small random DoF angles and velocities, bodies from forward kinematics) without a
simulator, for unit tests of tasks, rewards and observation code.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping

import torch
from torch import Tensor

from mocap.interfaces import Box, ExternalWrench, LatentSample, LatentSpace, MovableTarget, MultiDiscrete, PerEnvModels, Simulator, Task
from mocap.kinematics import forward_kinematics_dofs
from mocap.sim_snapshot import load_sim_state, save_sim_state
from mocap.skeleton import Skeleton
from mocap.state import HUMANOID_FIELDS, Observations, SimState


class ContractViolation(AssertionError):
    """A component broke its role's contract (the message names the role, the method and what)."""


def _require(ok: bool, what: str) -> None:
    if not ok:
        raise ContractViolation(what)


def _shape(x: Any, shape: tuple[int, ...], what: str) -> None:
    _require(isinstance(x, Tensor), f"{what}: expected a tensor, got {type(x).__name__}")
    _require(tuple(x.shape) == shape, f"{what}: expected shape {shape}, got {tuple(x.shape)}")


def _finite(x: Tensor, what: str) -> None:
    _require(bool(torch.isfinite(x.float()).all()), f"{what}: has non-finite values")


def fake_sim_state(skeleton: Skeleton, num_envs: int, seed: int = 0, height: float = 0.9) -> SimState:
    """(N = ``num_envs``) standing humanoids: root at ``height`` m with a random yaw and xy, DoFs
    N(0, 0.1²) rad, velocities N(0, 0.1²); bodies by forward kinematics; no contacts."""
    g = torch.Generator().manual_seed(int(seed))
    N, D, B = num_envs, skeleton.num_dofs, skeleton.num_bodies
    yaw = (torch.rand(N, generator=g) * 2 - 1) * math.pi
    root_rot = torch.stack((torch.cos(yaw / 2), torch.zeros(N), torch.zeros(N), torch.sin(yaw / 2)), -1)
    root_pos = torch.cat((torch.randn(N, 2, generator=g), torch.full((N, 1), float(height))), -1)
    dof_pos = 0.1 * torch.randn(N, D, generator=g)
    body_pos, body_rot = forward_kinematics_dofs(skeleton, root_pos, root_rot, dof_pos)
    return SimState(
        root_pos=root_pos,
        root_rot=root_rot,
        root_lin_vel=0.1 * torch.randn(N, 3, generator=g),
        root_ang_vel=0.1 * torch.randn(N, 3, generator=g),
        dof_pos=dof_pos,
        dof_vel=0.1 * torch.randn(N, D, generator=g),
        body_pos=body_pos,
        body_rot=body_rot,
        body_lin_vel=0.1 * torch.randn(N, B, 3, generator=g),
        body_ang_vel=0.1 * torch.randn(N, B, 3, generator=g),
        contact_forces=torch.zeros(N, B, 3),
        body_contact=torch.zeros(N, B, dtype=torch.bool),
        unstable=torch.zeros(N, dtype=torch.bool),
        dof_force=torch.zeros(N, D),
    )


def _check_state(state: Any, skeleton: Skeleton, n: int, what: str) -> None:
    _require(isinstance(state, SimState), f"{what}: expected a SimState, got {type(state).__name__}")
    B, D = skeleton.num_bodies, skeleton.num_dofs
    want = {
        "root_pos": (n, 3), "root_rot": (n, 4), "root_lin_vel": (n, 3), "root_ang_vel": (n, 3),
        "dof_pos": (n, D), "dof_vel": (n, D), "body_pos": (n, B, 3), "body_rot": (n, B, 4),
        "body_lin_vel": (n, B, 3), "body_ang_vel": (n, B, 3),
    }  # fmt: skip
    for name in HUMANOID_FIELDS:
        value = getattr(state, name)
        _shape(value, want[name], f"{what}.{name}")
        _finite(value, f"{what}.{name}")
    norms = torch.linalg.vector_norm(state.body_rot.double(), dim=-1)
    _require(bool(((norms - 1).abs() < 1e-3).all()), f"{what}.body_rot: quaternions are not unit length")
    _require(tuple(state.unstable.shape) == (n,) and state.unstable.dtype == torch.bool, f"{what}.unstable: expected ({n},) bool")


def check_simulator(sim: Simulator, steps: int = 3) -> list[str]:
    """A :class:`Simulator`: ``dt`` > 0; ``device`` a :class:`torch.device` where ``state`` lives;
    ``state`` of the declared shapes; ``reset`` of a subset of
    envs puts them at the given pose; ``step`` with (N, D) PD targets returns finite states and a
    wrongly shaped action is a ValueError; ``get_physics_state`` / ``set_physics_state``
    round-trip when offered; and each optional capability it declares (:class:`MovableTarget` when
    built with its prop: the target lands where it was put; :class:`ExternalWrench`: a zero wrench is
    accepted; :class:`PerEnvModels`: one model per env)."""
    sk, N = sim.skeleton, sim.num_envs
    _require(isinstance(sim.dt, float) and sim.dt > 0, f"Simulator.dt must be a positive float, got {sim.dt!r}")
    _require(isinstance(sim.device, torch.device), f"Simulator.device must be a torch.device, got {sim.device!r}")
    _check_state(sim.state, sk, N, "Simulator.state")
    _require(sim.state.root_pos.device.type == sim.device.type, f"Simulator.state lives on {sim.state.root_pos.device}, not Simulator.device {sim.device}")
    start = fake_sim_state(sk, N, seed=1)
    ids = torch.arange(0, N, 2)
    sim.reset(ids, start.index(ids))
    got = sim.state
    _require(
        bool(torch.allclose(got.dof_pos[ids].double(), start.dof_pos[ids].double(), atol=1e-4)),
        "Simulator.reset: the reset envs' dof_pos is not the state they were given",
    )
    _require(
        bool(torch.allclose(got.root_pos[ids].double(), start.root_pos[ids].double(), atol=1e-4)),
        "Simulator.reset: the reset envs' root_pos is not the state they were given",
    )
    sim.reset(torch.arange(N), start)
    for k in range(steps):
        _check_state(sim.step(start.dof_pos.clone()), sk, N, f"Simulator.step (step {k})")
    try:
        sim.step(torch.zeros(N, sk.num_dofs + 1))
    except ValueError:
        pass
    else:
        raise ContractViolation("Simulator.step: actions of the wrong shape must raise ValueError")
    report = [f"state and {steps} steps of {N} envs", "subset reset", "wrong-shape actions refused"]
    saved = sim.get_physics_state()
    if saved is not None:
        before = sim.state.dof_pos.clone()
        sim.step(start.dof_pos.clone())
        sim.set_physics_state(torch.arange(N), saved, as_reset=False)
        _require(bool(torch.allclose(sim.state.dof_pos, before)), "Simulator.set_physics_state does not restore get_physics_state")
        report.append("physics state round-trip")
    return report + _check_capabilities(sim)


def _check_capabilities(sim: Simulator) -> list[str]:
    """The optional simulator capabilities of :mod:`mocap.interfaces` that ``sim`` declares."""
    N, B = sim.num_envs, sim.skeleton.num_bodies
    report = []
    if isinstance(sim, MovableTarget) and sim.has_target:
        pos = torch.tensor([[3.0, 0.5 + i, 0.5] for i in range(N)])
        sim.set_target(torch.arange(N), pos)
        target = sim.target_state()
        _require(tuple(target.pos.shape) == (N, 3) and tuple(target.rot.shape) == (N, 4), "MovableTarget.target_state: expected (N, 3) pos, (N, 4) rot")
        _require(
            bool(torch.allclose(target.pos.double().cpu(), pos.double(), atol=1e-4)), "MovableTarget.target_state: the target is not where set_target put it"
        )
        report.append("movable target")
    if isinstance(sim, ExternalWrench):
        sim.set_external_wrench(torch.arange(N), torch.zeros(N, B, 6))
        report.append("external wrench")
    if isinstance(sim, PerEnvModels):
        _require(len(sim.env_models()) == N, "PerEnvModels.env_models: expected one model per env")
        report.append("per-env models")
    return report


_FORGETS_GOALS = (
    "Task.load_state_dict(state_dict()) does not restore the goals: return every per-env goal, timer and generator state "
    "from Task.state_dict() and set them back in Task.load_state_dict(), or a resumed task stage diverges from an "
    "uninterrupted one (docs/plugins.md, 'What the framework calls, and when')"
)


def check_task(
    task: Task,
    skeleton: Skeleton,
    num_envs: int = 4,
    steps: int = 3,
    state_factory: Callable[[int], SimState] | None = None,
    declared: Mapping[str, Any] | None = None,
    sim: Simulator | None = None,
) -> list[str]:
    """A :class:`Task` with ``num_envs`` envs: ``observe`` (N, goal_dim) finite; ``reward`` (N,)
    finite and at most ``max_reward``; ``terminated`` (N,) bool; ``reset`` of a subset; ``metrics``
    a mapping of names to floats; ``state_dict`` / ``load_state_dict`` round-trip (same
    observation after a reload). ``state_factory(seed)`` gives the states (default
    :func:`fake_sim_state`); tasks that need ``attach`` / ``attach_motions`` get them before.
    ``declared``: the metric declarations the task was registered with (``register(...,
    metrics=...)``, :attr:`mocap.plugins.Component.metrics`); every key ``metrics()`` reports must
    be declared there (an undeclared key reaches reports without a display name or unit).
    ``sim``: the simulator a task with ``sim_overrides`` was attached to (its goal lives there, e.g.
    strike's target): the round-trip saves and restores its physics with the task's state, as the
    task env's ``state_dict`` does."""
    N = num_envs
    make = state_factory or (lambda seed: fake_sim_state(skeleton, N, seed=seed))
    _require(isinstance(task.goal_dim, int) and task.goal_dim >= 0, f"Task.goal_dim must be an int >= 0, got {task.goal_dim!r}")
    state = make(0)
    task.reset(torch.arange(N), state)
    for k in range(steps):
        state = make(k + 1)
        if not task.tracks_reference:
            task.step(state)
        obs = task.observe(state)
        _shape(obs, (N, task.goal_dim), f"Task.observe (step {k})")
        _finite(obs, f"Task.observe (step {k})")
        r = task.reward(state, torch.zeros(N, skeleton.num_dofs))
        _shape(r, (N,), f"Task.reward (step {k})")
        _finite(r, f"Task.reward (step {k})")
        _require(bool((r <= task.max_reward + 1e-5).all()), f"Task.reward (step {k}): above max_reward {task.max_reward}")
        done = task.terminated(state)
        _shape(done, (N,), f"Task.terminated (step {k})")
        _require(done.dtype == torch.bool, f"Task.terminated: expected bool, got {done.dtype}")
    task.reset(torch.arange(0, N, 2), state)  # the framework passes the full (N-row) state after a subset reset
    metrics = task.metrics()
    _require(isinstance(metrics, dict) and all(isinstance(k, str) and isinstance(v, (int, float)) for k, v in metrics.items()),
             "Task.metrics must return {name: float}")  # fmt: skip
    if declared is not None:
        undeclared = sorted(set(metrics) - set(declared))
        _require(not undeclared, f"Task.metrics reports undeclared key(s) {', '.join(undeclared)}: declare them in register(..., metrics=...)")
    saved = task.state_dict()
    physics = save_sim_state(sim) if sim is not None else None
    before = task.observe(state).clone()
    task.reset(torch.arange(N), make(99))
    if sim is not None and physics is not None:
        load_sim_state(sim, torch.arange(N), physics)
    task.load_state_dict(saved)
    _require(bool(torch.allclose(task.observe(state), before)), _FORGETS_GOALS)
    return [f"{steps} steps of {N} envs", "subset reset", "metrics" if declared is None else "declared metrics", "state_dict round-trip"]


def _check_sample(s: Any, n: int, z: int, what: str) -> None:
    _require(isinstance(s, LatentSample), f"{what}: expected a LatentSample, got {type(s).__name__}")
    _shape(s.mean, (n, z), f"{what}.mean")
    _finite(s.mean, f"{what}.mean")
    if s.std is not None:
        _shape(s.std, (n, z), f"{what}.std")
        _require(bool((s.std > 0).all()), f"{what}.std: must be positive")
    if s.z is not None:
        _shape(s.z, (n, z), f"{what}.z")


def check_latent_space(latent: LatentSpace, obs: Observations, action_dim: int) -> list[str]:
    """A :class:`LatentSpace` on a batch ``obs`` (what its encoder, decoder and prior see): samples of
    (N, latent_dim); ``decode_action``'s (N, ``action_dim``) finite raw actions; a task action from its
    ``task_action_space`` mapped by ``to_latent`` to (N, latent_dim); ``random_action`` when it
    ``samples_prior``; ``task_state_dict`` / ``load_task_state_dict`` round-trip. A latent space with
    ``has_encoder`` False (the ``scratch`` baseline) has no posterior to check: ``z`` is its prior's.
    ``obs`` carries what the encoder reads beyond proprioception and goal in ``obs.extra`` (VMP: the
    motion ``window``)."""
    N, Z = int(obs.proprio.shape[0]), int(latent.latent_dim)
    latent.eval()
    with torch.no_grad():
        prior = latent.prior(obs)
        _check_sample(prior, N, Z, "LatentSpace.prior")
        post = prior
        if latent.has_encoder:
            post = latent.encoder(obs)
            _check_sample(post, N, Z, "LatentSpace.encoder")
        z = post.z if post.z is not None else post.mean
        action = latent.decode_action(obs, z)  # the raw decoder output (decoder() may need attach_imitator first)
        _shape(action, (N, action_dim), "LatentSpace.decode_action")
        _finite(action, "LatentSpace.decode_action")
        space = latent.task_action_space
        g = torch.Generator().manual_seed(0)
        if isinstance(space, Box):
            task_action = torch.randn(N, *space.shape, generator=g)
        elif isinstance(space, MultiDiscrete):
            task_action = torch.stack([torch.randint(0, int(k), (N,), generator=g) for k in space.nvec], -1)
        else:
            raise ContractViolation(f"LatentSpace.task_action_space: expected Box or MultiDiscrete, got {type(space).__name__}")
        zt = latent.to_latent(obs, task_action)
        _shape(zt, (N, Z), "LatentSpace.to_latent")
        _finite(zt, "LatentSpace.to_latent")
        checked = "encoder, prior, decode_action" if latent.has_encoder else "prior, decode_action (no encoder)"
        report = [checked, f"task action space {type(space).__name__}", "to_latent"]
        offers_random_action = type(latent).random_action is not LatentSpace.random_action
        _require(
            latent.samples_prior or not offers_random_action,
            f"{type(latent).__name__} defines random_action but leaves samples_prior False, so mocap generate and prior "
            "rollouts will not use it: set the class attribute samples_prior = True (docs/plugins.md, 'What the framework calls, and when')",
        )
        if latent.samples_prior:
            ra = latent.random_action(obs, 1.0, g)
            _require(isinstance(ra, Tensor) and ra.shape[0] == N, "LatentSpace.random_action: expected N rows")
            _finite(ra, "LatentSpace.random_action")
            report.append("random_action")
    saved = latent.task_state_dict()
    latent.load_task_state_dict(saved)
    report.append("task state round-trip")
    return report


__all__ = ["ContractViolation", "check_latent_space", "check_simulator", "check_task", "fake_sim_state"]
