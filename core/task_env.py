"""Hierarchical control: a task policy acting in the task action space of any latent space.

The ``task`` stage of a spec (``task: {name: speed, params: ..., trainer: {name: ppo, ...}}``)
trains a policy with PPO on a :class:`TaskEnv`:

* **observation** = ``[s^p | g]``: the humanoid's proprioception (:func:`mocap.observations.proprioception`,
  heading frame) and the task's goal observation ``task.observe(state)``;
* **action** ``a`` in ``latent.task_action_space`` (PULSE: a continuous residual; Hybrid-RVQ: code
  indices; ``scratch``: normalized PD targets). The frozen latent space maps it:
  ``z = latent.to_latent(obs, a)``, ``out = latent.decoder(obs, z)``, and ``out`` becomes PD targets
  (identity for a decoder distilled with ``label: pd_targets`` and for ``scratch``; otherwise the
  imitator's ``to_pd_targets``, which must not need a reference motion);
* **reward / termination** on the shared episode layer (:mod:`mocap.episodes`): the reward is the
  one term ``task`` (``task.reward``) of :class:`~mocap.episodes.RewardTerms`, so it is **0 on a
  numerically unstable step** (or where the task's reward is not finite; before the episode layer
  the task's reward was passed on as it was); termination is the
  :class:`~mocap.episodes.TerminationTerms` ``task`` (``task.terminated``) OR ``unstable``;
  **truncation** after ``task.episode_steps`` (default 300 = 10 s);
* **starts**: reference states of the motion library (clip and time drawn with its weights) in
  which every non-foot body is above 0.25 m (standing or moving, not lying), then ``task.reset``;
* **logged**: per step ``reward/task`` (the task's reward before the instability rule),
  ``terminated/task`` and ``terminated/unstable``; per finished episode (the layer's
  :class:`~mocap.episodes.EpisodeBook`) return, length, success and **normalized return** = return /
  (``task.max_reward`` × ``episode_steps``) (PULSE Fig. 4); the task's own metrics every iteration
  (``task.metrics()``). Returns are summed in float64 (float32 before the episode layer: the logged
  return statistics may differ from earlier runs in the last bits).

Tasks never see which latent space drives the humanoid; latent spaces never see the task. What
the env reads from a task beyond the four abstract methods is declared, with defaults, on
:class:`mocap.interfaces.Task`: ``episode_steps``, ``max_reward``, ``sim_overrides`` (simulator
params the task needs, e.g. the strike target), ``attach(sim)``, ``attach_motions(library)``,
``start_state(env_ids, frames)`` (may replace the start frames: terrain's spawn square, inbetween's
keyframe sequence; a :class:`~mocap.state.MotionFrames` result also names clip and time),
``step(state)`` (after each reward), ``truncated(state)`` (OR-ed with the time limit),
``state_dict()`` / ``load_state_dict()``, ``prior_rollout`` / ``prior_noise_scale`` (the task action
is ignored and ``latent.random_action`` is rolled out; a latent without ``samples_prior`` is
refused), and for tasks that follow a reference motion (``tracks_reference``: ``vr_tracking``,
``hmd_tracking``, ``motion_tracking``) ``reference_start(env_ids, clip_ids, times)``, called on
every reset before ``task.reset``. A task factory that names a ``motions`` parameter (or takes
``**kwargs``) receives the env's :class:`~mocap.motion.library.MotionLibrary`. From the latent
space the env uses :meth:`~mocap.interfaces.LatentSpace.decode_action`, ``reset_envs`` and
``task_state_dict`` (declared there with defaults).

``scratch`` (registered by :mod:`mocap.hierarchy`, its params there) is the no-latent baseline: a latent space whose task action is the
PD target itself, ``q = offset + scale · a`` with ``a`` in [-1, 1] mapped to each joint's range (a hinge that may
wind more than one turn, e.g. amp's shoulders with ``shoulder_turns`` > 0.5: to [-pi, pi])
(PHC's absolute action mapping), so that "task policy from scratch" runs through the same code.
"""

from __future__ import annotations

import inspect
import math
from typing import Any, Callable

import torch
from torch import Tensor

from mocap.episodes import EpisodeBook, ReferenceStarts, RewardTerms, TerminationTerms
from mocap.hierarchy import ScratchParams
from mocap.interfaces import Box, LatentSample, LatentSpace, MultiDiscrete, Simulator, Task
from mocap.motion.library import MotionLibrary, grid_start_times
from mocap.observations import SixD, proprioception
from mocap.rl.env import StepResult
from mocap.sim_snapshot import load_sim_state, save_sim_state
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, MotionFrames, Observations, SimState

STATE_FORMAT = "mocap.task_env/1"


# ---------------------------------------------------------------------------------- scratch
class ScratchLatent(LatentSpace):
    """No latent space: the task action is the normalized PD target (module docstring)."""

    has_encoder = False  # nothing to encode: the framework never calls encoder()

    offset: Tensor  # buffers (register_buffer in __init__)
    scale: Tensor

    def __init__(self, params: ScratchParams, skeleton: Skeleton):
        super().__init__()
        lo_t = torch.tensor([float(h.range[0]) for h in skeleton.hinges])
        hi_t = torch.tensor([float(h.range[1]) for h in skeleton.hinges])
        # a hinge that may wind more than a turn (amp's shoulder_turns) is mapped over one turn about 0
        wide = torch.tensor([float(h.range[1]) - float(h.range[0]) > 2 * math.pi + 1e-9 for h in skeleton.hinges])
        self.register_buffer("offset", torch.where(wide, 0.0, 0.5 * (lo_t + hi_t)))
        self.register_buffer("scale", torch.where(wide, math.pi, 0.5 * (hi_t - lo_t)) * params.range_scale)
        self.latent_dim = skeleton.num_dofs

    def encoder(self, obs: Observations) -> LatentSample:
        raise NotImplementedError("scratch has no encoder: it is the no-latent baseline")

    def prior(self, obs: Observations) -> LatentSample:
        zero = torch.zeros(obs.proprio.shape[0], self.latent_dim, device=obs.proprio.device)
        return LatentSample(mean=zero, std=None, z=zero)

    def decoder(self, obs: Observations, z: Tensor) -> Tensor:
        return self.offset + self.scale * z

    @property
    def task_action_space(self) -> Box:
        return Box((self.latent_dim,), low=-1.0, high=1.0)

    def to_latent(self, obs: Observations, task_action: Tensor) -> Tensor:
        return task_action.float().clamp(-1.0, 1.0)


def make_scratch(params: ScratchParams, *, skeleton: Skeleton, checkpoint: Any = None, device: Any = "cpu") -> ScratchLatent:
    return ScratchLatent(params, skeleton).to(device)


# ------------------------------------------------------------------------------------- env
def stateless_task_warning(task: Task) -> str | None:
    """The warning a resume gives for a task that keeps the default :meth:`Task.state_dict` (it
    saves nothing): its goals, timers and generators restart, so the resumed stage diverges from an
    uninterrupted one. None for a task that defines its own state."""
    if type(task).state_dict is not Task.state_dict:
        return None
    name = type(task).__name__
    return (
        f"warning: resuming task {name}, which defines no state_dict(): its per-env goals, timers and generators restart now, "
        f"so this run will differ from an uninterrupted one. Add {name}.state_dict() returning them and load_state_dict() "
        "restoring them (docs/plugins.md, 'What the framework calls, and when'; mocap.testing.check_task checks the round trip)"
    )


class TaskEnv:
    """A batched downstream task driven through a frozen latent space (module docstring)."""

    def __init__(
        self,
        task: Task,
        latent: LatentSpace,
        to_pd_targets: Callable[[Observations, Tensor], Tensor],
        library: MotionLibrary,
        sim: Simulator,
        *,
        seed: int = 0,
        sixd: SixD = "zhou",
        start_min_height: float = 0.25,
        warn: Callable[[str], None] | None = None,
    ):
        """``warn``: where a resume's warnings go (the stage's console; default: Python's warnings)."""
        self.task, self.latent, self.map_targets = task, latent, to_pd_targets
        self._warn = warn
        self.library, self.sim = library, sim
        self.num_envs = int(sim.num_envs)
        self.skeleton = sim.skeleton
        self.sixd = sixd
        self.start_min_height = float(start_min_height)
        self.episode_steps = int(task.episode_steps)
        self.max_reward = float(task.max_reward)
        self.action_space = latent.task_action_space
        self.proprio_dim = 15 * self.skeleton.num_bodies - 2
        self.obs_dim = self.proprio_dim + int(task.goal_dim)
        self._gen = torch.Generator().manual_seed(int(seed))
        self.book = EpisodeBook(self.num_envs)  # per-env steps and return of the current episode
        self.reward_terms = RewardTerms({"task": 1.0})
        self.termination_terms = TerminationTerms(("task", "unstable"))
        self._obs: Tensor | None = None
        latent.eval()
        # the decoder's raw output (PULSE: decode_action; its `decoder` maps through an attached imitator)
        self._decode = latent.decode_action
        #: the generation task: the task action is ignored, the latent prior is rolled out
        self.prior_rollout = bool(task.prior_rollout)
        self.prior_noise_scale = float(task.prior_noise_scale)
        self._prior_gen = torch.Generator().manual_seed(int(seed) + 1)
        if self.prior_rollout and not latent.samples_prior:
            raise ValueError(
                f"task {type(task).__name__} rolls out the latent space's prior, and {type(latent).__name__} has none "
                "(no random_action): `scratch` is the no-latent baseline, there is no prior to sample; use a trained "
                "latent space (pulse, hybrid_rvq)"
            )
        task.attach(sim)
        task.attach_motions(library)
        # a task that follows the clip it started from reads the reference every step: start it on
        # the control grid and read the reference from the precomputed table (MotionLibrary.use_control_grid)
        self._tracks_reference = bool(task.tracks_reference)
        self._starts: ReferenceStarts | None = None
        if self._tracks_reference:
            library.use_control_grid(float(sim.dt), self.episode_steps + 2)
            self._starts = ReferenceStarts(library, float(sim.dt), control_grid=True)

    # ------------------------------------------------------------------------------- helpers
    def _proprio(self, state: SimState) -> Observations:
        return Observations(proprio=proprioception(state, self.sixd).float(), goal=None, extra={})

    def _observe(self, state: SimState) -> Tensor:
        return torch.cat([proprioception(state, self.sixd).float(), self.task.observe(state).float()], -1)

    def _reset_envs(self, ids: Tensor) -> None:
        from mocap.generation_eval import start_states

        clips = list(self.task.start_clips) if self.task.start_clips is not None else None
        clip_ids, times = start_states(self.library, len(ids), self.skeleton, self.start_min_height, self._gen, clips)
        if self._starts is not None:  # the task's own start frames (standing), moved onto the control grid
            st = self._starts
            times = grid_start_times(times.to(torch.float64), st.durations[clip_ids], st.loops[clip_ids], st.dt)
        sampled = self.library.frames(clip_ids, times)
        frames: HumanoidState = self.task.start_state(ids, sampled)  # terrain spawn square, keyframe-sequence start
        if isinstance(frames, MotionFrames):
            clip_ids, times = frames.clip_ids, frames.times
        self.sim.reset(ids, frames)
        self.latent.reset_envs(ids)  # latents with per-env state (VMP: the tracker's action history)
        self.book.start(ids)
        if self._tracks_reference:  # tasks that track the reference they were started from
            self.task.reference_start(ids, clip_ids, times)
        self.task.reset(ids, self.sim.state)

    # ---------------------------------------------------------------------------------- VecEnv
    def reset(self) -> Tensor:
        self._reset_envs(torch.arange(self.num_envs))
        self._obs = self._observe(self.sim.state)
        return self._obs.clone()

    @torch.no_grad()
    def pd_targets(self, state: SimState, actions: Tensor) -> Tensor:
        """PD targets of task actions ``actions`` in ``state`` through the frozen latent space."""
        obs = self._proprio(state)
        if self.prior_rollout:
            raw = self.latent.random_action(obs, noise_scale=self.prior_noise_scale, generator=self._prior_gen)
        else:
            z = self.latent.to_latent(obs, actions)
            raw = self._decode(obs, z)
        return self.map_targets(obs, raw)

    def step(self, actions: Tensor) -> StepResult:
        state = self.sim.state
        targets = self.pd_targets(state, actions)
        state = self.sim.step(targets)
        task_reward = self.task.reward(state, actions).float().cpu()
        self.task.step(state)
        self.book.tick()
        unstable = state.unstable.cpu().bool() if state.unstable.numel() else torch.zeros(self.num_envs, dtype=torch.bool)
        reward, info = self.reward_terms({"task": task_reward}, unstable)  # 0 where unstable
        terminated, term_info = self.termination_terms({"task": self.task.terminated(state).cpu(), "unstable": unstable})
        info.update(term_info)
        truncated = self.book.steps >= self.episode_steps
        task_truncated = self.task.truncated(state)
        if task_truncated is not None:  # e.g. the tracked clip ran out
            truncated = truncated | task_truncated.cpu().bool()
        res = self.book.conclude(
            reward, terminated, truncated, self._observe_envs, self._reset_envs, info=info, on_finish=self._normalized_return, count_step=False
        )
        self._obs = res.obs
        return res

    def _observe_envs(self, ids: Tensor | None) -> Tensor:
        """The observation of every env (``ids`` None) or of envs ``ids`` (after their reset)."""
        obs = self._observe(self.sim.state)
        return obs if ids is None else obs[ids]

    def _normalized_return(self, ids: Tensor, terminated: Tensor) -> dict[str, Tensor]:
        return {"normalized_return": (self.book.returns[ids] / (self.max_reward * self.episode_steps)).float()}

    def after_iteration(self, iteration: int, policy_fn: Any) -> dict[str, float]:
        """The task's metrics accumulated over the iteration (logged under ``eval/``)."""
        return {k: float(v) for k, v in self.task.metrics().items()}

    def state_dict(self) -> dict[str, Any]:
        sd: dict[str, Any] = {
            "format": STATE_FORMAT,
            "num_envs": self.num_envs,
            "generator": self._gen.get_state().clone(),
            "steps": self.book.steps.clone(),
            "ep_return": self.book.returns.clone(),  # float64 (float32 before the episode layer: both load)
            "prior_generator": self._prior_gen.get_state().clone(),
        }
        sd.update(save_sim_state(self.sim))
        sd["task"] = self.task.state_dict()
        sd["latent"] = self.latent.task_state_dict()
        return sd

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a TaskEnv state (format {state.get('format')!r})")
        if int(state["num_envs"]) != self.num_envs:
            raise ValueError(f"state has {state['num_envs']} envs, this env {self.num_envs}")
        self._gen.set_state(state["generator"].clone())
        self.book.load_state_dict({"steps": state["steps"], "returns": state["ep_return"]})
        if "prior_generator" in state:
            self._prior_gen.set_state(state["prior_generator"].clone())
        load_sim_state(self.sim, torch.arange(self.num_envs), state)
        message = stateless_task_warning(self.task)
        if message is not None:
            if self._warn is not None:
                self._warn(message)
            else:
                import warnings

                warnings.warn(message, RuntimeWarning, stacklevel=2)
        if "task" in state:
            self.task.load_state_dict(state["task"])
        if "latent" in state:
            self.latent.load_task_state_dict(state["latent"])
        self._obs = self._observe(self.sim.state)

    def close(self) -> None:
        self.sim.close()


def _accepts(factory: Callable[..., Any], name: str) -> bool:
    """``factory`` has a parameter ``name`` or takes ``**kwargs``."""
    try:
        params = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):  # no signature (a builtin): do not pass extras
        return False
    return any(p.name == name or p.kind is inspect.Parameter.VAR_KEYWORD for p in params)


def make_task_env(ctx: Any, num_envs: int) -> TaskEnv:
    """The ``task`` stage's RL env (called by ``StageContext.make_rl_env``): the spec's task, its
    latent space (trained upstream, or untrained such as ``scratch``) and the simulator with the
    task's ``sim_overrides``."""
    from mocap.pipeline import StageFailed

    spec = ctx.spec
    if spec.latent is None:
        raise StageFailed("the task stage needs a latent space (use `latent: {name: scratch}` for a policy without one)")
    skeleton = ctx.skeleton
    task_ref = spec.task
    motion_set = ctx.build("motions").load(skeleton)
    library = MotionLibrary(motion_set, skeleton)
    component = ctx.plugins.get("task", task_ref.name)
    extra: dict[str, Any] = {"motions": library} if _accepts(component.resolved_factory(), "motions") else {}
    task = component.build(ctx.params("task"), skeleton=skeleton, num_envs=num_envs, device=torch.device("cpu"), **extra)
    latent_stage = ctx.upstream.get("latent")
    latent_ckpt = latent_stage.checkpoint if latent_stage is not None else None
    if latent_ckpt is None and spec.latent.trainer is not None:
        raise StageFailed("the latent stage has no checkpoint")
    latent = ctx.stage_component("latent", checkpoint=latent_ckpt)
    label = "pd_targets"
    if latent_ckpt is not None and not latent.decodes_pd_targets:
        from mocap.distill_files import load_latent_state

        label = str(load_latent_state(latent_ckpt)["extra"].get("label", "policy_output"))
    # the teacher's proprioception layout (its 6D convention): what the latent space was distilled on
    imitator = None
    if spec.imitator is not None:
        imitator_stage = ctx.upstream.get("imitator")
        imitator = ctx.stage_component("imitator", checkpoint=imitator_stage.checkpoint if imitator_stage else None)
    sixd: SixD = imitator.proprio_sixd if imitator is not None else "zhou"
    if label == "pd_targets":
        mapping: Callable[[Observations, Tensor], Tensor] = lambda obs, out: out  # noqa: E731
    elif imitator is None:
        raise StageFailed(f"the latent space's actions are its teacher's raw output (label {label!r}): the spec needs its imitator section")
    else:
        mapping = imitator.to_pd_targets
    sim_ref = spec.simulator
    sim_params = ctx.params("simulator")
    overrides = dict(task.sim_overrides)
    if overrides:
        sim_params = type(sim_params).model_validate({**sim_params.model_dump(), **overrides})
    sim = ctx.plugins.get("simulator", sim_ref.name).build(sim_params, skeleton=skeleton, num_envs=num_envs, seed=ctx.seed)
    try:
        env = TaskEnv(task, latent, mapping, library, sim, seed=ctx.seed, sixd=sixd, warn=lambda text: ctx.console.print(text, style="yellow", markup=False))
    except ValueError as exc:  # e.g. the generation task with scratch (no prior)
        sim.close()
        raise StageFailed(f"task {task_ref.name} with latent {spec.latent.name}: {exc}") from None
    space = env.action_space
    probe = torch.zeros(num_envs, len(space.nvec), dtype=torch.long) if isinstance(space, MultiDiscrete) else torch.zeros(num_envs, *space.shape)
    try:  # a decoder that needs the reference motion fails here, before training starts
        env.pd_targets(sim.state, probe)
    except ValueError as exc:
        raise StageFailed(
            f"task {task_ref.name}: the latent space cannot act without a reference motion ({exc}); distill it with "
            "label: pd_targets or use an imitator with absolute actions"
        ) from None
    return env


__all__ = ["STATE_FORMAT", "ScratchLatent", "TaskEnv", "make_scratch", "make_task_env"]
