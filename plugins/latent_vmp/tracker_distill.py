"""Warm start of VMP's tracking policy by online distillation (DAgger) from a trained imitator.

Not in VMP (Serifi et al. 2024, Sec. 3.2 trains the tracker by RL alone, from random weights); the
``vmp_track`` trainer runs it before PPO when its ``distill`` params are set
(:class:`~mocap_vmp.vmp_params.TrackerDistillParams`). Why: on two CPU cores the tracker trained by
PPO alone held 5 of 15 clips after 15M env steps (``checkpoints/vmp_amp_v2``), while the PHC
imitator of the same humanoid holds 14 of 15 after far more; the latent spaces PULSE and the hybrid
RVQ are distilled from that imitator too, so a distilled tracker makes the three comparable.

**Student**: the tracker's own :class:`~mocap.rl.networks.ActorCritic` (PPO's architecture and
observation: proprioception, previous actions and the VMP conditioning ``c_t``). **Teacher**: the
spec's trained imitator (any :class:`~mocap.interfaces.Imitator` of one reference frame, e.g. PHC).
Each env step of :class:`~mocap_vmp.tracking_env.VmpTrackingEnv`::

    ref     = the reference at the step's target time (the env's clip and time)
    label   = action_map.inverse(teacher.to_pd_targets(o, teacher.policy_output(o)), ref.dof_pos),
              o = teacher.observe(state, ref)       (the teacher's PD targets in the tracker's action space)
    action  = label with probability beta, else the student's mean action     (DAgger's beta_i)

``beta`` anneals linearly over the budget (``beta[0]`` -> ``beta[1]``). Every iteration
(``num_envs`` x ``horizon`` steps) updates the observation normalizer, then takes ``epochs`` passes
of minibatches minimizing ``|mu(s) - label|^2`` (mean over action dims) plus, with ``value_coef`` >
0, ``value_coef * (V(s) - R)^2`` with ``R`` the TD(lambda) return of the tracking reward under the
current critic (the ppo params' gamma and lambda; truncated episodes bootstrap from their final
observation), so that PPO's first updates start from a critic of the distilled policy.

The env used here never jumps the reference to another clip at a clip's end (``reference_jump``
is forced off, the episode is truncated instead): the teacher's goal is the reference's global
pose, so a jump to another clip's frame elsewhere in the world would be a goal the teacher never saw.

Files (``<workdir>``): ``distill.pt`` (resumable: model, optimizer, counters, env state incl.
physics, RNG states) and, at the end, ``policy.pt`` (:func:`~mocap.rl.networks.save_policy`), which
the trainer hands to PPO as its initial weights.
"""

from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mocap import trainer_scaffold as scaffold
from mocap.checkpoint import save_checkpoint
from mocap.interfaces import Imitator
from mocap.progress import IterationProgress
from mocap.rl.networks import ActorCritic, save_policy
from mocap.rng import rng_state
from mocap_vmp.tracking_conditioning import clip_frames
from mocap_vmp.vmp_params import TrackerDistillParams

FORMAT = "mocap_vmp.tracker_distill/1"
CHECKPOINT_NAME = "distill.pt"
POLICY_NAME = "policy.pt"


def mixture_beta(params: TrackerDistillParams, progress: float) -> float:
    """DAgger's beta at ``progress`` in [0, 1]: linear from ``beta[0]`` to ``beta[1]``."""
    b0, b1 = params.beta
    x = min(max(float(progress), 0.0), 1.0)
    return b0 + (b1 - b0) * x


def distill_lr(params: TrackerDistillParams, progress: float) -> float:
    """The learning rate at ``progress``: linear from ``lr`` to ``lr_end``."""
    x = min(max(float(progress), 0.0), 1.0)
    return params.lr + (params.lr_end - params.lr) * x


def td_lambda_returns(rewards: Tensor, next_values: Tensor, terminated: Tensor, done: Tensor, gamma: float, lam: float) -> Tensor:
    """TD(lambda) returns of a (T, N) chunk: ``R_t = r_t + gamma (1 - term_t) [(1 - lambda') V(s'_t) + lambda' R_{t+1}]``
    with ``lambda' = 0`` where the episode ended at ``t`` (``done``: terminated or truncated) and ``R_T``
    the last step's bootstrap; ``next_values`` (T, N) is ``V`` of the observation each step reached
    (the final one of a finished episode; ignored where it terminated)."""
    if not (rewards.shape == next_values.shape == terminated.shape == done.shape):
        raise ValueError("rewards, next_values, terminated and done must share their (T, N) shape")
    T = rewards.shape[0]
    out = torch.zeros_like(rewards)
    ahead = next_values[-1]
    for t in range(T - 1, -1, -1):
        cont = (~done[t]).to(rewards)
        boot = (1.0 - lam * cont) * next_values[t] + lam * cont * ahead
        ahead = rewards[t] + gamma * (~terminated[t]).to(rewards) * boot
        out[t] = ahead
    return out


class TrackerDistiller:
    """Runs the distillation of ``teacher`` into ``model`` on ``env`` (module docstring)."""

    def __init__(self, params: TrackerDistillParams, gamma: float, lam: float):
        self.params = params
        self.gamma = float(gamma)
        self.lam = float(lam)

    def run(self, ctx: Any, env: Any, teacher: Imitator, model: ActorCritic) -> Path | None:
        """Distil; returns ``<workdir>/policy.pt``, or None when stopped (Ctrl-C: ``distill.pt`` resumes)."""
        p = self.params
        ckpt_path, device = scaffold.begin(ctx, p.torch_threads, CHECKPOINT_NAME)
        policy_path = ckpt_path.parent / POLICY_NAME
        if policy_path.is_file():
            return policy_path
        if teacher.reference_steps != 1:
            raise ValueError(f"the teacher observes {teacher.reference_steps} reference frames; distil from a one-frame imitator")
        model = model.to(device)
        optimizer = torch.optim.Adam([q for q in model.parameters() if q.requires_grad], lr=p.lr)
        gen = torch.Generator().manual_seed(int(ctx.seed) + 7)
        batch = p.num_envs * p.horizon
        iterations = max(1, math.ceil(p.total_env_steps / batch))
        iteration = env_steps = 0
        window: dict[str, deque[float]] = {}
        ck = scaffold.resume_from(ctx, ckpt_path, FORMAT, "tracker distillation", map_location=device)
        if ck is not None:
            model.load_state_dict(ck["model"])
            optimizer.load_state_dict(ck["optimizer"])
            env.load_state_dict(ck["env"])
            gen.set_state(ck["generator"])
            iteration, env_steps = int(ck["iteration"]), int(ck["env_steps"])
            scaffold.resumed(ctx, "tracker distillation", iteration, ck["rng"], f"iteration {iteration} ({env_steps:,} env steps)")
            obs = env.current_obs().to(device)
        else:
            obs = env.reset().to(device)
            model.obs_norm.update(obs)

        def save(final: bool = False) -> None:
            save_checkpoint(
                ckpt_path,
                {
                    "format": FORMAT,
                    "model": model.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "env": env.state_dict(),
                    "generator": gen.get_state(),
                    "rng": rng_state(),
                    "iteration": iteration,
                    "env_steps": env_steps,
                    "params": p.model_dump(mode="json"),
                    "finished": final,
                },
                spec_yaml=ctx.spec_yaml(),
            )

        progress = IterationProgress(
            ctx.console,
            iterations,
            p.print_every,
            "tracker distill",
            [("loss/action", "action mse", ".4f"), ("episode/length", "len", ".1f"), ("beta", "beta", ".2f")],
        )
        log: dict[str, float] = {}
        try:
            while iteration < iterations:
                t0 = time.perf_counter()
                prog = env_steps / max(1, iterations * batch)
                beta = mixture_beta(p, prog)
                for group in optimizer.param_groups:
                    group["lr"] = distill_lr(p, prog)
                chunk = self._rollout(env, teacher, model, obs, beta, gen, window, device)
                obs = chunk["next_obs"]
                t1 = time.perf_counter()
                stats = self._update(model, optimizer, chunk, gen)
                iteration += 1
                env_steps += batch
                log = {
                    **stats,
                    "beta": beta,
                    "lr": distill_lr(p, prog),
                    "steps_per_s": batch / max(time.perf_counter() - t0, 1e-9),
                    "time/rollout_s": t1 - t0,
                    **{f"episode/{k}": sum(v) / len(v) for k, v in window.items() if v},
                }
                ctx.log.log(iteration, **log)
                progress.update(iteration, env_steps, log)
                stop = ctx.should_stop()
                if stop or iteration % p.checkpoint_every == 0 or iteration >= iterations:
                    save(final=iteration >= iterations)
                if stop:
                    ctx.console.print(f"tracker distill: stopped at iteration {iteration}; checkpoint {ckpt_path}")
                    return None
        finally:
            progress.close()
        summary = {**log, "env_steps": float(env_steps), "iterations": float(iteration)}
        save_policy(policy_path, model, extra={"trainer": "vmp_tracker_distill", "metrics": summary}, spec_yaml=ctx.spec_yaml())
        return policy_path

    # ------------------------------------------------------------------------------ rollout
    def _rollout(
        self, env: Any, teacher: Imitator, model: ActorCritic, obs: Tensor, beta: float, gen: torch.Generator, window: dict[str, deque[float]], device: Any
    ) -> dict[str, Tensor]:
        p = self.params
        T, N = p.horizon, env.num_envs
        obs_l, lab_l, rew_l, term_l, done_l, final_l = [], [], [], [], [], []
        model.eval()
        for _ in range(T):
            ref = clip_frames(env.library, env.clip_ids, env.target_time)
            with torch.no_grad():
                t_obs = teacher.observe(env.sim.state, ref)
                targets = teacher.to_pd_targets(t_obs, teacher.policy_output(t_obs, deterministic=True))
                label = env.action_map.inverse(targets.float().cpu(), ref.dof_pos.float().cpu()).to(device)
                student = model.mean_action(obs)
            use_teacher = (torch.rand(N, generator=gen) < beta).to(device)
            action = torch.where(use_teacher[:, None], label, student)
            res = env.step(action)
            obs_l.append(obs)
            lab_l.append(label)
            rew_l.append(res.reward.to(device).float())
            term_l.append(res.terminated.to(device).bool())
            done_l.append((res.terminated | res.truncated).to(device).bool())
            final_l.append(res.final_obs.to(device).float())
            for k, v in res.episodes.items():
                window.setdefault(k, deque(maxlen=100)).extend(float(x) for x in v.reshape(-1))
            obs = res.obs.to(device).float()
        model.train()
        return {
            "obs": torch.stack(obs_l),
            "label": torch.stack(lab_l),
            "reward": torch.stack(rew_l),
            "terminated": torch.stack(term_l),
            "done": torch.stack(done_l),
            "final_obs": torch.stack(final_l),
            "next_obs": obs,
        }

    # ------------------------------------------------------------------------------- update
    def _update(self, model: ActorCritic, optimizer: torch.optim.Optimizer, chunk: dict[str, Tensor], gen: torch.Generator) -> dict[str, float]:
        p = self.params
        T, N = chunk["reward"].shape
        flat_obs = chunk["obs"].reshape(T * N, -1)
        model.obs_norm.update(flat_obs)
        returns = None
        if p.value_coef > 0:
            with torch.no_grad():
                next_values = model.value(chunk["final_obs"].reshape(T * N, -1)).reshape(T, N)
            returns = td_lambda_returns(chunk["reward"], next_values, chunk["terminated"], chunk["done"], self.gamma, self.lam)
            returns = returns.reshape(-1)
        labels = chunk["label"].reshape(T * N, -1)
        a_sum = v_sum = 0.0
        count = 0
        for _ in range(p.epochs):
            perm = torch.randperm(T * N, generator=gen)
            for start in range(0, T * N - p.minibatch_size + 1, p.minibatch_size):
                idx = perm[start : start + p.minibatch_size]
                fwd = model.train_forward(flat_obs[idx], labels[idx])
                assert fwd.mean is not None  # a Box action space (the tracker's)
                a_loss = (fwd.mean - labels[idx]).square().mean()
                loss = a_loss
                if returns is not None:
                    v = model.denormalize_value(fwd.value_raw)
                    v_loss = (v - returns[idx]).square().mean()
                    loss = loss + p.value_coef * v_loss
                    v_sum += float(v_loss.detach())
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), p.max_grad_norm)
                optimizer.step()
                a_sum += float(a_loss.detach())
                count += 1
        out = {"loss/action": a_sum / max(count, 1)}
        if returns is not None:
            out["loss/value"] = v_sum / max(count, 1)
        return out


__all__ = ["TrackerDistiller", "distill_lr", "mixture_beta", "td_lambda_returns"]
