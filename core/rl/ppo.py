"""Proximal Policy Optimization (Schulman et al. 2017, arXiv:1707.06347) on a :class:`~mocap.rl.env.VecEnv`.

Read top to bottom: the loss math as small pure functions (each citing its formula), then
:class:`PPOTrainer` (rollout → GAE → minibatch epochs → log → checkpoint). The parameters are in
:mod:`mocap.rl.ppo_params` (re-exported here): their defaults are the CPU recipe that learned a
DeepMimic walk on 2 cores, and each description gives PHC's value (rl_games config) where it differs.

Checkpoint ``<workdir>/ppo.pt`` holds everything needed to continue bit-exactly on the same
device: network, optimizer, normalizers, ``env.state_dict()``, the env's current observation,
torch/numpy/python RNG states, counters and the episode-statistics window. A run resumed from it
produces the same weights as an uninterrupted one. The final policy goes to
``<workdir>/policy.pt`` (:func:`mocap.rl.networks.save_policy`; load with ``load_policy``).

Data-parallel (under torchrun, :mod:`mocap.distributed`): every rank steps its own ``num_envs``
envs (its own seed), so one iteration collects ``world_size × num_envs × horizon`` samples and the
budget ``total_env_steps`` counts all ranks' samples (fewer iterations). Each rank computes the
loss on its own minibatches (``minibatch_size`` per rank); gradients are averaged over ranks
before the clip and the step, so the weights stay identical. Advantages are standardized with
the mean/std of all ranks' batches; the observation (and value) normalizer statistics are merged
exactly; the KL of the adaptive schedule is the ranks' mean. Rank 0 writes ``ppo.pt`` with every
rank's env, observation, RNG state and episode window (``rank_states``), so each rank resumes its
own stream; ranks the checkpoint lacks (more processes than before) start from fresh envs.
"""

from __future__ import annotations

import math
import time
from collections import deque
from typing import Any, Callable

import numpy as np
import torch
from torch import Tensor

from mocap import distributed as dist
from mocap.checkpoint import save_checkpoint
from mocap.faults import FaultGuard
from mocap.interfaces import Box, MultiDiscrete, StageResult, Trainer
from mocap.progress import IterationProgress
from mocap.rl.env import AfterIteration, OnDevice
from mocap.rl.networks import ActorCritic, init_from_policy, save_policy
from mocap.rng import rng_state
from mocap import trainer_scaffold as scaffold
from mocap.rl.ppo_params import DEFAULT_LOG_STD, PPOParams, adapt_lr, initial_log_std

CHECKPOINT_FORMAT = "mocap.rl.ppo/1"
CHECKPOINT_NAME = "ppo.pt"
POLICY_NAME = "policy.pt"
EPISODE_WINDOW = 100


# ------------------------------------------------------------------------------------ the math
def compute_gae(
    rewards: Tensor,
    values: Tensor,
    next_values: Tensor,
    terminated: Tensor,
    dones: Tensor,
    gamma: float,
    lam: float,
) -> tuple[Tensor, Tensor]:
    """Generalized advantage estimation (Schulman et al. 2016, arXiv:1506.02438, eq. 16).

    All inputs are (T, N) over T steps of N envs:

    * ``values[t]`` = V(s_t);
    * ``next_values[t]`` = V(s'_t), the state the step reached *before* any auto-reset: the
      value of ``final_obs`` for envs that finished at step t, else V(s_{t+1});
    * ``terminated[t]``: the episode ended by failure/success, so V(s'_t) is not used;
    * ``dones[t]`` = terminated or truncated: the advantage recursion stops there.

    ::

        δ_t = r_t + γ (1 − term_t) V(s'_t) − V(s_t)
        A_t = δ_t + γ λ (1 − done_t) A_{t+1}           (A_T = 0)
            = Σ_{l=0}^{k} (γλ)^l δ_{t+l},   k = steps to the episode end (or the rollout end)

    A truncated (time-limit) episode therefore bootstraps from V(final_obs); a terminated one
    does not. Returns ``(advantages, returns)`` with ``returns = advantages + values`` (the
    TD(λ) value targets).
    """
    not_term = 1.0 - terminated.to(rewards.dtype)
    not_done = 1.0 - dones.to(rewards.dtype)
    deltas = rewards + gamma * not_term * next_values - values
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(rewards[0])
    for t in range(rewards.shape[0] - 1, -1, -1):
        last = deltas[t] + gamma * lam * not_done[t] * last
        advantages[t] = last
    return advantages, advantages + values


def clipped_surrogate(ratio: Tensor, advantages: Tensor, clip: float) -> Tensor:
    """PPO's clipped surrogate objective per sample (Schulman et al. 2017, eq. 7), to maximize::

        L^CLIP = min(r A, clip(r, 1 − ε, 1 + ε) A),   r = π(a|s) / π_old(a|s)

    It is a pessimistic bound: never above the unclipped ``r A``.
    """
    return torch.minimum(ratio * advantages, ratio.clamp(1.0 - clip, 1.0 + clip) * advantages)


def value_loss(values: Tensor, old_values: Tensor, returns: Tensor, clip: float | None = None) -> Tensor:
    """Mean squared value error ``½ (V − R)²``; with ``clip`` = ε the PPO2 clipped form::

        ½ max((V − R)², (V_old + clip(V − V_old, −ε, ε) − R)²)

    (value clipping as in OpenAI baselines' ppo2; PHC does not clip values).
    """
    err = (values - returns).square()
    if clip is not None:
        clipped = old_values + (values - old_values).clamp(-clip, clip)
        err = torch.maximum(err, (clipped - returns).square())
    return 0.5 * err.mean()


def bounds_loss(mean: Tensor, soft_bound: float) -> Tensor:
    """Per-sample penalty on a Gaussian mean leaving ``[−b, b]`` (rl_games' bound loss, used by PHC)::

        Σ_i max(μ_i − b, 0)² + min(μ_i + b, 0)²

    Zero inside the bound, quadratic outside. Returns (B,).
    """
    high = (mean - soft_bound).clamp(min=0.0).square()
    low = (mean + soft_bound).clamp(max=0.0).square()
    return (high + low).sum(-1)


def explained_variance(pred: Tensor, target: Tensor) -> float:
    """``1 − Var(target − pred) / Var(target)`` (1: perfect, 0: no better than a constant)."""
    var = target.var(unbiased=False)
    return float("nan") if var == 0 else float(1.0 - (target - pred).var(unbiased=False) / var)


# -------------------------------------------------------------------------------------- trainer
class PPOTrainer(Trainer):
    """Trains an :class:`ActorCritic` on ``ctx.make_rl_env(num_envs)`` with PPO; resumes from ``ppo.pt``."""

    data_parallel = True  # runs on every rank under torchrun (module docstring)

    def __init__(self, params: PPOParams | None = None, init_model: Callable[[ActorCritic], None] | None = None):
        """``init_model``: called on the freshly built model of a fresh run (not on a resume, where
        ``ppo.pt`` overwrites it), e.g. a trainer running PPO as a sub-phase that starts it from
        another policy's weights (PMCP's copied primitives, its composer's bias)."""
        self.params = params or PPOParams()
        self.init_model = init_model

    # ----------------------------------------------------------------------------- building
    def build_model(self, obs_dim: int, action_space: Any) -> ActorCritic:
        """The actor-critic of the params (no weights loaded; :meth:`run` applies ``init_model``)."""
        p = self.params
        return ActorCritic(
            obs_dim,
            action_space,
            actor_hidden=p.actor_hidden,
            critic_hidden=p.critic_hidden,
            activation=p.activation,
            log_std_init=initial_log_std(p.log_std_init, action_space),
            learn_std=p.learn_std,
            normalize_obs=p.normalize_obs,
            obs_clip=p.obs_clip,
            normalize_value=p.normalize_value,
        )

    # -------------------------------------------------------------------------------- run
    def run(self, ctx: Any) -> StageResult:
        p = self.params
        ckpt_path, device = scaffold.begin(ctx, p.torch_threads, CHECKPOINT_NAME)
        workdir = ckpt_path.parent
        env = ctx.make_rl_env(p.num_envs)
        if env.num_envs != p.num_envs:
            raise ValueError(f"the env has {env.num_envs} envs, PPO asked for {p.num_envs}")
        space = env.action_space
        model = self.build_model(env.obs_dim, space).to(device)
        fresh = not ckpt_path.is_file()
        if fresh and self.init_model is not None:
            self.init_model(model)
        if fresh and p.init_policy is not None:
            init_from_policy(model, p.init_policy, p.init_log_std, p.init_policy_repeat_tail)
            ctx.console.print(f"ppo: starting from {p.init_policy}")
        parallel, world = dist.active(), dist.world_size()
        dist.broadcast_module(model)  # data-parallel: every rank starts from rank 0's weights
        optimizer = torch.optim.Adam([q for q in model.parameters() if q.requires_grad], lr=p.start_lr(fresh))
        window: dict[str, deque[float]] = {}

        iteration, env_steps = 0, 0
        guard = FaultGuard(p.max_consecutive_faults, "ppo")
        ck = scaffold.resume_from(ctx, ckpt_path, CHECKPOINT_FORMAT, "PPO", map_location=device)
        if ck is not None:
            model.load_state_dict(ck["model"])
            optimizer.load_state_dict(ck["optimizer"])
            if p.lr_schedule == "constant":  # the spec's rate, not the one saved by a run with another schedule
                for group in optimizer.param_groups:
                    group["lr"] = p.lr
            mine = _own_state(ck, dist.rank())
            if mine is not None:
                env.load_state_dict(mine["env"])
                obs = mine["obs"].to(device)
            else:  # a rank the checkpoint did not have: fresh envs of its own seed
                obs = env.reset().to(device)
            iteration, env_steps = int(ck["iteration"]), int(ck["env_steps"])
            if mine is not None:
                window = {k: deque(v, maxlen=EPISODE_WINDOW) for k, v in mine["episode_window"].items()}
            guard.load_state_dict(ck.get("faults", {}))
            scaffold.resumed(ctx, "ppo", iteration, mine["rng"] if mine is not None else None, f"iteration {iteration} ({env_steps:,} env steps)")
            if int(ck.get("world_size", 1)) != world:
                ctx.console.print(f"ppo: the checkpoint was written by {int(ck.get('world_size', 1))} process(es), resuming with {world}")
        else:
            obs = env.reset().to(device)
            if p.normalize_obs and p.init_policy is None:  # first statistics from the initial states (of all ranks)
                dist.sync_normalizers(model.obs_norm, lambda: model.obs_norm.update(obs))
        # the budget counts every rank's samples; alone this is p.iterations
        iterations = iteration + max(0, math.ceil((p.total_env_steps - env_steps) / (p.batch_size * world)))

        env_device = torch.device(env.device if isinstance(env, OnDevice) else "cpu")  # actions go back to the env's device
        low = high = None
        if isinstance(space, Box) and (math.isfinite(space.low) or math.isfinite(space.high)):
            low, high = space.low, space.high
        act_shape = (len(space.nvec),) if isinstance(space, MultiDiscrete) else tuple(space.shape)
        act_dtype = torch.long if isinstance(space, MultiDiscrete) else torch.float32
        T, N = p.horizon, p.num_envs
        last_stats: dict[str, float] = {}
        last_eval: dict[str, float] = {}  # the latest value of each eval/ metric (the env's periodic or per-iteration evaluation)
        t_start = time.perf_counter()
        steps_at_start = env_steps

        def save(final: bool = False) -> None:
            extra: dict[str, Any] = {}
            if parallel:  # every rank's own stream goes into rank 0's checkpoint
                states = dist.gather_object(
                    {
                        "env": env.state_dict(),
                        "obs": obs.detach().cpu(),
                        "rng": rng_state(),
                        "episode_window": {k: list(v) for k, v in window.items()},
                    }
                )
                if states is None:  # not rank 0: nothing to write
                    return
                extra = {"world_size": world, "rank_states": {r: st for r, st in enumerate(states) if r > 0}}
            save_checkpoint(
                ckpt_path,
                {
                    "format": CHECKPOINT_FORMAT,
                    "iteration": iteration,
                    "env_steps": env_steps,
                    "model": model.state_dict(),
                    "policy_config": model.config,
                    "optimizer": optimizer.state_dict(),
                    "env": env.state_dict(),
                    "obs": obs.detach().cpu(),
                    "rng": rng_state(),
                    "episode_window": {k: list(v) for k, v in window.items()},
                    "faults": guard.state_dict(),
                    "params": p.model_dump(mode="json"),
                    "finished": final,
                    **extra,
                },
                spec_yaml=ctx.spec_yaml(),
            )

        progress = IterationProgress(
            ctx.console,
            iterations,
            p.print_every,
            "ppo",
            [("episode/return", "return", ".3g"), ("episode/length", "len", ".1f"), ("episode/success", "success", ".2f")],
        )
        try:
            while iteration < iterations:
                # ---------------------------------------------------------------- rollout
                t0 = time.perf_counter()
                if p.lr_schedule == "linear":
                    for group in optimizer.param_groups:
                        group["lr"] = p.lr * (1.0 - iteration / iterations)
                b_obs = torch.zeros((T, N, env.obs_dim), device=device)
                b_act = torch.zeros((T, N, *act_shape), dtype=act_dtype, device=device)
                b_logp = torch.zeros((T, N), device=device)
                b_val = torch.zeros((T, N), device=device)
                b_rew = torch.zeros((T, N), device=device)
                b_next_val = torch.zeros((T, N), device=device)
                b_term = torch.zeros((T, N), dtype=torch.bool, device=device)
                b_done = torch.zeros((T, N), dtype=torch.bool, device=device)
                info_sums: dict[str, float] = {}
                finished = 0
                model.eval()
                with torch.no_grad():
                    for t in range(T):
                        b_obs[t] = obs
                        action, logp, value = model.act(obs)
                        b_act[t], b_logp[t], b_val[t] = action, logp, value
                        env_action = action if low is None else action.clamp(low, high)
                        res = env.step(env_action.to(env_device))
                        obs = res.obs.to(device).float()
                        b_rew[t] = res.reward.to(device)
                        term = res.terminated.to(device).bool()
                        trunc = res.truncated.to(device).bool() & ~term
                        b_term[t], b_done[t] = term, term | trunc
                        if t > 0:
                            b_next_val[t - 1] = torch.where(b_done[t - 1], b_next_val[t - 1], value)
                        if trunc.any():  # bootstrap time-limit truncations from V(final_obs)
                            b_next_val[t, trunc] = model.value(res.final_obs.to(device).float()[trunc])
                        for key, val in res.episodes.items():
                            vals = val.detach().float().cpu().tolist()
                            window.setdefault(key, deque(maxlen=EPISODE_WINDOW)).extend(vals)
                        finished += int(b_done[t].sum())
                        for key, val in res.info.items():
                            v = float(val.float().mean()) if isinstance(val, Tensor) else float(val)
                            info_sums[key] = info_sums.get(key, 0.0) + v
                    last_value = model.value(obs)
                    b_next_val[T - 1] = torch.where(b_done[T - 1], b_next_val[T - 1], last_value)
                    advantages, returns = compute_gae(b_rew, b_val, b_next_val, b_term, b_done, p.gamma, p.gae_lambda)
                env_steps += T * N * world
                t_rollout = time.perf_counter() - t0

                # ----------------------------------------------------------------- update
                t1 = time.perf_counter()
                stats: dict[str, float] = {}
                # (data-parallel: a non-finite input on any rank makes every rank skip the batch)
                if dist.check_inputs(guard, observations=b_obs, rewards=b_rew, advantages=advantages, returns=returns):
                    stats = self._update(model, optimizer, b_obs, b_act, b_logp, b_val, advantages, returns, guard)
                    if p.normalize_obs:  # after the update, so that rollout and update saw the same statistics

                        def update_obs_norm(x: Tensor = b_obs) -> None:
                            model.obs_norm.update(x)

                        dist.sync_normalizers(model.obs_norm, update_obs_norm)
                t_update = time.perf_counter() - t1
                iteration += 1

                # ---------------------------------------------------------------- logging
                elapsed = time.perf_counter() - t_start
                log = {
                    "env_steps": float(env_steps),
                    **stats,
                    "explained_variance": explained_variance(b_val.flatten(), returns.flatten()),
                    "value_mean": float(b_val.mean()),
                    "return_target_mean": float(returns.mean()),
                    "reward_mean": float(b_rew.mean()),
                    "lr": optimizer.param_groups[0]["lr"],
                    "episodes_finished": float(finished),
                    "time/rollout_s": t_rollout,
                    "time/update_s": t_update,
                    "steps_per_s": T * N / max(t_rollout + t_update, 1e-9),
                    "rollout_steps_per_s": T * N / max(t_rollout, 1e-9),
                    "steps_per_s_run": (env_steps - steps_at_start) / max(elapsed, 1e-9),
                    **guard.take_counts(),
                }
                if model.log_std is not None:
                    log["std"] = float(model.log_std.detach().exp().mean())
                for key, vals in window.items():
                    if vals:
                        log[f"episode/{key}"] = float(np.mean(vals))
                for key, total in info_sums.items():
                    log[f"env/{key}"] = total / T
                if isinstance(env, AfterIteration):  # e.g. periodic evaluation for hard-negative mining

                    def policy_fn(o: Tensor) -> Tensor:
                        model.eval()
                        with torch.no_grad():
                            return model.mean_action(o.to(device).float()).to(env_device)

                    for key, val in (env.after_iteration(iteration, policy_fn) or {}).items():
                        log[f"eval/{key}"] = float(val)
                        last_eval[f"eval/{key}"] = float(val)
                if parallel:  # one line for all ranks: sums, slowest times, means, pooled episode windows
                    log = dist.reduce_metrics(log, sums=("episodes_finished",), maxima=("time/rollout_s", "time/update_s"), windows=window)
                    log["steps_per_s"] = T * N * world / max(log["time/rollout_s"] + log["time/update_s"], 1e-9)
                    log["rollout_steps_per_s"] = T * N * world / max(log["time/rollout_s"], 1e-9)
                ctx.log.log(iteration, **log)
                last_stats = log
                progress.update(iteration, env_steps, log)

                stop = dist.any_true(ctx.should_stop()) if parallel else ctx.should_stop()
                if stop or iteration % p.checkpoint_every == 0 or iteration >= iterations:
                    save(final=iteration >= iterations)
                if stop:
                    ctx.console.print(f"ppo: stopped at iteration {iteration}; checkpoint {ckpt_path}")
                    return StageResult(checkpoint=ckpt_path, metrics=_summary({**last_eval, **last_stats}, iteration, env_steps))
        finally:
            progress.close()
            env.close()

        if not last_stats:  # the checkpoint was already at the end (e.g. a crash before policy.pt)
            last_stats = {f"episode/{k}": float(np.mean(v)) for k, v in window.items() if v}
        metrics = _summary({**last_eval, **last_stats}, iteration, env_steps)
        policy_path = workdir / POLICY_NAME
        if parallel:
            dist.assert_in_sync(model, "ppo")
        if dist.is_main():
            save_policy(policy_path, model, extra={"trainer": "ppo", "metrics": metrics}, spec_yaml=ctx.spec_yaml())
        return StageResult(checkpoint=policy_path, metrics=metrics)

    # ------------------------------------------------------------------------------ update
    def _update(
        self,
        model: ActorCritic,
        optimizer: torch.optim.Optimizer,
        b_obs: Tensor,
        b_act: Tensor,
        b_logp: Tensor,
        b_val: Tensor,
        advantages: Tensor,
        returns: Tensor,
        guard: FaultGuard | None = None,
    ) -> dict[str, float]:
        """``epochs`` passes of shuffled minibatches over the rollout; returns averaged diagnostics
        (a minibatch with a non-finite loss or gradient is skipped by ``guard``)."""
        guard = guard or FaultGuard(0, "ppo")
        p = self.params
        B = b_logp.numel()
        obs = b_obs.reshape(B, -1)
        act = b_act.reshape(B, *b_act.shape[2:])
        old_logp = b_logp.reshape(B)
        adv = advantages.reshape(B)
        ret = returns.reshape(B)
        old_val = b_val.reshape(B)
        if p.normalize_advantage:
            if dist.active():  # data-parallel: standardized over all ranks' samples
                adv_mean, adv_std = dist.global_mean_std(adv)
                adv = (adv - adv_mean) / (adv_std + 1e-8)
            else:
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        if p.normalize_value:
            # the critic regresses standardized targets; statistics updated once per batch (of all ranks)
            dist.sync_normalizers(model.value_norm, lambda: model.value_norm.update(ret))
            ret_t = model.value_norm.normalize(ret)
            old_val_t = model.value_norm.normalize(old_val)
        else:
            ret_t, old_val_t = ret, old_val
        params = [q for q in model.parameters() if q.requires_grad]
        n_mb = B // p.minibatch_size
        sums: dict[str, float] = {}
        done_steps = 0
        model.train()
        for _ in range(p.epochs):
            perm = torch.randperm(B, device=obs.device)
            for i in range(n_mb):
                idx = perm[i * p.minibatch_size : (i + 1) * p.minibatch_size]
                out = model.train_forward(obs[idx], act[idx])
                log_ratio = out.log_prob - old_logp[idx]
                ratio = log_ratio.exp()
                pg_loss = -clipped_surrogate(ratio, adv[idx], p.clip).mean()
                v_loss = value_loss(out.value_raw, old_val_t[idx], ret_t[idx], p.value_clip)
                entropy = out.entropy.mean()
                b_loss = bounds_loss(out.mean, p.soft_bound).mean() if out.mean is not None else pg_loss.new_zeros(())
                loss = pg_loss + p.value_coef * v_loss - p.entropy_coef * entropy + p.bounds_coef * b_loss
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                step_loss, mean_kl = loss, None
                if dist.active():
                    # data-parallel: average gradients (and loss, KL) over the ranks; a non-finite
                    # value on any rank makes the averaged loss/gradient non-finite everywhere
                    with torch.no_grad():
                        local_kl = ((ratio - 1) - log_ratio).mean()
                    step_loss, mean_kl = dist.average_gradients(params, loss, local_kl)
                # global-norm clip (max_grad_norm None: inf, i.e. only measure the norm); skipped if not finite
                stepped, grad_norm = guard.step(optimizer, step_loss, params, p.max_grad_norm)
                if not stepped:
                    continue
                with torch.no_grad():
                    # k3 estimator of KL(π_old || π): E[(r − 1) − log r] (Schulman, "Approximating KL divergence")
                    approx_kl = ((ratio - 1) - log_ratio).mean()
                    clip_frac = ((ratio - 1).abs() > p.clip).float().mean()
                if p.lr_schedule == "adaptive":
                    kl = float(approx_kl) if mean_kl is None else float(mean_kl)
                    for group in optimizer.param_groups:
                        group["lr"] = adapt_lr(group["lr"], kl, p.desired_kl, p.lr_min, p.lr_max)
                for key, val in (
                    ("loss/policy", pg_loss),
                    ("loss/value", v_loss),
                    ("loss/entropy", entropy),
                    ("loss/bounds", b_loss),
                    ("loss/total", loss),
                    ("approx_kl", approx_kl),
                    ("clip_fraction", clip_frac),
                    ("grad_norm", grad_norm),
                ):
                    sums[key] = sums.get(key, 0.0) + float(val.detach() if isinstance(val, Tensor) else val)
                done_steps += 1
        model.eval()
        steps = max(done_steps, 1)
        return {k: v / steps for k, v in sums.items()}


def _own_state(ck: dict[str, Any], rank: int) -> dict[str, Any] | None:
    """This rank's env / observation / RNG / episode-window state in a checkpoint (rank 0: the
    top-level fields, which a single-process run also writes); None when the checkpoint lacks it."""
    if rank == 0:
        return {k: ck[k] for k in ("env", "obs", "rng", "episode_window")}
    return (ck.get("rank_states") or {}).get(rank)


def _summary(stats: dict[str, float], iteration: int, env_steps: int) -> dict[str, float]:
    """The stage's summary metrics (``stages.json``, ``report.md``, comparisons): episode statistics,
    the env's ``eval/`` metrics (a task's ``metrics()``, periodic imitation evaluations) and a few
    learning diagnostics."""
    out = {"iterations": float(iteration), "env_steps": float(env_steps)}
    for key, value in stats.items():
        if key.startswith(("episode/", "eval/")) or key in ("explained_variance", "steps_per_s_run", "approx_kl"):
            out[key] = float(value)
    return out


__all__ = [
    "DEFAULT_LOG_STD",
    "PPOParams",
    "PPOTrainer",
    "adapt_lr",
    "bounds_loss",
    "clipped_surrogate",
    "compute_gae",
    "explained_variance",
    "initial_log_std",
    "value_loss",
]
