"""Shared pieces of the downstream tasks: fall termination, body lookup, seeded sampling, metric sums.

Conventions are :mod:`mocap.state`'s (z up, wxyz, SI, 30 Hz control). Goal observations are
expressed in the **heading frame** of the humanoid's root (:func:`mocap.observations.world_to_heading`):
rotated by the inverse of the root's yaw and, for positions, taken relative to the root, so that a
yaw of the whole world about z plus a translation leaves them unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch
from mocap.interfaces import Simulator
from mocap.motion.transform import yaw_frames
from mocap.rotations import heading_angle
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, MotionFrames, SimState
from mocap.termination import allowed_contact_mask, fallen
from torch import Tensor
from mocap_tasks.task_params import FallParams, StartParams

__all__ = [
    "FallParams",
    "GoalBookkeeping",
    "MetricSums",
    "TaskBase",
    "angle_between_2d",
    "horizontal_unit",
    "quat_from_yaw",
    "resolve_body",
    "root_heading",
    "rows",
    "wrap_angle",
]

#: right-hand body names of the built-in skeletons (``smpl``, ``amp``), tried in order
RIGHT_HAND_NAMES: tuple[str, ...] = ("R_Hand", "right_hand")


def resolve_body(skeleton: Skeleton, name: str | None, candidates: Sequence[str] = RIGHT_HAND_NAMES) -> int:
    """Index of body ``name``, or of the first of ``candidates`` the skeleton has when ``name`` is None."""
    names = tuple(skeleton.body_names)
    if name is not None:
        if name not in names:
            raise ValueError(f"skeleton {skeleton.name!r} has no body {name!r}; bodies: {', '.join(names)}")
        return names.index(name)
    for c in candidates:
        if c in names:
            return names.index(c)
    raise ValueError(f"skeleton {skeleton.name!r} has none of the bodies {', '.join(candidates)}; name one explicitly")


def rows(state: SimState, env_ids: Tensor, num_envs: int) -> SimState:
    """The rows of ``state`` for ``env_ids``: ``state`` itself when it has one row per id, else indexed.

    ``Task.reset`` may receive either the reset rows (K) or the full batch (N)."""
    k = int(env_ids.numel())
    n = state.num_envs
    if n == k:
        return state
    if n == num_envs:
        return state.index(env_ids.to(state.root_pos.device))
    raise ValueError(f"reset got {k} env ids and a state with {n} rows (expected {k} or {num_envs})")


def wrap_angle(a: Tensor) -> Tensor:
    """Angles wrapped to ``(-pi, pi]``."""
    return torch.atan2(torch.sin(a), torch.cos(a))


def quat_from_yaw(yaw: Tensor) -> Tensor:
    """(..., 4) wxyz rotation by ``yaw`` about world z."""
    half = 0.5 * yaw
    z = torch.zeros_like(half)
    return torch.stack((torch.cos(half), z, z, torch.sin(half)), dim=-1)


def root_heading(state: SimState) -> Tensor:
    """(N,) facing yaw of the root, rad."""
    return heading_angle(state.root_rot)


class MetricSums:
    """Named running sums and counts; :meth:`pop` returns the means and clears them."""

    def __init__(self) -> None:
        self._sum: dict[str, float] = {}
        self._count: dict[str, float] = {}

    def add(self, name: str, values: Tensor | float, count: float | None = None) -> None:
        """Add ``values`` (a tensor: summed, counted by its number of elements) or a float with ``count``."""
        if isinstance(values, Tensor):
            v = values.detach()
            total, n = float(v.double().sum()), float(v.numel())
        else:
            total, n = float(values), float(1 if count is None else count)
        if n == 0:
            return
        self._sum[name] = self._sum.get(name, 0.0) + total
        self._count[name] = self._count.get(name, 0.0) + n

    def pop(self, totals: Sequence[str] = ()) -> dict[str, float]:
        """Means of every name with data (sums for the names in ``totals``); then clear."""
        out = {k: (self._sum[k] if k in totals else self._sum[k] / self._count[k]) for k in self._sum if self._count[k] > 0}
        self._sum.clear()
        self._count.clear()
        return out


class TaskBase:
    """Mixin holding what every task shares: sizes, device, generator, fall termination, step counters."""

    max_reward: float = 1.0
    #: simulator params the task needs (strike: the target prop); set per instance
    sim_overrides: Mapping[str, Any]

    def _setup(
        self,
        fall: FallParams,
        skeleton: Skeleton,
        num_envs: int,
        device: Any,
        seed: int,
        start: StartParams | None = None,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.skeleton = skeleton
        self.sim_overrides = {}
        self.num_envs = int(num_envs)
        self.device = torch.device(device)
        self.fall = fall
        self._allowed = allowed_contact_mask(skeleton, fall.allowed_contacts, device=self.device)
        self.generator = torch.Generator(device="cpu")
        self.generator.manual_seed(int(seed))
        self.sim: Simulator | None = None
        self.dt = 1.0 / 30.0
        #: (N,) control steps since the env's last reset (advanced by :meth:`step`)
        self.progress = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        self._sums = MetricSums()
        self.start = start or StartParams()
        #: the clips the env draws start frames from (Task.start_clips; None: every clip)
        self.start_clips: Sequence[str] | None = tuple(self.start.clips) if self.start.clips else None

    def start_state(self, env_ids: Tensor, frames: MotionFrames) -> HumanoidState:
        """The sampled start frames turned to face +x and / or moved to the origin (:class:`StartParams`)."""
        s = self.start
        if not (s.face_x or s.origin):
            return frames
        yaw = -heading_angle(frames.root_rot) if s.face_x else torch.zeros(frames.root_pos.shape[0], dtype=frames.root_pos.dtype)
        target = torch.zeros_like(frames.root_pos) if s.origin else frames.root_pos
        return yaw_frames(frames, yaw, frames.root_pos, target)

    # -------------------------------------------------------------------------- sampling
    def _rand(self, *shape: int) -> Tensor:
        """U[0, 1) of ``shape`` from the task's generator (CPU, then moved: reproducible anywhere)."""
        return torch.rand(*shape, generator=self.generator, dtype=torch.float64).to(self.device)

    def _randint(self, low: int, high: int, n: int) -> Tensor:
        """Integers in ``[low, high)`` (``high`` exclusive, as ``torch.randint``; ``low`` when equal)."""
        if high <= low:
            return torch.full((n,), int(low), dtype=torch.long, device=self.device)
        return torch.randint(int(low), int(high), (n,), generator=self.generator).to(self.device)

    def _ids(self, env_ids: Tensor) -> Tensor:
        return torch.as_tensor(env_ids, dtype=torch.long).reshape(-1).to(self.device)

    # ----------------------------------------------------------------------------- resume
    def state_dict(self) -> dict[str, Any]:
        """Every per-env tensor of the task (goals, timers, counters) and its generator, so that a
        resumed task env continues bit-exactly (the metric sums are emptied every PPO iteration)."""
        tensors = {k: v.detach().clone() for k, v in vars(self).items() if isinstance(v, Tensor)}
        return {"tensors": tensors, "generator": self.generator.get_state().clone()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        own = {k: v for k, v in vars(self).items() if isinstance(v, Tensor)}
        saved = state["tensors"]
        if set(saved) <= set(own) and set(own) - set(saved) <= _ADDED_LATER:  # a run saved before they existed
            own = {k: v for k, v in own.items() if k in saved}
        if set(saved) != set(own):
            raise ValueError(f"task state of another task: tensors {sorted(saved)} vs {sorted(own)}")
        for key, value in saved.items():
            if tuple(value.shape) != tuple(own[key].shape):
                raise ValueError(f"task state {key!r}: shape {tuple(value.shape)} vs {tuple(own[key].shape)} (another num_envs?)")
            setattr(self, key, value.to(own[key].device, own[key].dtype).clone())
        self.generator.set_state(state["generator"].clone())

    # ------------------------------------------------------------------------ simulator
    def attach(self, sim: Simulator) -> None:
        """Keep the simulator (its control period ``dt``, ground-only contacts, props)."""
        self.sim = sim
        self.dt = float(sim.dt)

    def _ground_contact(self, state: SimState) -> Tensor:
        """(N, B) ground-only contacts: the simulator's ``ground_contact`` when attached and it has one."""
        gc = self.sim.ground_contact if self.sim is not None else None
        if isinstance(gc, Tensor) and gc.shape == state.body_contact.shape:
            return gc.to(state.body_contact.device)
        return state.body_contact

    def _fallen(self, state: SimState) -> Tensor:
        if not self.fall.early_termination:
            return torch.zeros(state.num_envs, dtype=torch.bool, device=state.root_pos.device)
        contact = self._ground_contact(state)
        if contact.numel() == 0:
            contact = torch.zeros(state.body_pos.shape[:2], dtype=torch.bool, device=state.root_pos.device)
        if self.fall.rule == "contact_and_low_body":  # the official code's rule (FallParams.rule)
            allowed = self._allowed.to(contact.device)
            low = (state.body_pos[..., 2] < self.fall.fall_height) & ~allowed
            return (contact & ~allowed).any(-1) & low.any(-1) & (self.progress.to(contact.device) > 1)
        return fallen(
            state,
            self._allowed.to(contact.device),
            self.fall.fall_height,
            contact=contact,
        )


def horizontal_unit(v: Tensor, eps: float = 1e-9) -> Tensor:
    """(N, 2) ``v[..., :2]`` normalised (zero where it is shorter than ``eps``)."""
    xy = v[..., :2]
    n = torch.linalg.vector_norm(xy, dim=-1, keepdim=True)
    return torch.where(n > eps, xy / n.clamp_min(eps), torch.zeros_like(xy))


def angle_between_2d(a: Tensor, b: Tensor) -> Tensor:
    """(N,) unsigned angle between 2-D vectors ``a`` and ``b``, rad in [0, pi]."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    dot = (a * b).sum(-1)
    return torch.atan2(cross, dot).abs()


#: per-env tensors added after runs were saved without them; a resumed run starts them afresh
_ADDED_LATER = frozenset({"min_distance"})


class GoalBookkeeping:
    """Per-goal metrics shared by the goal-reaching tasks (``reach``, ``point_goal``): how many goals
    ended, the share reached, the mean time to reach and the mean final distance.

    The task keeps ``goal_steps`` (steps since the goal was set) and ``reached_step`` (-1 until
    reached) up to date, reports each step's distances with :meth:`_track_distance`, calls
    :meth:`_new_goals` when it sets goals and :meth:`_finish_goals` when goals end.

    ``closest_distance``: the mean over finished goals of the smallest distance during the goal, m (a
    success rate at one radius hides a policy that closes from 5 m to 0.3 m; this does not)."""

    dt: float

    def _init_goals(self, num_envs: int, device: Any) -> None:
        self.goal_steps = torch.zeros(num_envs, dtype=torch.long, device=device)
        self.reached_step = torch.full((num_envs,), -1, dtype=torch.long, device=device)
        self.last_distance = torch.zeros(num_envs, dtype=torch.float64, device=device)
        self.min_distance = torch.full((num_envs,), math.inf, dtype=torch.float64, device=device)
        self._goal_stats = {"goals": 0.0, "reached": 0.0, "time": 0.0, "final": 0.0, "closest": 0.0}

    def _new_goals(self, ids: Tensor) -> None:
        """Goals ``ids`` were just set: their counters and closest distance start afresh."""
        self.goal_steps[ids] = 0
        self.reached_step[ids] = -1
        self.min_distance[ids] = math.inf

    def _track_distance(self, dist: Tensor) -> None:
        """This step's distance of every env to its goal."""
        d = dist.detach().to(self.last_distance)
        self.last_distance = d
        self.min_distance = torch.minimum(self.min_distance, d)

    def _finish_goals(self, ids: Tensor) -> None:
        ids = ids[self.goal_steps[ids] > 0]
        if ids.numel() == 0:
            return
        reached = self.reached_step[ids] >= 0
        g = self._goal_stats
        g["goals"] += float(ids.numel())
        g["reached"] += float(reached.sum())
        g["time"] += float(self.reached_step[ids][reached].double().sum()) * self.dt
        g["final"] += float(self.last_distance[ids].sum())
        g["closest"] += float(self.min_distance[ids].sum())

    def _pop_goal_metrics(self, out: dict[str, float]) -> dict[str, float]:
        """Add the goal metrics since the last call to ``out`` and reset them."""
        g = self._goal_stats
        if g["goals"] > 0:
            out["goals"] = g["goals"]
            out["success_rate"] = g["reached"] / g["goals"]
            out["final_distance"] = g["final"] / g["goals"]
            out["closest_distance"] = g["closest"] / g["goals"]
            if g["reached"] > 0:
                out["time_to_reach"] = g["time"] / g["reached"]
        self._goal_stats = {k: 0.0 for k in g}
        return out
