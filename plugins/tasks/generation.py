"""The ``generation`` task: unconditional motion generation from a latent space's prior, run as a
task so that the same env, specs and comparison tables hold it next to the goal-directed tasks
(PULSE Sec. 4.3 "random generation" and Sec. 5.3; hybrid-RVQ Sec. 6.2).

Action. There is no task policy: :attr:`GenerationTask.prior_rollout` tells the task env
(:class:`mocap.task_env.TaskEnv`) to ignore the policy's action and decode, every control step,
``latent.random_action(obs, prior_noise_scale, generator)`` (PULSE: ``z = mu_p + noise sigma_p eps``;
hybrid: uniformly random codes of the task codebooks added to the prior). PPO still runs (it learns
nothing: the reward is 0), so a ``task`` stage with this task is a seeded generation rollout logged
like any task.

Not with ``scratch``. ``scratch`` is the no-latent baseline: its action is a PD target and it has no
prior to sample (no ``random_action``); "generation" would be a policy that is never trained. The
task env refuses the pairing with a clear error (``task generation with latent scratch: ...``).

Observation: none (``goal_dim`` 0). Reward: 0 every step (there is no task); ``max_reward`` 1 only
so that the normalized return is defined (always 0).

Termination: by default none (``fall.early_termination`` False: a rollout goes on after a fall and
getting up counts, as :mod:`mocap.generation`); with it on, the shared fall test ends the episode.

Hook: ``step(state)`` advances the counters and records the body positions for diversity.

Metrics (since the last :meth:`GenerationTask.metrics`), with :mod:`mocap.generation`'s definitions
and functions (:func:`~mocap.generation_eval.fallen_down`, :func:`~mocap.generation_eval.heading_frame`,
:func:`~mocap.generation_eval.in_start_frame`, :func:`~mocap.generation_eval.pairwise_diversity`). An *episode*
finishes when its env is reset:

* ``fall_rate``: fraction of the finished episodes (with at least one step) with a fall at some step
  (a non-foot body touching the ground below ``fall_height``, 0.15 m);
* ``time_to_fall_s``: mean time of the first fall over the episodes that fell;
* ``survival_s``: mean time of the first fall, or of the episode's length when it did not fall;
* ``down_at_end``: fraction of the finished episodes that were fallen at their last step;
* ``diversity_m``: APD-style diversity over the episodes that lasted ``diversity_steps`` (body
  positions every ``diversity_stride`` steps, each trajectory in its own start frame; at most
  ``diversity_rollouts`` of them, the first ones finished);
* ``episodes``, ``diversity_episodes``: counts (sums); ``steps``: control steps (a sum).
"""

from __future__ import annotations

from typing import Any

import torch
from mocap.generation_eval import fallen_down, heading_frame, in_start_frame, pairwise_diversity
from mocap.interfaces import Task
from mocap.skeleton import Skeleton
from mocap.state import SimState
from mocap_tasks.common import TaskBase, rows
from torch import Tensor
from mocap_tasks.task_params import GenerationTaskParams

__all__ = ["GenerationTask", "GenerationTaskParams", "make_generation"]


class GenerationTask(TaskBase, Task):
    """The ``generation`` task (module docstring)."""

    goal_dim = 0
    max_reward = 1.0
    #: the task env ignores the policy's action and samples the latent prior (mocap.hierarchy)
    prior_rollout = True

    def __init__(self, params: GenerationTaskParams, *, skeleton: Skeleton, num_envs: int, device: Any = "cpu", seed: int | None = None):
        self.params = p = params
        self._setup(p.fall, skeleton, num_envs, device, p.seed if seed is None else seed)
        self.sim_overrides = {}
        self.prior_noise_scale = p.noise_scale
        self.episode_steps = p.episode_steps
        self.horizon = p.diversity_steps or p.episode_steps
        self.frames = self.horizon // p.diversity_stride + 1  # k = 0, stride, 2 stride, ... <= horizon
        N, B, dev = self.num_envs, skeleton.num_bodies, self.device
        self.first_fall = torch.full((N,), -1, dtype=torch.long, device=dev)
        self.down = torch.zeros(N, dtype=torch.bool, device=dev)
        self.origin = torch.zeros(N, 3, device=dev)
        self.heading = torch.zeros(N, 4, device=dev)
        self.traj = torch.zeros(N, self.frames, B, 3, device=dev)
        self._done: list[Tensor] = []  # finished (frames, B, 3) trajectories in their start frames
        self._episode_stats = {"episodes": 0.0, "fell": 0.0, "fall_time": 0.0, "survival": 0.0, "down": 0.0}

    # ------------------------------------------------------------------------------ goals
    def _finish_episodes(self, ids: Tensor) -> None:
        ids = ids[self.progress[ids] > 0]
        if ids.numel() == 0:
            return
        fell = self.first_fall[ids] >= 0
        e = self._episode_stats
        e["episodes"] += float(ids.numel())
        e["fell"] += float(fell.sum())
        e["fall_time"] += float(self.first_fall[ids][fell].double().sum()) * self.dt
        survival = torch.where(fell, self.first_fall[ids], self.progress[ids]).double() * self.dt
        e["survival"] += float(survival.sum())
        e["down"] += float(self.down[ids].sum())

    def reset(self, env_ids: Tensor, state: SimState) -> None:
        ids = self._ids(env_ids)
        if ids.numel() == 0:
            return
        self._finish_episodes(ids)
        r = rows(state, ids, self.num_envs)
        origin, heading = heading_frame(r.root_pos.float().to(self.device), r.root_rot.float().to(self.device))
        self.origin[ids], self.heading[ids] = origin, heading
        self.traj[ids, 0] = r.body_pos.float().to(self.device)
        self.progress[ids] = 0
        self.first_fall[ids] = -1
        self.down[ids] = False

    def step(self, state: SimState) -> None:
        """Advance the counters; record body positions for the diversity (module docstring)."""
        self.progress += 1
        k = self.progress
        rec = ((k % self.params.diversity_stride) == 0) & (k <= self.horizon)
        if bool(rec.any()):
            ids = rec.nonzero().flatten()
            self.traj[ids, k[ids] // self.params.diversity_stride] = state.body_pos[ids.to(state.body_pos.device)].float().to(self.device)
        full = (k == self.horizon).nonzero().flatten()
        if full.numel() and len(self._done) < self.params.diversity_rollouts:
            full = full[: self.params.diversity_rollouts - len(self._done)]
            local = in_start_frame(self.traj[full].transpose(0, 1), self.origin[full], self.heading[full])  # (F, K, B, 3)
            self._done.extend(local.unbind(1))

    # ------------------------------------------------------------------------ observation
    def observe(self, state: SimState) -> Tensor:
        return torch.zeros(state.num_envs, 0, dtype=state.root_pos.dtype, device=state.root_pos.device)

    # ----------------------------------------------------------------------------- reward
    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        contact = self._ground_contact(state)
        if contact.numel() == 0:
            contact = torch.zeros(state.body_pos.shape[:2], dtype=torch.bool, device=state.body_pos.device)
        down = fallen_down(state.body_pos, contact, self._allowed, self.params.fall_height).to(self.device)
        now = self.progress + 1  # the step of ``state``
        self.first_fall = torch.where((self.first_fall < 0) & down, now, self.first_fall)
        self.down = down
        self._sums.add("steps", float(state.num_envs), count=1)
        return torch.zeros(state.num_envs, dtype=state.root_pos.dtype, device=state.root_pos.device)

    def terminated(self, state: SimState) -> Tensor:
        return self._fallen(state)

    def metrics(self) -> dict[str, float]:
        out = self._sums.pop(totals=("steps",))
        e = self._episode_stats
        if e["episodes"] > 0:
            out["episodes"] = e["episodes"]
            out["fall_rate"] = e["fell"] / e["episodes"]
            out["survival_s"] = e["survival"] / e["episodes"]
            out["down_at_end"] = e["down"] / e["episodes"]
            if e["fell"] > 0:
                out["time_to_fall_s"] = e["fall_time"] / e["fell"]
        if len(self._done) >= 2:
            out["diversity_m"] = pairwise_diversity(torch.stack(self._done, 1))
            out["diversity_episodes"] = float(len(self._done))
        self._done = []
        self._episode_stats = {k: 0.0 for k in e}
        return out


def make_generation(
    params: GenerationTaskParams, *, skeleton: Skeleton, num_envs: int, device: Any = "cpu", seed: int | None = None, **_: Any
) -> GenerationTask:
    """Registry factory of the ``generation`` task."""
    return GenerationTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed)
