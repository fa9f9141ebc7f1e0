"""Tasks that follow a reference motion of the motion library through the latent space: ``vr_tracking``
(PULSE, head + both hands), ``hmd_tracking`` (Hybrid-RVQ, head only) and ``motion_tracking`` (the
full-body imitation goal of the imitator).

Episode (all three).

* **Start**: reference-state initialization. The task env (:class:`mocap.task_env.TaskEnv`) draws a
  (clip, time) with the library's weights, resets the humanoid to that reference frame and tells the
  task through ``reference_start(env_ids, clip_ids, times)``; the task then follows that clip from
  that time, one control step ``dt`` per step. Used outside the env (no ``reference_start`` before
  ``reset``), the task draws the (clip, time) itself from the library with its own generator.
* **Reference of a step**: with ``k`` = :attr:`progress` (steps since the reset, advanced by ``step``)
  the simulated state before the step is matched to the reference at ``t0 + k dt``; the goal
  observation holds the reference **one frame ahead**, ``t0 + (k + 1) dt`` (PHC/PULSE
  ``s^g-mimic``); the reward and the tracking termination compare the state the step produced with
  that same frame (computed in ``reward``, which the env calls before ``step`` and ``terminated``).
* **End**: *terminated* on tracking failure (per task, below), optionally on a fall
  (:class:`~mocap_tasks.common.FallParams`, off by default: imitation terminates on the tracking
  error only, and a reference may lie on the ground); *truncated* (``truncated(state)``) when a
  non-looping clip has no next frame left, besides the env's time limit :attr:`episode_steps`.

Metrics (means over the steps whose reward was computed since the last :meth:`metrics`, positions of
all bodies, through :mod:`mocap.metrics` on one-frame :class:`~mocap.state.Trajectories`):

* ``mpjpe_g`` / ``mpjpe_l``: full-body global / root-relative mean per-joint position error, mm
  (:func:`mocap.metrics.mpjpe_global`, :func:`~mocap.metrics.mpjpe_local`), averaged over frames as
  PULSE's ``compute_metrics_lite`` does;
* ``tracked_error`` (vr, hmd): mean position error of the tracked points, mm (PULSE's ``E_g-mhpe``
  on the 3 points; the head error for HMD);
* ``success``: fraction of the episodes that ended since the last call in which the humanoid
  *completed* the episode (no termination) **and** the mean error of the success bodies never
  exceeded ``success_threshold`` (0.5 m; :func:`mocap.metrics.success` per frame). Success bodies:
  the 3 tracked points for VR ([P] PULSE Sec. 5 "Metrics": "the success rate is measured against
  only the three body points"), the head for HMD, all bodies for motion tracking (PHC/PULSE).
  Completion matters when the termination is stricter than the success criterion (the code's 0.25 m
  any-body rule);
* ``episodes`` (a sum), ``reward`` (mean), ``steps`` (a sum).

Normalized return: every reward is a weighted sum of kernels in (0, 1], so :attr:`max_reward` is
the sum of the weights (1 with the defaults), reached exactly when the humanoid matches the
reference frame.

``vr_tracking`` (PULSE Sec. 5.2 / App. C.4 "VR Controller Tracking", after QuestSim):

* goal ``s^g-vr`` = the imitation goal of :func:`mocap.observations.imitation_goal` restricted to
  the head and both hands: ``(theta^_{t+1} - theta_t, p^_{t+1} - p_t, v^_{t+1} - v_t,
  w^ - w_t, theta^_{t+1}, p^_{t+1})`` per point in the heading frame ([CODE] 3 x 24 = 72 dims;
  ``goal: keypoint`` gives positions and velocities only, 3 x 9 = 27);
* reward: "the same (full-body) imitation reward" (PULSE App. C.4; App. B.2, Eq. 5's
  ``r^g-imitation``): ``sum_i w_i exp(-k_i e_i)`` over position, rotation, linear and angular
  velocity, weights (0.5, 0.3, 0.1, 0.1), scales (100, 10, 0.1, 0.1); switch ``reward_form``:
  [P] ``e`` a norm (mean over bodies of the per-body norm / angle) or [CODE] the mean of squared
  components (squared angle); ``reward_bodies: tracked`` scores the 3 points only (not PULSE). The
  AMP and energy terms of PHC+ are not part of the task reward;
* termination: [CODE] any of the 3 points farther than 0.25 m from its reference (after the first
  step); [P] defines no training termination, ``termination: paper`` uses its success criterion
  (mean of the 3 point errors > 0.5 m);
* episode 300 steps (10 s, [CODE]).

``hmd_tracking`` (Hybrid-RVQ Sec. 6.3.2 / App. C.2):

* goal: the head part of the target ``s~`` (Eq. 9), **current minus reference** as printed, for the
  reference frames ``t + 1 .. t + frames`` ([P] the next target and 4 more, ``frames`` = 5), each
  ``[h^-1 (p_h - p~_h) (3) | h^-1 (v_h - v~_h) (3) | q(h^-1 (theta_h theta~_h^-1) h) (4, w >= 0)
  | h^-1 (w_h - w~_h) (3)]`` = 13 dims, 65 in all; all against the current simulated head and in
  the heading frame ([DEFAULT], our choice: the paper states neither);
* reward: [P] "a similar reward structure used for motion in-betweening", "only the head part"
  (App. C.2, no formula); [DEFAULT], our choice:
  ``0.4 exp(-40 |dp|^2) + 0.3 exp(-2 angle^2) + 0.15 exp(-0.5 |dv|^2) + 0.15 exp(-0.1 |dw|^2)``
  with Eq. 10's kernels; weights and scales are parameters;
* termination: [P] head farther than 1 m from the reference head;
* episode 150 steps (5 s, [P]).

``motion_tracking`` (full-body imitation through the latent space; PHC Sec. 3.1, PULSE Sec. 4.1):

* goal: the imitator's imitation goal :func:`mocap.observations.imitation_goal` (``goal: rot``
  24 B dims or ``keypoint`` 9 B) of all bodies at ``t + 1``;
* reward: the PHC imitation reward over all bodies (``reward_form`` as for VR);
* termination: ``paper`` (PHC Relaxed Early Termination: mean distance of the checked bodies, all but
  the feet, > 0.5 m) or ``code`` (any checked body > 0.25 m after the first step);
* episode 300 steps (10 s).

Code layout: the parameter models live in :mod:`mocap_tasks.tracking_params`, the pure reward, goal and
termination functions in :mod:`mocap_tasks.tracking_functions`; both are re-exported here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import torch
from mocap.interfaces import Task
from mocap.metrics import mpjpe_global, mpjpe_local, success
from mocap.observations import imitation_goal, imitation_goal_dim
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, SimState, Trajectories
from mocap.imitation_rewards import imitation_errors
from mocap_tasks.common import TaskBase, resolve_body
from mocap_tasks.tracking_functions import (
    _like,
    head_goal,
    head_reward,
    imitation_reward,
    select_bodies,
    tracking_failed,
)
from mocap_tasks.tracking_params import HmdTrackingParams, MotionTrackingParams, VrTrackingParams
from torch import Tensor

__all__ = [
    "HEAD_NAMES",
    "LEFT_HAND_NAMES",
    "RIGHT_HAND_NAMES",
    "HmdTrackingParams",
    "HmdTrackingTask",
    "MotionTrackingParams",
    "MotionTrackingTask",
    "VrTrackingParams",
    "VrTrackingTask",
    "head_goal",
    "head_reward",
    "imitation_errors",
    "imitation_reward",
    "make_hmd_tracking",
    "make_motion_tracking",
    "make_vr_tracking",
    "select_bodies",
    "tracking_failed",
]

#: body names of the built-in skeletons (``amp``, ``smpl``), tried in order
HEAD_NAMES: tuple[str, ...] = ("head", "Head")
LEFT_HAND_NAMES: tuple[str, ...] = ("left_hand", "L_Hand")
RIGHT_HAND_NAMES: tuple[str, ...] = ("right_hand", "R_Hand")


# ------------------------------------------------------------------------------------ tasks
class TrackingTask(TaskBase, Task):
    """Reference bookkeeping, starts, truncation, termination and metrics shared by the three tasks."""

    tracks_reference = True  # the env calls reference_start and starts episodes on the control grid
    goal_dim: int
    #: body indices whose mean error decides ``success``
    success_bodies: Tensor
    #: body indices of ``tracked_error`` (None: not reported)
    tracked_bodies: Tensor | None = None

    def _setup_tracking(self, params: Any, skeleton: Skeleton, num_envs: int, device: Any, seed: int | None, motions: Any) -> None:
        self.params = params
        self._setup(params.fall, skeleton, num_envs, device, params.seed if seed is None else seed)
        if motions is None:
            raise ValueError(f"task {type(self).__name__} follows a reference motion: build it with motions=<MotionLibrary> (the task stage's env does)")
        from mocap.motion.library import MotionLibrary
        from mocap.motion.sources import MotionSet

        if isinstance(motions, (MotionSet, list, tuple)):  # clips, not yet a library: indexed here
            motions = MotionLibrary(motions, skeleton)
        self.library = motions
        self.episode_steps = int(params.episode_steps)
        N, dev = self.num_envs, self.device
        self.clip_ids = torch.zeros(N, dtype=torch.long, device=dev)
        self.start_time = torch.zeros(N, dtype=torch.float64, device=dev)
        self._pending = torch.zeros(N, dtype=torch.bool, device=dev)
        #: (N,) the episode has not yet exceeded the success threshold
        self.ok = torch.ones(N, dtype=torch.bool, device=dev)
        #: (N,) the tracking failed at the last reward (decides :meth:`terminated`)
        self.too_far = torch.zeros(N, dtype=torch.bool, device=dev)
        #: (N,) the last :meth:`terminated` result
        self.failed = torch.zeros(N, dtype=torch.bool, device=dev)
        self._loops = self.library.loops.to(dev)
        self._durations = self.library.durations.to(dev, torch.float64)

    # ---------------------------------------------------------------------------- reference
    def reference_start(self, env_ids: Tensor, clip_ids: Tensor, times: Tensor) -> None:
        """The env reset ``env_ids`` to clip ``clip_ids`` at ``times`` s: follow it from there."""
        ids = self._ids(env_ids)
        self.clip_ids[ids] = torch.as_tensor(clip_ids).to(self.device, torch.long).reshape(-1)
        self.start_time[ids] = torch.as_tensor(times).to(self.device, torch.float64).reshape(-1)
        self._pending[ids] = True

    def reference_times(self, offset: int = 0) -> Tensor:
        """(N,) reference time ``t0 + (progress + offset) dt`` of every env, s."""
        return self.start_time + (self.progress + offset).to(torch.float64) * self.dt

    def reference(self, offset: int = 0, ids: Tensor | None = None) -> HumanoidState:
        """The reference frames at ``t0 + (progress + offset) dt`` (of envs ``ids``; all when None)."""
        t = self.reference_times(offset)
        c = self.clip_ids
        if ids is not None:
            t, c = t[ids], c[ids]
        return self.library.frames(c, t)

    def _ref(self, offset: int, state: HumanoidState) -> HumanoidState:
        """The reference at ``offset`` in ``state``'s dtype; the frames of the last (clips, times) asked
        for are reused (``observe``'s goal frame is the next ``reward``'s frame)."""
        return _like(self._cached_frames(self.clip_ids, self.reference_times(offset)), state)

    def _cached_frames(self, clips: Tensor, times: Tensor) -> HumanoidState:
        key = getattr(self, "_cache_key", None)
        if key is not None and torch.equal(key[0], clips) and torch.equal(key[1], times):
            return self._cache_frames
        frames = self.library.frames(clips, times)
        self._remember(clips, times, frames)
        return frames

    def _remember(self, clips: Tensor, times: Tensor, frames: HumanoidState) -> None:
        self._cache_key = (clips.clone(), times.clone())
        self._cache_frames = frames

    def reset(self, env_ids: Tensor, state: SimState) -> None:
        ids = self._ids(env_ids)
        if ids.numel() == 0:
            return
        ended = ids[self.progress[ids] > 0]
        if ended.numel():
            self._sums.add("success", (self.ok[ended] & ~self.failed[ended]).double())
            self._sums.add("episodes", float(ended.numel()), count=1)
        own = ids[~self._pending[ids]]
        if own.numel():  # not started by the env: draw the reference start here
            c, t = self.library.sample(int(own.numel()), generator=self.generator)
            self.clip_ids[own] = c.to(self.device)
            self.start_time[own] = t.to(self.device, torch.float64)
        self._pending[ids] = False
        self.progress[ids] = 0
        self.ok[ids] = True
        self.too_far[ids] = False
        self.failed[ids] = False

    def step(self, state: SimState) -> None:
        """Advance the reference by one control step (the env calls it after the reward)."""
        self.progress += 1

    def truncated(self, state: SimState) -> Tensor:
        """(N,) a non-looping clip has reached its last frame: no next reference frame."""
        end = self.reference_times(0) >= self._durations[self.clip_ids] - 1e-6
        return end & ~self._loops[self.clip_ids]

    def terminated(self, state: SimState) -> Tensor:
        out = self.too_far | self._fallen(state).to(self.device)
        self.failed = out.clone()
        return out

    # ------------------------------------------------------------------------------ metrics
    def _frame_metrics(self, state: HumanoidState, ref: HumanoidState, reward: Tensor) -> None:
        """Per-step metrics of the state against its reference frame (module doc)."""
        fps = 1.0 / self.dt
        p, rp = state.body_pos.detach(), ref.body_pos.detach()
        full = Trajectories(sim=p[None], ref=rp[None], fps=fps)
        sb = self.success_bodies.to(p.device)
        pts = Trajectories(sim=p[None][:, :, sb], ref=rp[None][:, :, sb], fps=fps)
        frame_ok = success(pts, threshold=self.params.success_threshold).bool().to(self.device)
        unstable = getattr(state, "unstable", None)
        if isinstance(unstable, Tensor) and unstable.shape == frame_ok.shape:  # the env ends these: not a success
            frame_ok &= ~unstable.to(self.device)
        self.ok &= frame_ok
        s = self._sums
        s.add("mpjpe_g", mpjpe_global(full))
        s.add("mpjpe_l", mpjpe_local(full))
        if self.tracked_bodies is not None:
            tb = self.tracked_bodies.to(p.device)
            s.add("tracked_error", mpjpe_global(Trajectories(sim=p[None][:, :, tb], ref=rp[None][:, :, tb], fps=fps)))
        s.add("reward", reward.detach())
        s.add("steps", float(reward.numel()), count=1)

    def metrics(self) -> dict[str, float]:
        return self._sums.pop(totals=("steps", "episodes"))

    # ----------------------------------------------------------------------------- resume
    def state_dict(self) -> dict[str, Any]:
        return {
            "clip_ids": self.clip_ids.clone(),
            "start_time": self.start_time.clone(),
            "progress": self.progress.clone(),
            "pending": self._pending.clone(),
            "ok": self.ok.clone(),
            "too_far": self.too_far.clone(),
            "failed": self.failed.clone(),
            "generator": self.generator.get_state().clone(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        dev = self.device
        self.clip_ids = state["clip_ids"].to(dev).clone()
        self.start_time = state["start_time"].to(dev).clone()
        self.progress = state["progress"].to(dev).clone()
        self._pending = state["pending"].to(dev).clone()
        self.ok = state["ok"].to(dev).clone()
        self.too_far = state["too_far"].to(dev).clone()
        self.failed = state["failed"].to(dev).clone()
        self.generator.set_state(state["generator"].clone())


def _resolve_many(skeleton: Skeleton, names: Sequence[str] | None, defaults: Sequence[Sequence[str]]) -> Tensor:
    if names is None:
        idx = [resolve_body(skeleton, None, cands) for cands in defaults]
    else:
        idx = [resolve_body(skeleton, n) for n in names]
    return torch.tensor(idx, dtype=torch.long)


class VrTrackingTask(TrackingTask):
    """``vr_tracking`` (module docstring)."""

    def __init__(
        self,
        params: VrTrackingParams,
        *,
        skeleton: Skeleton,
        num_envs: int,
        device: Any = "cpu",
        seed: int | None = None,
        motions: Any = None,
    ):
        self._setup_tracking(params, skeleton, num_envs, device, seed, motions)
        self.points = _resolve_many(skeleton, params.bodies, (HEAD_NAMES, LEFT_HAND_NAMES, RIGHT_HAND_NAMES))
        self.success_bodies = self.points
        self.tracked_bodies = self.points
        self.goal_dim = imitation_goal_dim(len(self.points), params.goal)
        self.max_reward = float(sum(params.reward_weights))
        rule = params.termination
        self._rule: Literal["mean", "any"] = "any" if rule == "code" else "mean"
        self._threshold = params.termination_threshold or (0.25 if rule == "code" else 0.5)
        self._grace = 1 if rule == "code" else 0

    def observe(self, state: SimState) -> Tensor:
        ref = self._ref(1, state)
        pts = self.points.to(state.body_pos.device)
        return imitation_goal(select_bodies(state, pts), select_bodies(ref, pts), self.params.goal, self.params.sixd)

    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        ref = self._ref(1, state)
        pts = self.points.to(state.body_pos.device)
        if p.reward_bodies == "tracked":
            r, _ = imitation_reward(select_bodies(state, pts), select_bodies(ref, pts), p.reward_form, p.reward_weights, p.reward_scales)
        else:
            r, _ = imitation_reward(state, ref, p.reward_form, p.reward_weights, p.reward_scales)
        dist = torch.linalg.vector_norm(state.body_pos[:, pts] - ref.body_pos[:, pts], dim=-1)
        self.too_far = tracking_failed(dist, self._rule, self._threshold, self.progress + 1, self._grace).to(self.device)
        self._frame_metrics(state, ref, r)
        return r


class HmdTrackingTask(TrackingTask):
    """``hmd_tracking`` (module docstring)."""

    def __init__(
        self,
        params: HmdTrackingParams,
        *,
        skeleton: Skeleton,
        num_envs: int,
        device: Any = "cpu",
        seed: int | None = None,
        motions: Any = None,
    ):
        self._setup_tracking(params, skeleton, num_envs, device, seed, motions)
        self.head = resolve_body(skeleton, params.head, HEAD_NAMES)
        self.success_bodies = torch.tensor([self.head])
        self.tracked_bodies = self.success_bodies
        self.goal_dim = 13 * params.frames
        self.max_reward = float(sum(params.reward_weights))

    def observe(self, state: SimState) -> Tensor:
        F, N = self.params.frames, self.num_envs
        t = torch.cat([self.reference_times(k) for k in range(1, F + 1)])
        frames = _like(self.library.frames(self.clip_ids.repeat(F), t), state)
        refs = [HumanoidState(**{k: v[i * N : (i + 1) * N] for k, v in vars(frames).items()}) for i in range(F)]
        self._remember(self.clip_ids, t[:N], refs[0])  # the next reward's frame
        return head_goal(state, refs, self.head)

    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        ref = self._ref(1, state)
        r, _ = head_reward(state, ref, self.head, p.reward_weights, p.reward_scales)
        dist = torch.linalg.vector_norm(state.body_pos[:, self.head] - ref.body_pos[:, self.head], dim=-1)[:, None]
        self.too_far = tracking_failed(dist, "any", p.termination_threshold).to(self.device)
        self._frame_metrics(state, ref, r)
        return r


class MotionTrackingTask(TrackingTask):
    """``motion_tracking`` (module docstring)."""

    def __init__(
        self,
        params: MotionTrackingParams,
        *,
        skeleton: Skeleton,
        num_envs: int,
        device: Any = "cpu",
        seed: int | None = None,
        motions: Any = None,
    ):
        self._setup_tracking(params, skeleton, num_envs, device, seed, motions)
        self.success_bodies = torch.arange(skeleton.num_bodies)
        exclude = skeleton.feet if params.termination_exclude is None else params.termination_exclude
        drop = {resolve_body(skeleton, n) for n in exclude}
        self.checked = torch.tensor([i for i in range(skeleton.num_bodies) if i not in drop], dtype=torch.long)
        if self.checked.numel() == 0:
            raise ValueError("termination_exclude excludes every body")
        self.goal_dim = imitation_goal_dim(skeleton.num_bodies, params.goal)
        self.max_reward = float(sum(params.reward_weights))
        rule = params.termination
        self._rule: Literal["mean", "any"] = "any" if rule == "code" else "mean"
        self._threshold = params.termination_threshold or (0.25 if rule == "code" else 0.5)
        self._grace = 1 if rule == "code" else 0

    def observe(self, state: SimState) -> Tensor:
        return imitation_goal(state, self._ref(1, state), self.params.goal, self.params.sixd)

    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        ref = self._ref(1, state)
        r, _ = imitation_reward(state, ref, p.reward_form, p.reward_weights, p.reward_scales)
        ch = self.checked.to(state.body_pos.device)
        dist = torch.linalg.vector_norm(state.body_pos[:, ch] - ref.body_pos[:, ch], dim=-1)
        self.too_far = tracking_failed(dist, self._rule, self._threshold, self.progress + 1, self._grace).to(self.device)
        self._frame_metrics(state, ref, r)
        return r


# -------------------------------------------------------------------------------- factories
def make_vr_tracking(
    params: VrTrackingParams,
    *,
    skeleton: Skeleton,
    num_envs: int,
    device: Any = "cpu",
    seed: int | None = None,
    motions: Any = None,
    **_: Any,
) -> VrTrackingTask:
    """Registry factory of ``vr_tracking`` (needs ``motions``: the motion library)."""
    return VrTrackingTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed, motions=motions)


def make_hmd_tracking(
    params: HmdTrackingParams,
    *,
    skeleton: Skeleton,
    num_envs: int,
    device: Any = "cpu",
    seed: int | None = None,
    motions: Any = None,
    **_: Any,
) -> HmdTrackingTask:
    """Registry factory of ``hmd_tracking`` (needs ``motions``: the motion library)."""
    return HmdTrackingTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed, motions=motions)


def make_motion_tracking(
    params: MotionTrackingParams,
    *,
    skeleton: Skeleton,
    num_envs: int,
    device: Any = "cpu",
    seed: int | None = None,
    motions: Any = None,
    **_: Any,
) -> MotionTrackingTask:
    """Registry factory of ``motion_tracking`` (needs ``motions``: the motion library)."""
    return MotionTrackingTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed, motions=motions)
