"""The episode bookkeeping of online distillation (:mod:`mocap.distill`): reference-state starts on
the control grid, optional fallen / far starts and bonus recovery episodes (:mod:`mocap.fail_states`),
termination and truncation, per-clip failure counts for hard negatives, and an exact state dict.

Built on the shared episode layer (:mod:`mocap.episodes`): :class:`~mocap.episodes.ReferenceStarts`
draws the starts (clip, clamped time, control grid) and says when a non-looping clip is over;
:class:`~mocap.episodes.TerminationTerms` ORs the terms ``tracking`` (body error above the threshold
after the grace steps, outside a recovery window, not a bonus episode) and ``unstable``. There are
no rewards, so no :class:`~mocap.episodes.EpisodeBook`: the step counter is :attr:`DistillEpisodes.progress`."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from mocap.episodes import ReferenceStarts, TerminationTerms
from mocap.fail_states import fail_starts, generate_fall_states
from mocap.getup_starts import GetUpStarts
from mocap.hard_negatives import FailureTracker
from mocap.interfaces import Simulator
from mocap.motion.library import MotionLibrary
from mocap.sim_snapshot import load_sim_state, save_sim_state
from mocap.state import HumanoidState, MotionFrames, SimState

if TYPE_CHECKING:  # pragma: no cover
    from mocap.distill import DistillParams


class DistillEpisodes:
    """The episode bookkeeping of the distillation rollouts: RSI resets, termination/truncation,
    per-clip failure counts and hard-negative weights, and an exact ``state_dict`` (module doc)."""

    def __init__(self, params: DistillParams, library: MotionLibrary, simulator: Simulator, seed: int = 0):
        self.params = p = params
        self.library = lib = library
        self.sim = simulator
        self.num_envs = N = int(simulator.num_envs)
        self.dt = float(simulator.dt)
        self.gen = torch.Generator().manual_seed(int(seed))
        dev = lib.device
        self.clip_ids = torch.zeros(N, dtype=torch.long, device=dev)
        self.start_time = torch.zeros(N, dtype=torch.float64, device=dev)
        self.progress = torch.zeros(N, dtype=torch.long, device=dev)
        self.failures = FailureTracker(lib, params)
        self.starts = ReferenceStarts(lib, self.dt, control_grid=p.control_grid)
        self.termination = TerminationTerms(("tracking", "unstable"))
        self.threshold = p.termination_threshold
        self.recovery_left = torch.zeros(N, dtype=torch.long, device=dev)
        if p.control_grid:
            lib.use_control_grid(self.dt, p.episode_steps + 2)
        fs = p.fail_states
        self._fall_pool: HumanoidState | None = None
        if fs is not None and fs.fall_init_prob > 0:
            self._fall_pool = generate_fall_states(self.sim, lib.skeleton, fs.pool_size or N, fs, self.gen)
        self.getup = GetUpStarts(lib, p.getup_starts, N) if p.getup_starts is not None else None

    # ----------------------------------------------------------------------------- resets
    def reset_envs(self, ids: Tensor) -> None:
        n = int(ids.numel())
        if n == 0:
            return
        clips, t0 = self.starts.sample(n, self.gen)
        self.clip_ids[ids] = clips
        self.start_time[ids] = t0
        self.progress[ids] = 0
        start: HumanoidState = self.library.frames(clips, t0)
        self.recovery_left[ids] = 0
        fs = self.params.fail_states
        if fs is not None and (fs.fall_init_prob > 0 or fs.far_init_prob > 0):
            start, recovering, fallen = fail_starts(start, self._fall_pool, fs, self.gen)
            self.recovery_left[ids[recovering]] = int(fs.recovery_steps)
            if self.getup is not None:  # fallen starts track a get-up clip laid onto the humanoid (mocap.getup_starts)
                rows = ids[fallen.to(ids.device)]
                self.clip_ids[rows] = self.getup.start(ids, fallen, start).to(rows.device)
                self.start_time[rows] = 0.0
        elif self.getup is not None:
            self.getup.start(ids, torch.zeros(n, dtype=torch.bool), start)
        self.sim.reset(ids, start)

    def reset_all(self) -> None:
        self.reset_envs(torch.arange(self.num_envs))

    def reference_next(self) -> MotionFrames:
        """The reference at the time the next step reaches (what ``observe`` gets)."""
        t = self.start_time + (self.progress + 1).to(torch.float64) * self.dt
        frames = self.library.frames(self.clip_ids, t)
        return self.getup.apply(frames, None, t) if self.getup is not None else frames

    # ------------------------------------------------------------------------------- steps
    def after_step(self, state: SimState, ref: MotionFrames) -> dict[str, Tensor]:
        """Advance the counters after ``sim.step``; reset finished envs. Returns per-env tensors
        ``error`` (mean body error, m), ``terminated``, ``truncated`` and ``length`` (steps)."""
        p = self.params
        self.progress += 1
        err = torch.linalg.vector_norm(state.body_pos.double() - ref.body_pos.double(), dim=-1).mean(-1)
        failed = ~(err <= self.threshold) & (self.progress > p.termination_grace)
        unstable = state.unstable.bool() if state.unstable.numel() else torch.zeros_like(failed)
        fs = p.fail_states
        if fs is not None:  # a fallen or far start (or a bonus episode) has a window to recover in
            failed = failed & ~(self.recovery_left > 0)
            if fs.recovery_episode_prob > 0:  # [CODE] some failures go on as recovery episodes
                u = torch.rand(self.num_envs, generator=self.gen, dtype=torch.float64).to(failed.device)
                bonus = failed & ~unstable & (u < fs.recovery_episode_prob)
                failed = failed & ~bonus
                self.recovery_left = torch.where(bonus, torch.full_like(self.recovery_left, fs.recovery_steps + 1), self.recovery_left)
            self.recovery_left = (self.recovery_left - 1).clamp_min(0)
        terminated, _ = self.termination({"tracking": failed, "unstable": unstable})
        t_next = self.start_time + (self.progress + 1).to(torch.float64) * self.dt
        clip_over = self.starts.clip_over(self.clip_ids, t_next)
        if self.getup is not None:  # a get-up episode ends after its clip plus the hold
            clip_over = self.getup.over(self.clip_ids, t_next, clip_over)
        truncated = ((self.progress >= p.episode_steps) | clip_over) & ~terminated
        done = terminated | truncated
        length = self.progress.clone()
        if bool(done.any()):
            ids = done.nonzero().squeeze(-1)
            mined = ids if self.getup is None else ids[~self.getup.active[ids.cpu()].to(ids.device)]  # get-ups are not mined
            self._record(self.clip_ids[mined].cpu(), terminated[mined].cpu())
            self.reset_envs(ids)
        return {"error": torch.nan_to_num(err, nan=0.0), "terminated": terminated, "truncated": truncated, "length": length}

    # ---------------------------------------------------------------------- hard negatives
    @property
    def clip_weights(self) -> Tensor:
        return self.library.weights.detach().to("cpu", torch.float64).clone()

    def _record(self, clip_ids: Tensor, failed: Tensor) -> None:
        self.failures.record(clip_ids, failed)

    def add_failures(self, amount: Tensor) -> None:
        self.failures.add_failures(amount)

    # per-clip failure bookkeeping lives in the shared tracker (mocap.hard_negatives)
    @property
    def fail_counts(self) -> Tensor:
        return self.failures.fail_counts

    @property
    def episodes_per_clip(self) -> Tensor:
        return self.failures.episodes_per_clip

    @property
    def failures_per_clip(self) -> Tensor:
        return self.failures.failures_per_clip

    @property
    def base_weights(self) -> Tensor:
        return self.failures.base_weights

    # ------------------------------------------------------------------------------ resume
    def state_dict(self) -> dict[str, Any]:
        sd: dict[str, Any] = {
            "num_envs": self.num_envs,
            "clip_names": list(self.library.clip_names),
            "generator": self.gen.get_state().clone(),
            "clip_ids": self.clip_ids.cpu().clone(),
            "start_time": self.start_time.cpu().clone(),
            "progress": self.progress.cpu().clone(),
            "recovery_left": self.recovery_left.cpu().clone(),
            **self.failures.state_dict(),
            **(self.getup.state_dict() if self.getup is not None else {}),
        }
        sd.update(save_sim_state(self.sim))
        return sd

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if int(state["num_envs"]) != self.num_envs:
            raise ValueError(f"the checkpoint has {state['num_envs']} envs, the params ask for {self.num_envs}")
        if list(state["clip_names"]) != list(self.library.clip_names):
            raise ValueError("the checkpoint was made with a different motion set")
        dev = self.library.device
        self.gen.set_state(state["generator"].clone())
        self.clip_ids = state["clip_ids"].to(dev).clone()
        self.start_time = state["start_time"].to(dev).clone()
        self.progress = state["progress"].to(dev).clone()
        if "recovery_left" in state:
            self.recovery_left = state["recovery_left"].to(dev).clone()
        self.failures.load_state_dict(state)
        if self.getup is not None:
            self.getup.load_state_dict(state)
        load_sim_state(self.sim, torch.arange(self.num_envs), state, dev)


__all__ = ["DistillEpisodes"]
