"""The PHC imitation environment (a :class:`~mocap.rl.env.VecEnv`) and the observation/action code
it shares with the trained imitator.

Episode (PHC Sec. 3.1; official code phc/env/tasks/humanoid_im.py):

* **Reference-state initialization** (RSI, DeepMimic): a clip drawn with the motion library's
  sampling weights, a start time uniform in the clip (non-looping clips: in
  ``[0, duration - dt]``, so at least one step remains), and the simulator reset to the reference
  state there (root pose and velocities, DoF angles and velocities).
* **Step** ``t -> t+1``: the observation at ``t`` holds the reference at ``t+1``; the action is
  mapped to PD targets (:class:`ActionMap`), the simulator advances one control step, and the
  reward (:mod:`mocap.imitation_rewards`) and termination (:mod:`mocap_phc.termination`) compare the new
  state with that same ``t+1`` reference.
* **End**: *terminated* on tracking failure, fall (optional) or numerical instability (no
  bootstrap); *truncated* after ``episode_steps`` steps (300 = 10 s at 30 Hz) or when a
  non-looping clip has no next frame left. Looping clips keep going past their end (the motion
  library advances the root by the cycle offset each period). Finished envs are reset at once;
  :attr:`StepResult.final_obs` holds their last observation before the reset.
* ``episodes`` statistics per finished env: ``return``, ``length`` (steps) and ``success`` (1 if
  it was truncated, i.e. reached the time limit or the clip's end without terminating).

The episode mechanics are the shared layer of :mod:`mocap.episodes`: :class:`~mocap.episodes.ReferenceStarts`
(the RSI draw, the adaptive start sampler, the clamp and the control grid, the clip-end test),
:class:`~mocap.episodes.EpisodeBook` (``book.steps`` = :attr:`ImitationEnv.progress`, ``book.returns`` =
:attr:`ImitationEnv.ep_return`, and the end of every step), :class:`~mocap.episodes.TerminationTerms`
(``tracking``, ``fall``, ``unstable`` of :class:`~mocap_phc.termination.Termination`; the fail-state grace
window and bonus episodes are applied after it) and :class:`~mocap.episodes.RewardTerms`: the reward is
``sum_k w_k r_k`` over the terms ``imitation``, ``point`` (PHC Eq. 4's point-goal reward where the root is
far, with ``recovery_goal.reward == "point"``; ``imitation`` is 0 there), ``energy`` and ``amp`` (with
``params.amp``), each logged unweighted as ``reward/<name>`` (``reward/imitation`` logs the task reward,
i.e. the point reward where far). Weights: :meth:`~mocap_phc.imitator.PHCParams.reward_term_weights`,
replaced term by term by ``params.reward_terms``.

**Hard-negative mining** (PHC+ "soft" mining; PULSE Sec. 4.1, PHC Sec. 3.1 "Hard Negative Mining", PHC
code ``update_soft_sampling_weight`` in phc/utils/motion_lib_base.py), when
``params.hard_negative``: each clip ``c`` has a failure count ``f_c`` (PHC's
``termination_history``) and the clip sampling probabilities become::

    p_c = (1 - floor) * f_c / sum(f) + floor * b_c        (p = b while sum(f) = 0)

where ``b`` are the library's initial weights (uniform unless the motion set says otherwise). PHC+
gives never-failing clips probability 0; the ``floor`` share (default 0.2) keeps every clip in
play so that mastered clips are not forgotten. ``f`` grows from two sources; before each addition
``f`` is multiplied by ``hard_negative_decay`` (1 = PHC's never-forgetting counts):

* training episodes: every ``update_every`` finished episodes, each clip played in that window
  adds its **failure rate** in the window (failures / episodes, in [0, 1]) — a rate, not a raw
  count, so that a clip's weight does not feed on how often it was sampled;
* :meth:`ImitationEnv.evaluate_clips` (PHC's evaluation-driven mining): every clip once from
  frame 0 with deterministic actions in a separate simulator; each failed clip adds 1. The
  trainer calls it through :meth:`ImitationEnv.after_iteration` every ``eval_every`` iterations.
  Failure there is the project evaluator's criterion (:func:`mocap.imitation_eval.rollout_imitation`:
  mean body error above ``eval_threshold`` = 0.5 m at any frame, or instability).

**AMP reward** (PHC+; ``params.amp``, :mod:`mocap_phc.amp`): every env keeps the last
``amp_history`` AMP frames (newest first). After each physics step the new state's frame is pushed
and the step's reward becomes::

    r = w_task r^g + w_amp r^amp + r^energy          (amp_energy_mix "paper", Eq. 1)
    r = w_task (r^g + r^energy) + w_amp r^amp        (amp_energy_mix "code")

(as reward terms the "code" form is summed as ``w_task r^g + w_task r^energy + w_amp r^amp``, which can
differ from the factored form in the last bit of the float32 sum unless ``w_task`` is a power of two)

with ``r^amp`` from the discriminator as it stood during the rollout; the window is also handed to
the discriminator trainer as a policy sample. At an episode start (RSI reset) the window is filled
with the simulator's reset state as the newest frame and the reference clip's frames at
``t0 - k dt`` (``k = 1 .. history - 1``, clamped to the clip's first frame for non-looping clips)
as the older ones, i.e. the motion the humanoid is pretended to have come from (the code's
``_init_amp_obs_ref``). :meth:`ImitationEnv.after_iteration` trains the discriminator on the last
rollout's windows (``amp_updates_per_iteration`` steps of ``amp_batch``); the discriminator, its
optimizer, buffers and generator, and the windows are part of :meth:`ImitationEnv.state_dict`.

The observation/action code is in :mod:`mocap_phc.observation` and the per-clip mining and
evaluation methods in :mod:`mocap_phc.env_mining` (a base class of :class:`ImitationEnv`); both re-exported here.
"""

from __future__ import annotations

import dataclasses

from dataclasses import replace

from typing import TYPE_CHECKING, Any, Callable

import torch
from torch import Tensor

from mocap.episodes import EpisodeBook, ReferenceStarts, RewardTerms, TerminationTerms
from mocap.fail_states import fail_starts, generate_fall_states
from mocap.getup_starts import GetUpStarts
from mocap.hard_negatives import FailureTracker
from mocap.hard_negatives import failure_weights as hard_negative_weights
from mocap.interfaces import Simulator
from mocap.motion.library import MotionLibrary
from mocap.pd_actions import ActionMap, pd_offset_scale
from mocap.rl.env import StepResult
from mocap.skeleton import Skeleton
from mocap.start_sampling import AdaptiveStartSampler
from mocap.sim_snapshot import load_sim_state, save_sim_state
from mocap.state import HUMANOID_FIELDS, HumanoidState, MotionFrames, SimState
from mocap_phc.amp import AMPHistory, AMPObservation, DiscriminatorTrainer, demo_windows, loss_config, window_frames
from mocap.imitation_rewards import ImitationReward, energy_penalty
from mocap_phc.env_mining import ClipMining, PolicyFn
from mocap_phc.observation import PHCObservation, PolicyImitator
from mocap_phc.phc_params import REWARD_TERMS
from mocap_phc.termination import DEFAULT_THRESHOLD, Termination, contact_table, curriculum_threshold

if TYPE_CHECKING:  # pragma: no cover
    from mocap_phc.imitator import PHCParams

STATE_FORMAT = 1


# ---------------------------------------------------------------------------------------- env
class ImitationEnv(ClipMining):
    """N imitation episodes on a motion library (module docstring).

    Args:
        params: :class:`~mocap_phc.imitator.PHCParams`.
        skeleton: the humanoid.
        library: the clips (the env owns it: it sets its sampling weights).
        simulator: N envs of ``skeleton``.
        seed: seeds the env's RNG (clip and start-time sampling).
        eval_simulator_factory: ``n -> Simulator`` with n envs, for :meth:`evaluate_clips`.
    """

    def __init__(
        self,
        params: "PHCParams",
        skeleton: Skeleton,
        library: MotionLibrary,
        simulator: Simulator,
        *,
        seed: int = 0,
        eval_simulator_factory: Callable[[int], Simulator] | None = None,
    ):
        p = self.params = params
        self.skeleton = skeleton
        self.library = lib = library
        self.sim = simulator
        self.num_envs = N = int(simulator.num_envs)
        self.device = lib.device
        self.dt = float(simulator.dt)
        self.observation = p.observation()
        self.action_map = ActionMap.for_skeleton(skeleton, p.action, p.action_clip, p.action_scale_overrides)
        self.action_space = self.action_map.space
        self.obs_dim = self.observation.dim(skeleton.num_bodies)
        self.reward_fn = ImitationReward(p.reward_form, tuple(p.reward_weights), tuple(p.reward_scales))  # type: ignore[arg-type]
        self.reward_terms = _reward_terms(p)
        self.termination_terms = TerminationTerms(("tracking", "fall", "unstable"))
        self._steps_seen = 0  # training env steps of this env (all envs), for the termination curriculum
        self.termination = Termination.for_skeleton(
            skeleton,
            p.termination,
            p.termination_threshold,
            p.termination_grace,
            p.termination_exclude,
            p.fall_check,
            p.fall_height,
        )
        # per-clip contact rules: (C, B) bodies whose ground contact ends an episode of that clip
        cr = p.contact_rules
        self._forbidden = contact_table(skeleton, library.clip_names, cr.allowed, cr.default).to(library.device) if cr is not None else None
        self._final_threshold = self.termination.threshold if self.termination.threshold is not None else DEFAULT_THRESHOLD[p.termination]
        if p.termination_curriculum is not None:
            self.termination = replace(self.termination, threshold=curriculum_threshold(p.termination_curriculum, self._final_threshold, 0))
        self._eval_factory = eval_simulator_factory
        self._eval_sims: dict[int, Simulator] = {}
        self._gen = torch.Generator(device="cpu")
        self._gen.manual_seed(int(seed))

        dev = self.device
        self.clip_ids = torch.zeros(N, dtype=torch.long, device=dev)
        self.start_time = torch.zeros(N, dtype=torch.float64, device=dev)
        self.book = EpisodeBook(N, dev)  # steps (progress) and returns of the current episodes
        self.failures = FailureTracker(lib, p)
        if p.control_grid:  # the reference at t0 + k dt becomes a table lookup (start times on the grid)
            lib.use_control_grid(self.dt, p.episode_steps + 1 + p.goal_frames)
        ss = p.start_sampling
        durations = lib.durations64.to(dev)
        self.start_sampler = AdaptiveStartSampler(durations, ss) if ss.mode == "adaptive" else None
        self.starts = ReferenceStarts(lib, self.dt, control_grid=p.control_grid, start_sampler=self.start_sampler)
        self._ref_next: MotionFrames | None = None
        self._seen_next: MotionFrames | None = None  # what the policy observed of it (noisy references)
        self._obs: Tensor | None = None
        # noisy references (params.reference_noise): the observed library, redrawn every reference_noise_every iterations
        self._noise_seed = (int(seed) + 104729) % (2**31)
        self._noise_draw = 0  # the draw the current observation was made with
        self._noise_due = False  # a fresh draw takes effect at the next step, after its action
        self.observed: MotionLibrary | None = None
        self._draw_noise()
        self.last_evaluation: dict[str, Any] | None = None
        self.recovery_left = torch.zeros(N, dtype=torch.long, device=dev)
        self.root_dist = torch.zeros(N, dtype=torch.float64, device=dev)  # root to reference root, m (point-goal reward)
        self._fall_pool: HumanoidState | None = None
        fs = p.fail_states
        if fs is not None and fs.fall_init_prob > 0:
            self._fall_pool = generate_fall_states(self.sim, skeleton, fs.pool_size or N, fs, self._gen)
        self.getup = GetUpStarts(lib, p.getup_starts, N) if p.getup_starts is not None else None

        self.amp_obs: AMPObservation | None = None
        self.amp_history: AMPHistory | None = None
        self.amp_trainer: DiscriminatorTrainer | None = None
        if p.amp:
            self.amp_obs = AMPObservation(skeleton, p.amp_joints, "tan_norm", p.amp_key_bodies, p.amp_exclude)
            H = int(p.amp_history)
            self.amp_history = AMPHistory(N, H, self.amp_obs.dim)
            amp_obs, dt = self.amp_obs, self.dt

            def demo_fn(n: int, gen: torch.Generator) -> Tensor:
                return demo_windows(lib, amp_obs, n, H, dt, gen).reshape(n, -1)

            self.amp_trainer = DiscriminatorTrainer(
                H * self.amp_obs.dim,
                demo_fn,
                loss_config(p.amp_loss, p.amp_grad_penalty, p.amp_reward_scale),
                hidden=tuple(p.amp_hidden),
                lr=p.amp_lr,
                replay_size=p.amp_replay_size,
                replay_keep_prob=p.amp_replay_keep_prob,
                demo_buffer_size=p.amp_demo_buffer_size,
                seed=int(seed) + 7919,
            )

    # ----------------------------------------------------------------------------- helpers
    @property
    def progress(self) -> Tensor:
        """(N,) long, steps of the current episodes (``book.steps``; read-only)."""
        return self.book.steps

    @property
    def ep_return(self) -> Tensor:
        """(N,) float64, summed reward of the current episodes (``book.returns``; read-only)."""
        return self.book.returns

    def _ref_at(self, ids: Tensor | None, steps_ahead: int, library: MotionLibrary | None = None) -> MotionFrames:
        c = self.clip_ids if ids is None else self.clip_ids[ids]
        t0 = self.start_time if ids is None else self.start_time[ids]
        k = self.book.steps if ids is None else self.book.steps[ids]
        t = t0 + (k + steps_ahead).to(torch.float64) * self.dt
        frames = (library or self.library).frames(c, t)
        return self.getup.apply(frames, ids, t) if self.getup is not None else frames

    def _draw_noise(self) -> None:
        """(Re)build the noisy observed library (``params.reference_noise``; draw ``_noise_draw``)."""
        level = self.params.reference_noise
        if level is None or level.clean:
            self.observed = None
            return
        from mocap.noisy import noisy_library

        self.observed = noisy_library(self.library, level, self._noise_seed + 7919 * self._noise_draw)

    def _observe(self, state: SimState, ids: Tensor | None = None) -> Tensor:
        """Flat observations of envs ``ids`` (all when None); updates the cached next reference
        (clean) and what the policy saw of it (the noisy reference with ``reference_noise``)."""
        ref = self._ref_at(ids, 1)
        seen = ref if self.observed is None else self._ref_at(ids, 1, self.observed)
        if self.params.goal_frames > 1:  # the later goal frames, as the policy sees them
            seen = replace(seen, ahead=tuple(self._ref_at(ids, k, self.observed) for k in range(2, self.params.goal_frames + 1)))
        st = state if ids is None else state.index(ids)
        obs = PHCObservation.flatten(self.observation(st, seen))
        if ids is None:
            self._ref_next, self._seen_next = ref, seen
        else:
            assert self._ref_next is not None and self._seen_next is not None
            _assign_rows(self._ref_next, ids, ref)
            if self._seen_next is not self._ref_next:
                _assign_rows(self._seen_next, ids, seen)
        return obs

    def _reset_envs(self, ids: Tensor) -> None:
        n = int(ids.numel())
        if n == 0:
            return
        clips, t0 = self.starts.sample(n, self._gen)  # RSI (adaptive start times, clamped, on the control grid)
        self.clip_ids[ids] = clips
        self.start_time[ids] = t0
        self.book.start(ids)
        start: HumanoidState = self.library.frames(clips, t0)
        self.recovery_left[ids] = 0
        fs = self.params.fail_states
        fallen = torch.zeros(n, dtype=torch.bool)
        if fs is not None and (fs.fall_init_prob > 0 or fs.far_init_prob > 0):
            start, fallen = self._fail_starts(ids, start, fs)
        if self.getup is not None:  # fallen starts track a get-up clip laid onto the humanoid (mocap.getup_starts)
            rows = ids[fallen.to(ids.device)]
            self.clip_ids[rows] = self.getup.start(ids, fallen, start).to(rows.device)
            self.start_time[rows] = 0.0
        self.sim.reset(ids, start)
        ref0 = self._ref_at(ids, 0)
        self.root_dist[ids] = torch.linalg.vector_norm(
            ref0.root_pos.to(torch.float64) - self.sim.state.root_pos[ids].to(ref0.root_pos.device, torch.float64), dim=-1
        )
        if self.amp_history is not None:
            self._amp_fill(ids, self.sim.state.index(ids), self.clip_ids[ids], self.start_time[ids])

    def _fail_starts(self, ids: Tensor, start: HumanoidState, fs: Any) -> tuple[HumanoidState, Tensor]:
        """Replace some RSI starts by fallen states (at the reference root's xy) or far ones
        (:func:`mocap.fail_states.fail_starts`); those envs get a recovery window. Returns the
        states and the (n,) mask of the fallen ones."""
        state, recovering, fallen = fail_starts(start, self._fall_pool, fs, self._gen)
        self.recovery_left[ids[recovering]] = int(fs.recovery_steps)
        return state, fallen

    def _amp_fill(self, ids: Tensor, state: HumanoidState, clips: Tensor, t0: Tensor) -> None:
        """Episode-start AMP window of envs ``ids``: ``state`` newest, the reference before ``t0`` older."""
        assert self.amp_obs is not None and self.amp_history is not None
        H = self.amp_history.history
        now = self.amp_obs(state)[:, None]
        if H > 1:
            past = window_frames(self.library, self.amp_obs, clips, t0, H, self.dt, first=1)
            now = torch.cat((now, past.to(now)), dim=1)
        self.amp_history.fill(ids, now)

    # ---------------------------------------------------------------------------- VecEnv
    def reset(self) -> Tensor:
        """Reset every env (RSI); return the (N, O) observations."""
        self._reset_envs(torch.arange(self.num_envs, device=self.device))
        self._obs = self._observe(self.sim.state)
        return self._obs.clone()

    def step(self, actions: Tensor) -> StepResult:
        if self._ref_next is None:
            raise RuntimeError("call reset() (or load_state_dict) before step()")
        p = self.params
        N = self.num_envs
        a = torch.as_tensor(actions, device=self.device).float()
        if tuple(a.shape) != (N, self.action_space.shape[0]):
            raise ValueError(f"actions must be ({N}, {self.action_space.shape[0]}), got {tuple(a.shape)}")
        ref = self._ref_next  # the reference at the time this step reaches
        seen = self._seen_next if self._seen_next is not None else ref
        targets = self.action_map(a, seen.dof_pos)  # residuals are relative to the reference the policy saw
        if self._noise_due:
            self._noise_draw += 1
            self._noise_due = False
            self._draw_noise()
        state = self.sim.step(targets)
        self.book.tick()  # the energy warm-up and the termination grace read the new step count

        r_im, terms = self.reward_fn(state, ref)
        dist = torch.linalg.vector_norm(ref.root_pos.to(torch.float64) - state.root_pos.to(ref.root_pos.device, torch.float64), dim=-1)
        rg = p.recovery_goal
        point = rg is not None and rg.reward == "point"
        recovery_info: dict[str, Tensor] = {}
        reward_terms: dict[str, Tensor] = {}
        if rg is not None:
            far = self.root_dist > rg.close_distance
            # diagnostics of fail-state training: share of envs recovering (root far), their root distance
            recovery_info = {"recovery/far": far.float(), "recovery/root_dist_m": dist.float()}
            if point:  # PHC Eq. 4: the point-goal reward replaces the imitation reward while far
                from mocap_phc.recovery import point_goal_reward

                far_ = far.to(r_im.device)
                r_point = point_goal_reward(self.root_dist, dist, rg.point_form).to(r_im)
                reward_terms["point"] = torch.where(far_, r_point, torch.zeros_like(r_im))
                reward_terms["imitation"] = torch.where(far_, torch.zeros_like(r_im), r_im)
                r_im = torch.where(far_, r_point, r_im)  # the task reward (logged as reward/imitation, as before)
        reward_terms.setdefault("imitation", r_im)
        self.root_dist = dist
        energy = energy_penalty(state.dof_force, state.dof_vel, p.energy_form, p.energy_coef, self.book.steps)
        if rg is not None and point:  # PHC Eq. 4: 0.1 r^energy while recovering
            energy = torch.where(far.to(energy.device), rg.far_energy_weight * energy, energy)
        reward_terms["energy"] = energy
        amp_info: dict[str, Tensor] = {}
        if self.amp_trainer is not None:
            assert self.amp_obs is not None and self.amp_history is not None
            self.amp_history.push(self.amp_obs(state))
            window = self.amp_history.flat()
            reward_terms["amp"] = self.amp_trainer.reward(window).to(r_im.device, r_im.dtype)
            self.amp_trainer.observe_policy(window)
            amp_info = {"reward/task": r_im + energy if p.amp_energy_mix == "code" else r_im}
        self._steps_seen += N
        if p.termination_curriculum is not None:  # loose to tight (PHCParams.termination_curriculum)
            self.termination = replace(self.termination, threshold=curriculum_threshold(p.termination_curriculum, self._final_threshold, self._steps_seen))
        forbidden = self._forbidden[self.clip_ids] if self._forbidden is not None else None
        _, parts = self.termination(state, ref, self.book.steps, forbidden, p.contact_rules.fall_height if p.contact_rules is not None else None)
        terminated, term_info = self.termination_terms(parts)
        if p.fail_states is not None:  # a fallen or far start has a grace window to recover in
            grace = self.recovery_left > 0
            terminated = terminated & (~grace | parts["unstable"])
            if p.fail_states.recovery_episode_prob > 0:  # [C] bonus recovery episodes instead of some resets
                u = torch.rand(N, generator=self._gen, dtype=torch.float64).to(terminated.device)
                bonus = terminated & ~parts["unstable"] & (u < p.fail_states.recovery_episode_prob)
                terminated = terminated & ~bonus
                self.recovery_left = torch.where(bonus, torch.full_like(self.recovery_left, p.fail_states.recovery_steps + 1), self.recovery_left)
            self.recovery_left = (self.recovery_left - 1).clamp_min(0)
        reward, reward_info = self.reward_terms(reward_terms, unstable=parts["unstable"])  # 0 where unstable or not finite
        # with the point term, reward/imitation stays the task reward it always logged (the point reward where far)
        reward_info["reward/imitation"] = r_im
        t_next = self.start_time + (self.book.steps + 1).to(torch.float64) * self.dt
        over = self.starts.clip_over(self.clip_ids, t_next)
        if self.getup is not None:  # a get-up episode ends after its clip plus the hold
            over = self.getup.over(self.clip_ids, t_next, over)
        truncated = (self.book.steps >= p.episode_steps) | over
        if p.loop_cycles is not None:  # looping clips: the episode ends after loop_cycles periods
            played = self.book.steps.to(torch.float64) * self.dt
            truncated = truncated | (self.starts.loops[self.clip_ids] & (played >= p.loop_cycles * self.starts.durations[self.clip_ids] - 1e-6))
        err = torch.linalg.vector_norm(state.body_pos - ref.body_pos, dim=-1).mean(-1)
        info: dict[str, Any] = {
            **reward_info,
            **{f"reward/{k}": v for k, v in terms.items()},
            **amp_info,
            "error/body_pos_m": torch.nan_to_num(err, nan=0.0),
            **term_info,
            **recovery_info,
        }
        res = self.book.conclude(
            reward,
            terminated,
            truncated,
            lambda ids: self._observe(state) if ids is None else self._observe(self.sim.state, ids),
            self._reset_envs,
            info=info,
            on_finish=self._episodes_finished,
            count_step=False,
        )
        self._obs = res.obs.clone()
        return res

    def _episodes_finished(self, ids: Tensor, failed: Tensor) -> None:
        """``EpisodeBook.conclude``'s hook before envs ``ids`` are reset: per-clip failure counts (hard
        negatives) and, with adaptive starts, the clip times at which the ``failed`` ones failed
        (get-up episodes from fallen starts are left out: mocap.getup_starts)."""
        if self.getup is not None:
            keep = ~self.getup.active[ids.cpu()].to(ids.device)
            ids, failed = ids[keep], failed[keep]
        self._record(self.clip_ids[ids].cpu(), failed.cpu())
        if self.start_sampler is not None:
            bad = ids[failed]
            fail_t = self.start_time[bad] + self.book.steps[bad].to(torch.float64) * self.dt
            self.start_sampler.record_failures(self.clip_ids[bad], fail_t)

    def close(self) -> None:
        for sim in self._eval_sims.values():
            sim.close()
        self._eval_sims.clear()
        self.sim.close()

    # ------------------------------------------------- trainer hook (clip mining: env_mining)
    def after_iteration(self, iteration: int, policy_fn: PolicyFn) -> dict[str, float]:
        """Trainer hook: every ``eval_every`` iterations run :meth:`evaluate_clips` (which refreshes the
        sampling weights when ``hard_negative`` is on); returns scalars to log (empty otherwise)."""
        out: dict[str, float] = {}
        if self.observed is not None and iteration > 0 and iteration % self.params.reference_noise_every == 0:
            self._noise_due = True  # fresh noise from the next step's observation on (the current one stays)
        if self.amp_trainer is not None:  # the discriminator learns from the rollout just collected
            stats = self.amp_trainer.update(self.params.amp_updates_per_iteration, self.params.amp_batch)
            out.update({f"amp/{k}": v for k, v in stats.items()})
        every = self.params.eval_every
        if every <= 0 or iteration <= 0 or iteration % every != 0 or self._eval_factory is None:
            return out
        res = self.evaluate_clips(policy_fn)
        w = self.clip_weights
        out.update(
            {
                "hard_negative/eval_success_rate": res["success_rate"],
                "hard_negative/failed_clips": float(len(res["failed"])),
                "hard_negative/max_weight": float(w.max()),
                "hard_negative/min_weight": float(w.min()),
            }
        )
        return out

    # -------------------------------------------------------------------------- resume
    def state_dict(self) -> dict[str, Any]:
        """RNG, episode counters, sampling weights, hard-negative counts and the simulator's physics state."""
        if self._ref_next is None:
            raise RuntimeError("state_dict() before reset()")
        sd: dict[str, Any] = {
            "format": STATE_FORMAT,
            "num_envs": self.num_envs,
            "clip_names": list(self.library.clip_names),
            "generator": self._gen.get_state().clone(),
            "clip_ids": self.clip_ids.cpu().clone(),
            "start_time": self.start_time.cpu().clone(),
            "progress": self.book.steps.cpu().clone(),  # the keys of STATE_FORMAT 1 (EpisodeBook's steps/returns)
            "ep_return": self.book.returns.cpu().clone(),
            "recovery_left": self.recovery_left.cpu().clone(),
            "root_dist": self.root_dist.cpu().clone(),
            "noise_draw": self._noise_draw,
            "steps_seen": self._steps_seen,
            "noise_due": self._noise_due,
            **(self.start_sampler.state_dict() if self.start_sampler is not None else {}),
            **self.failures.state_dict(),
            **(self.getup.state_dict() if self.getup is not None else {}),
        }
        if self.amp_trainer is not None:
            assert self.amp_history is not None
            sd["amp"] = {"history": self.amp_history.buf.clone(), "trainer": self.amp_trainer.state_dict()}
        sd.update(save_sim_state(self.sim))
        return sd

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not an ImitationEnv state (format {state.get('format')!r})")
        if int(state["num_envs"]) != self.num_envs:
            raise ValueError(f"state has {state['num_envs']} envs, this env {self.num_envs}")
        if list(state["clip_names"]) != list(self.library.clip_names):
            raise ValueError("the saved env state was made with a different motion set")
        dev = self.device
        self._gen.set_state(state["generator"].clone())
        self.clip_ids = state["clip_ids"].to(dev).clone()
        self.start_time = state["start_time"].to(dev).clone()
        self.book.load_state_dict({"steps": state["progress"], "returns": state["ep_return"]})
        if "recovery_left" in state:
            self.recovery_left = state["recovery_left"].to(dev).clone()
        if "root_dist" in state:
            self.root_dist = state["root_dist"].to(dev).clone()
        self._noise_due = bool(state.get("noise_due", False))
        self._steps_seen = int(state.get("steps_seen", 0))
        if self.params.termination_curriculum is not None:
            self.termination = replace(
                self.termination, threshold=curriculum_threshold(self.params.termination_curriculum, self._final_threshold, self._steps_seen)
            )
        if self.start_sampler is not None:
            self.start_sampler.load_state_dict(state)
        if int(state.get("noise_draw", 0)) != self._noise_draw:
            self._noise_draw = int(state.get("noise_draw", 0))
            self._draw_noise()
        self.failures.load_state_dict(state)
        if self.getup is not None:
            self.getup.load_state_dict(state)
        if self.amp_trainer is not None:
            assert self.amp_history is not None
            if "amp" not in state:
                raise ValueError("the saved env state has no AMP discriminator state, but params.amp is on")
            if tuple(state["amp"]["history"].shape) != tuple(self.amp_history.buf.shape):
                raise ValueError("the saved AMP history has a different shape (history length or features)")
            self.amp_history.buf = state["amp"]["history"].clone()
            self.amp_trainer.load_state_dict(state["amp"]["trainer"])
        load_sim_state(self.sim, torch.arange(self.num_envs), state, dev)
        self._obs = self._observe(self.sim.state)

    def current_obs(self) -> Tensor:
        """(N, O) the observation the next :meth:`step` acts on."""
        if self._obs is None:
            raise RuntimeError("call reset() first")
        return self._obs.clone()


_HUMANOID_FIELDS = HUMANOID_FIELDS


def _assign_rows(dst: HumanoidState, ids: Tensor, src: HumanoidState) -> None:
    """``dst[ids] = src`` for every tensor field with rows."""
    shared = {f.name for f in dataclasses.fields(dst)} & {f.name for f in dataclasses.fields(src)}
    for name in [n for n in (*_HUMANOID_FIELDS, "clip_ids", "times") if n in shared]:  # the fields both states have
        d, s = getattr(dst, name), getattr(src, name)
        if isinstance(d, Tensor) and isinstance(s, Tensor) and d.dim() > 0 and d.numel():
            d[ids] = s.to(d)


def _reward_terms(p: "PHCParams") -> RewardTerms:
    """The env's reward terms (``p.reward_term_weights()``) with the spec's ``reward_terms`` weights."""
    weights = p.reward_term_weights()
    absent = sorted(set(p.reward_terms) - set(weights))
    if absent:
        needs = {"amp": "amp: true", "point": "recovery_goal.reward: point"}
        why = "; ".join(f"'{n}' needs {needs[n]}" for n in absent if n in needs)
        raise ValueError(
            f"phc.reward_terms: term(s) {', '.join(absent)} not in this configuration (its terms: {', '.join(weights)}; "
            f"all terms: {', '.join(REWARD_TERMS)}){'; ' + why if why else ''}"
        )
    return RewardTerms(weights, p.reward_terms, owner="phc.reward_terms")


__all__ = ["ActionMap", "ImitationEnv", "PHCObservation", "PolicyImitator", "hard_negative_weights", "pd_offset_scale"]
