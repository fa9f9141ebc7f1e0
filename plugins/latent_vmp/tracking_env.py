"""VMP stage II training environment: :class:`VmpTrackingEnv`, N tracking episodes as a
:class:`mocap.rl.env.VecEnv` (RSI, reference jumps, reward, termination, resume state), on the
shared episode layer (:mod:`mocap.episodes`: the reference starts, the named reward and termination
terms, the episode counters and the end of every step).

Moved out of :mod:`mocap_vmp.tracking` (re-exported there); the design is described in that
module's docstring."""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from mocap.episodes import EpisodeBook, ReferenceStarts, RewardTerms, TerminationTerms
from mocap.observations import proprioception, proprioception_dim
from mocap.rl.env import StepResult
from mocap.skeleton import Skeleton
from mocap.sim_snapshot import load_sim_state, save_sim_state
from mocap.state import HumanoidState, SimState
from mocap_vmp.randomization import DomainRandomizer
from mocap_vmp.tracking_conditioning import VmpConditioning, _action_map, _clean, clip_frames, hold_action
from mocap_vmp.tracking_params import VmpTrackerParams
from mocap_vmp.tracking_reward import (
    TRACK_TERMS,
    end_effector_error,
    persist_steps,
    smoothness_errors,
    state_features,
    tracking_errors,
    update_counter,
    vmp_reward_terms,
    vmp_reward_weights,
)

STATE_FORMAT = "mocap_vmp.tracking_env/1"


# ---------------------------------------------------------------------------------------- env
class VmpTrackingEnv:
    """N VMP tracking episodes (module docstring); a :class:`mocap.rl.env.VecEnv`.

    Args:
        params: :class:`VmpTrackerParams`.
        skeleton, library, simulator: the humanoid, the clips, N envs.
        latent: the trained :class:`~mocap_vmp.latent.VmpLatent` (statistics, encoder).
        seed: seeds the env's generator (RSI and reference jumps).
    """

    def __init__(
        self,
        params: VmpTrackerParams,
        skeleton: Skeleton,
        library: Any,
        simulator: Any,
        latent: Any,
        *,
        seed: int = 0,
    ):
        self.params = p = params
        self.skeleton = skeleton
        self.library = lib = library
        self.sim = simulator
        self.num_envs = N = int(simulator.num_envs)
        self.device = dev = lib.device
        self.dt = float(simulator.dt)
        self.cond = VmpConditioning(p, latent, lib, self.dt)
        self.layout = self.cond.layout
        self.action_map = _action_map(skeleton, p)
        self.action_space = self.action_map.space
        A = self.num_actions = int(self.action_map.offset.numel())
        self.proprio_dim = proprioception_dim(skeleton.num_bodies) + p.prev_actions * A
        self.obs_dim = self.proprio_dim + self.cond.dim
        self.episode_steps = max(1, round(p.episode_length_s / self.dt))
        # start times on the control grid: the reference of every step is a table lookup (MotionLibrary.use_control_grid)
        self.library.use_control_grid(self.dt, self.episode_steps + 2)
        self.persist = persist_steps(p.termination_persist_s, self.dt)
        # n_g of reward_form 'exp': feature dimensions of each tracking group
        self.track_dims = {g: sl.stop - sl.start for g, sl in self.layout.slices.items() if g in TRACK_TERMS}
        self._gen = torch.Generator(device="cpu")
        self._gen.manual_seed(int(seed))
        # RSI and reference jumps; every clip non-looping (at a clip's end the reference jumps or the episode ends)
        self.starts = ReferenceStarts(lib, self.dt, control_grid=True, loops=False)
        # reward: the raw terms of tracking_reward.REWARD_TERMS weighted by the params' VmpRewardWeights
        self.rewards = RewardTerms(vmp_reward_weights(p.reward, p.reward_form), owner="reward")
        self.terminations = TerminationTerms(("ee", "unstable"))
        self.book = EpisodeBook(N, dev)  # steps / returns: the state's "progress" / "ep_return"
        self.clip_ids = torch.zeros(N, dtype=torch.long, device=dev)
        self.target_time = torch.zeros(N, dtype=torch.float64, device=dev)
        self.ee_counter = torch.zeros(N, dtype=torch.long, device=dev)
        self.jumps = torch.zeros(N, dtype=torch.long, device=dev)
        self.hist_actions = torch.zeros(N, 2, A, device=dev)  # raw actions a_{t-1}, a_{t-2}
        self.hist_targets = torch.zeros(N, 2, A, device=dev)  # PD targets of the same steps
        self._ref_feat = torch.zeros(N, self.layout.dim, device=dev)
        self._ref_dof = torch.zeros(N, A, device=dev)
        self._obs: Tensor | None = None
        self.randomizer = DomainRandomizer(p.randomization, simulator, self._gen) if p.randomization is not None else None

    # ----------------------------------------------------------------------------- helpers
    def _observe(self, state: SimState, ids: Tensor | None = None) -> Tensor:
        """Observations of envs ``ids`` (all when None) at their current target time; caches the target's features."""
        c = self.clip_ids if ids is None else self.clip_ids[ids]
        t = self.target_time if ids is None else self.target_time[ids]
        st = state if ids is None else state.index(ids)
        ref = clip_frames(self.library, c, t)
        cond, feat = self.cond(ref, c, t)
        hist = self.hist_actions if ids is None else self.hist_actions[ids]
        obs = self.assemble(st, hist, cond)
        rows = slice(None) if ids is None else ids
        self._ref_feat[rows] = feat.to(self._ref_feat)
        self._ref_dof[rows] = ref.dof_pos.to(self._ref_dof)
        return obs

    def assemble(self, state: HumanoidState, hist_actions: Tensor, cond: Tensor) -> Tensor:
        parts = [_clean(proprioception(state, self.params.sixd))]
        if self.params.prev_actions:
            parts.append(hist_actions[:, : self.params.prev_actions].reshape(hist_actions.shape[0], -1).float())
        parts.append(_clean(cond))
        return torch.cat(parts, -1)

    def _reset_envs(self, ids: Tensor) -> None:
        n = int(ids.numel())
        if n == 0:
            return
        clips, t0 = self.starts.sample(n, self._gen)
        self.clip_ids[ids] = clips
        self.target_time[ids] = t0 + self.dt
        self.book.start(ids)
        self.ee_counter[ids] = 0
        self.jumps[ids] = 0
        if self.randomizer is not None:
            self.randomizer.on_reset(ids.cpu())
        self.sim.reset(ids, self.library.frames(clips, t0))
        q = self.sim.state.dof_pos[ids].to(self.hist_actions)
        self.hist_actions[ids] = hold_action(self.action_map, q)[:, None, :].expand(n, 2, -1)
        self.hist_targets[ids] = q[:, None, :].expand(n, 2, -1)

    # ---------------------------------------------------------------------------- VecEnv
    def reset(self) -> Tensor:
        self._reset_envs(torch.arange(self.num_envs, device=self.device))
        self._obs = self._observe(self.sim.state)
        return self._obs.clone()

    def step(self, actions: Tensor) -> StepResult:
        if self._obs is None:
            raise RuntimeError("call reset() (or load_state_dict) before step()")
        p, N = self.params, self.num_envs
        a = torch.as_tensor(actions, device=self.device).float()
        if tuple(a.shape) != (N, self.num_actions):
            raise ValueError(f"actions must be ({N}, {self.num_actions}), got {tuple(a.shape)}")
        if p.action_clip is not None:
            a = a.clamp(-p.action_clip, p.action_clip)
        targets = self.action_map(a, self._ref_dof)
        if self.randomizer is not None:
            self.randomizer.before_step()
        state = self.sim.step(targets)
        self.book.tick()

        layout, cond = self.layout, self.cond
        sim_feat = state_features(state, cond.ee_index).to(self._ref_feat)
        track = tracking_errors(
            cond.reward_standardize(self._ref_feat),
            cond.reward_standardize(sim_feat),
            layout,
        )
        x, hist = (targets, self.hist_targets) if p.smoothness_on == "targets" else (a, self.hist_actions)
        tau = state.dof_force.to(a) if state.dof_force.numel() else state.dof_force
        smooth = smoothness_errors(x.float(), hist[:, 0], hist[:, 1], tau)
        terms = vmp_reward_terms(track, smooth, p.reward_form, self.track_dims, p.exp_scale)
        ps = layout.slices["p"]
        ee_err = end_effector_error(self._ref_feat[:, ps], sim_feat[:, ps], p.termination_norm)
        ee_err = torch.nan_to_num(ee_err, nan=math.inf)
        self.ee_counter, fired = update_counter(self.ee_counter, ee_err, p.termination_threshold, self.persist)
        unstable = state.unstable.to(self.device).bool() if state.unstable.numel() else torch.zeros(N, dtype=torch.bool, device=self.device)
        # a reward that is not finite (after the only_positive clip) marks the env unstable: it ends the episode
        total = self.rewards.weighted_sum(terms)
        unstable = unstable | ~torch.isfinite(total.clamp_min(0.0) if p.only_positive_rewards else total)
        reward, reward_info = self.rewards.zero_invalid(total, unstable), self.rewards.info(terms)  # float64, 0 where unstable
        if p.only_positive_rewards:
            reward = reward.clamp_min(0.0)
        terminated, term_info = self.terminations({"ee": fired, "unstable": unstable})
        self.hist_actions = torch.stack((a, self.hist_actions[:, 0]), 1)
        self.hist_targets = torch.stack((targets.float(), self.hist_targets[:, 0]), 1)
        dq = (self._ref_dof - state.dof_pos.to(self._ref_dof)).abs().mean(-1)

        # the reference advances one step; at a clip's end it jumps (no simulator reset) or the episode ends
        self.target_time += self.dt
        clip_over = self.starts.clip_over(self.clip_ids, self.target_time)
        truncated = self.book.steps >= self.episode_steps
        if p.reference_jump:
            jump = clip_over & ~terminated & ~truncated
            if bool(jump.any()):
                ids = jump.nonzero().squeeze(-1)
                clips, t = self.starts.sample(int(ids.numel()), self._gen)
                self.clip_ids[ids] = clips
                self.target_time[ids] = t
                self.jumps[ids] += 1
        else:
            truncated = truncated | clip_over
        info: dict[str, Any] = {
            **{k: v.float() for k, v in reward_info.items()},
            "error/ee_max_m": torch.nan_to_num(ee_err, posinf=0.0),
            "error/joint_mae_deg": torch.nan_to_num(dq, nan=0.0) * (180.0 / math.pi),
            **term_info,
            "reference_jumps": clip_over.float(),
        }

        def observe(ids: Tensor | None) -> Tensor:
            return self._observe(state) if ids is None else self._observe(self.sim.state, ids)

        res = self.book.conclude(reward, terminated, truncated, observe, self._reset_envs, info=info, count_step=False)
        self._obs = res.obs.clone()
        return res

    def close(self) -> None:
        self.sim.close()

    def current_obs(self) -> Tensor:
        if self._obs is None:
            raise RuntimeError("call reset() first")
        return self._obs.clone()

    # -------------------------------------------------------------------------- resume
    def state_dict(self) -> dict[str, Any]:
        """RNG, per-env counters and action history, and the simulator's physics state."""
        if self._obs is None:
            raise RuntimeError("state_dict() before reset()")
        sd: dict[str, Any] = {
            "format": STATE_FORMAT,
            "num_envs": self.num_envs,
            "clip_names": list(self.library.clip_names),
            "generator": self._gen.get_state().clone(),
            **{k: getattr(self, k).cpu().clone() for k in _COUNTERS},
            "progress": self.book.steps.cpu().clone(),
            "ep_return": self.book.returns.cpu().clone(),
        }
        sd.update(save_sim_state(self.sim))
        if self.randomizer is not None:
            sd["randomization"] = self.randomizer.state_dict()
        return sd

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a VmpTrackingEnv state (format {state.get('format')!r})")
        if int(state["num_envs"]) != self.num_envs:
            raise ValueError(f"state has {state['num_envs']} envs, this env {self.num_envs}")
        if list(state["clip_names"]) != list(self.library.clip_names):
            raise ValueError("the saved env state was made with a different motion set")
        self._gen.set_state(state["generator"].clone())
        for k in _COUNTERS:
            setattr(self, k, state[k].to(self.device).clone())
        self.book.load_state_dict({"steps": state["progress"], "returns": state["ep_return"]})
        load_sim_state(self.sim, torch.arange(self.num_envs), state, self.device)
        if self.randomizer is not None and "randomization" in state:
            self.randomizer.load_state_dict(state["randomization"])
        self._obs = self._observe(self.sim.state)


# per-env state besides the episode book's (saved as "progress" and "ep_return")
_COUNTERS = (
    "clip_ids",
    "target_time",
    "ee_counter",
    "jumps",
    "hist_actions",
    "hist_targets",
)
