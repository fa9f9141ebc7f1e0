"""Online distillation of an imitator into a latent space (trainer ``distill``), DAgger style.

The trainer of the ``distill`` plugin (:mod:`mocap.distill` registers it without importing this module).

Works for any latent space implementing :class:`~mocap.interfaces.DistillableLatent` (PULSE,
Hybrid-RVQ, a third-party one); the trainer knows nothing of their internals. PULSE's Alg. 1
``TrainPULSE`` (PULSE Sec. 4.2 and App. C.1) is the reference:

* **Teacher** = the ``imitator`` stage's trained component; **student** = the ``latent`` stage's
  component (an ``nn.Module``). Both see the teacher's observation :class:`~mocap.state.Observations`
  (proprioception + next-frame imitation goal); the student learns the teacher's raw
  :meth:`~mocap.interfaces.Imitator.policy_output`.
* **Rollouts**: ``num_envs`` simulator envs; reference-state initialization at a (clip, time) drawn
  with the motion library's sampling weights (non-looping clips start at most one step before their
  end). Each step::

      obs          = teacher.observe(state, reference at t + dt)
      teacher_out  = teacher.policy_output(obs, deterministic=True)        (the label)
      student_out  = student.student_action(obs, sample=sample_latent)     (z ~ E, decoder mean)
      state        = sim.step(teacher.to_pd_targets(obs, acting output))

  The acting output is the student's (``act_with: student``, PULSE), the teacher's (behaviour
  cloning), or per env and step the teacher's with probability β and the student's otherwise
  (``mixture``: DAgger's β_i, annealed linearly from ``mixture_beta[0]`` at progress 0 to
  ``mixture_beta[1]`` at ``mixture_anneal_end``).
* **Episodes** end by *termination* when the mean body-position error exceeds
  ``termination_threshold`` (0.5 m, the evaluation protocol's criterion; PHC+ training uses 0.25 m on
  any body) or the simulator flags numerical instability, and by *truncation* after
  ``episode_steps`` or at the end of a non-looping clip. Finished envs are reset at once.
* **Update**: every iteration collects a (T, N) chunk (``horizon`` × ``num_envs``) of observations,
  teacher outputs and episode-start flags; ``epochs`` passes over minibatches of ``minibatch_envs``
  env columns (each keeping its T steps in time order, for temporal loss terms) minimize
  ``student.distill_losses(...)["loss"]`` with Adam and a global gradient-norm clip. ``progress``
  (env steps / budget, in [0, 1]) is passed for the latent's schedules.
* **Hard negatives** (PHC+ soft mining, PULSE Sec. 4.1 / App. C.1): per-clip failure counts ``f`` and clip
  sampling probabilities ``(1 − floor) f / Σf + floor · b`` (``b``: the library's initial weights).
  ``f`` grows by each clip's failure rate over every ``update_every`` finished training episodes and
  by 1 for each clip failed in a periodic evaluation.
* **Evaluation** every ``eval_every`` iterations (and at the end): the student as an imitator
  (:class:`~mocap.latent_imitator.LatentImitator`, ``z`` = encoder mean) through
  :func:`mocap.imitation_eval.evaluate_imitator`; logs ``eval/success_rate``, ``eval/mpjpe_g``, ...

Student hooks, declared on :class:`~mocap.interfaces.LatentSpace` with do-nothing defaults that a
latent space overrides: ``init_from_teacher(teacher)`` before training
starts (e.g. to copy the teacher's input statistics), ``update_normalizers(obs)`` with each chunk
before the update, ``config`` (a dict saved with the weights), and ``rl_hook()`` for an RL term
(``None`` = off; PULSE's Table 3 ablation, :mod:`mocap_pulse.rl_term`): with a hook, the student
acts through ``hook.act(obs) -> (output, per-env tensors)``, ``hook.reward(state, ref)`` is recorded
after every step, and ``hook.finish(stacked tensors, rewards, terminated, truncated, next obs)``
returns (T, N, ...) tensors that ride in the chunk's ``obs.extra`` to ``distill_losses``.

Files in the stage directory: ``distill.pt`` (resumable: student, optimizer, RNG states, counters,
env state incl. MuJoCo physics, clip weights and failure counts, params, spec) and, at the end,
``latent.pt`` (:func:`save_latent`; a latent factory loads it with :func:`load_latent_state`). A
run resumed from ``distill.pt`` produces the same weights as an uninterrupted one (CPU).

Data-parallel (under torchrun, :mod:`mocap.distributed`): every rank rolls out its own
``num_envs`` envs (own seed, own episode bookkeeping and hard-negative counts from its own
episodes), so an iteration collects ``world_size × num_envs × horizon`` samples and
``total_env_steps`` counts all of them. The student starts from rank 0's weights, gradients are
averaged over ranks before the clip and the step, and the student's running normalizers are
merged exactly. Rank 0 alone runs the periodic evaluation and sends its result (and the clips it
failed, for the failure counts) to the others; rank 0 writes ``distill.pt`` with each rank's
rollout state (``rank_states``) and ``latent.pt``.

Moved out (re-exported here and by :mod:`mocap.distill`): the parameters and β schedule to :mod:`mocap.distill_params`, the file
names, formats, :func:`save_latent` and :func:`load_latent_state` to :mod:`mocap.distill_files`, the
chunk helpers to :mod:`mocap.distill_chunks`.
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
from mocap import trainer_scaffold as scaffold
from mocap.checkpoint import CheckpointError, save_checkpoint
from mocap.faults import FaultGuard
from mocap.rng import rng_state
from mocap.interfaces import DistillableLatent, Imitator, LatentSpace, Simulator, StageResult, Trainer
from mocap.hard_negatives import failure_weights
from mocap.pipeline import StageFailed
from mocap.progress import IterationProgress
from mocap.latent_imitator import LatentImitator, PDTargetTeacher, observations_to
from mocap.motion.library import MotionLibrary
from mocap.distill_episodes import DistillEpisodes
from mocap.state import Observations
from mocap.distill_files import CHECKPOINT_FORMAT, CHECKPOINT_NAME, LATENT_FORMAT, LATENT_NAME, init_from_latent, load_latent_state, save_latent
from mocap.distill_params import DistillParams, distill_lr, mixture_beta
from mocap.distill_chunks import _columns, _stack_obs

EPISODE_WINDOW = 100


# ---------------------------------------------------------------------------------- errors
class DistillError(StageFailed):
    """A spec that cannot be distilled (shown to the user without a traceback)."""


# ------------------------------------------------------------------------------------ trainer
class DistillTrainer(Trainer):
    """Distills the imitator stage into the latent stage (module docstring); resumes from ``distill.pt``."""

    data_parallel = True  # runs on every rank under torchrun (module docstring)

    def __init__(self, params: DistillParams | None = None):
        self.params = params or DistillParams()

    def run(self, ctx: Any) -> StageResult:
        p = self.params
        ckpt_path, device = scaffold.begin(ctx, p.torch_threads, CHECKPOINT_NAME)
        workdir = ckpt_path.parent
        spec_yaml = ctx.spec_yaml()
        skeleton = ctx.skeleton
        upstream = ctx.upstream.get("imitator")
        try:
            teacher: Imitator = ctx.stage_component("imitator", checkpoint=upstream.checkpoint if upstream else None)
        except KeyError:
            raise DistillError("the distill trainer needs a teacher: add an `imitator:` section (a trained imitator or its checkpoint) to the spec") from None
        if teacher.reference_steps != 1:
            raise DistillError(
                f"the teacher observes {teacher.reference_steps} reference frames (e.g. phc goal_frames > 1); "
                "latent encoders read one goal frame, so distill from a one-frame imitator"
            )
        if p.label == "pd_targets":
            teacher = PDTargetTeacher(teacher)
        student = ctx.stage_component("latent")
        if not (isinstance(student, LatentSpace) and isinstance(student, DistillableLatent)):
            raise ValueError(
                f"the latent space {type(student).__name__} cannot be distilled: it must be a mocap.interfaces.LatentSpace "
                "with student_action and distill_losses (mocap.interfaces.DistillableLatent)"
            )
        student.to(device)
        motion_set = ctx.build("motions").load(skeleton)
        for path, reason in motion_set.skipped:
            ctx.console.print(f"[yellow]skipped[/] {path}: {reason}")
        lib = MotionLibrary(motion_set, skeleton)
        sim = ctx.build("simulator", skeleton=skeleton, num_envs=p.num_envs, seed=ctx.seed)
        episodes = DistillEpisodes(p, lib, sim, seed=ctx.seed)
        eval_sims: dict[int, Simulator] = {}

        def make_eval_sim(n: int) -> Simulator:
            if n not in eval_sims:
                eval_sims[n] = ctx.build("simulator", skeleton=skeleton, num_envs=n, seed=ctx.seed)
            return _Borrowed(eval_sims[n])  # type: ignore[return-value]

        params_list = [q for q in student.parameters() if q.requires_grad]
        parallel, world = dist.active(), dist.world_size()
        dist.broadcast_module(student)  # data-parallel: every rank starts from rank 0's weights
        optimizer = torch.optim.Adam(params_list, lr=p.lr)
        gen = torch.Generator().manual_seed(int(ctx.seed) + 1)  # minibatch order, mixture draws
        window: dict[str, deque[float]] = {}
        iteration, env_steps = 0, 0
        last_eval: dict[str, float] = {}
        guard = FaultGuard(p.max_consecutive_faults, "distill")
        ck = scaffold.resume_from(ctx, ckpt_path, CHECKPOINT_FORMAT, "distill", map_location=device)
        if ck is not None:
            student.load_state_dict(ck["student"])
            optimizer.load_state_dict(ck["optimizer"])
            mine = _own_state(ck, dist.rank())
            if mine is not None:
                episodes.load_state_dict(mine["episodes"])
                gen.set_state(mine["generator"])
            else:  # a rank the checkpoint did not have: fresh episodes of its own seed
                episodes.reset_all()
            iteration, env_steps = int(ck["iteration"]), int(ck["env_steps"])
            if mine is not None:
                window = {k: deque(v, maxlen=EPISODE_WINDOW) for k, v in mine["episode_window"].items()}
            last_eval = dict(ck.get("last_eval", {}))
            guard.load_state_dict(ck.get("faults", {}))
            scaffold.resumed(ctx, "distill", iteration, mine["rng"] if mine is not None else None, f"iteration {iteration} ({env_steps:,} env steps)")
            if int(ck.get("world_size", 1)) != world:
                ctx.console.print(f"distill: the checkpoint was written by {int(ck.get('world_size', 1))} process(es), resuming with {world}")
        else:
            try:
                student.init_from_teacher(teacher)
            except ValueError as exc:  # a student/teacher mismatch the spec has to fix
                raise DistillError(f"latent {type(student).__name__}: {exc}") from None
            if p.init_latent is not None:  # after the teacher's statistics: the file's own normalizers win
                try:
                    init_from_latent(student, p.init_latent)
                except CheckpointError as exc:
                    raise DistillError(str(exc)) from None
                ctx.console.print(f"distill: starting from {p.init_latent}")
            episodes.reset_all()
        self._check_dims(teacher, student, episodes, device)

        def save(final: bool = False) -> None:
            extra: dict[str, Any] = {}
            if parallel:  # every rank's own rollout state goes into rank 0's checkpoint
                states = dist.gather_object(
                    {
                        "episodes": episodes.state_dict(),
                        "generator": gen.get_state(),
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
                    "student": {k: v.detach().cpu() if isinstance(v, Tensor) else v for k, v in student.state_dict().items()},
                    "latent_config": student.config,
                    "optimizer": optimizer.state_dict(),
                    "episodes": episodes.state_dict(),
                    "generator": gen.get_state(),
                    "rng": rng_state(),
                    "episode_window": {k: list(v) for k, v in window.items()},
                    "last_eval": last_eval,
                    "faults": guard.state_dict(),
                    "params": p.model_dump(mode="json"),
                    "finished": final,
                    **extra,
                },
                spec_yaml=spec_yaml,
            )

        # the budget counts every rank's samples; alone this is p.iterations
        total = iteration + max(0, math.ceil((p.total_env_steps - env_steps) / (p.batch_size * world)))
        budget = p.iterations * p.batch_size
        progress_bar = IterationProgress(
            ctx.console,
            total,
            p.print_every,
            "distill",
            [("loss/action", "action", ".4g"), ("loss/kl", "kl", ".3g"), ("episode/length", "len", ".1f"), ("eval/success_rate", "eval success", ".2f")],
        )
        last_stats: dict[str, float] = {}
        t_start = time.perf_counter()
        steps_at_start = env_steps
        try:
            while iteration < total:
                progress = min(1.0, env_steps / budget)
                t0 = time.perf_counter()
                chunk, teacher_out, starts, roll = self._rollout(teacher, student, episodes, sim, gen, progress, device, window)
                env_steps += p.batch_size * world
                t_rollout = time.perf_counter() - t0

                t1 = time.perf_counter()
                for group in optimizer.param_groups:  # from progress alone, so a resumed run sets the same rate
                    group["lr"] = distill_lr(progress, p.lr, p.lr_end)
                stats: dict[str, float] = {}
                # (data-parallel: a non-finite input on any rank makes every rank skip the chunk)
                if dist.check_inputs(guard, observations=chunk.proprio, goals=chunk.goal, labels=teacher_out):
                    stats = self._update(student, optimizer, params_list, chunk, teacher_out, starts, gen, progress, guard)
                t_update = time.perf_counter() - t1
                iteration += 1

                elapsed = time.perf_counter() - t_start
                log = {
                    "env_steps": float(env_steps),
                    "progress": progress,
                    **stats,
                    **roll,
                    "lr": optimizer.param_groups[0]["lr"],
                    "time/rollout_s": t_rollout,
                    "time/update_s": t_update,
                    "steps_per_s": p.batch_size / max(t_rollout + t_update, 1e-9),
                    "steps_per_s_run": (env_steps - steps_at_start) / max(elapsed, 1e-9),
                    **guard.take_counts(),
                }
                for key, vals in window.items():
                    if vals:
                        log[f"episode/{key}"] = float(np.mean(vals))
                w = episodes.clip_weights
                log["hard_negative/max_weight"], log["hard_negative/min_weight"] = float(w.max()), float(w.min())
                if parallel:  # one line for all ranks: sums, slowest times, means, pooled episode windows
                    log = dist.reduce_metrics(log, maxima=("time/rollout_s", "time/update_s"), windows=window)
                    log["steps_per_s"] = p.batch_size * world / max(log["time/rollout_s"] + log["time/update_s"], 1e-9)
                if p.eval_every > 0 and (iteration % p.eval_every == 0 or iteration >= total):
                    t2 = time.perf_counter()
                    if parallel:  # rank 0 evaluates; every rank adds the clips it failed to its counts
                        evaluated = None
                        if dist.is_main():
                            with dist.solo():
                                evaluated = self._evaluate_clips(teacher, student, lib, episodes, make_eval_sim, device)
                        last_eval, failed = dist.broadcast_object(evaluated)
                        episodes.add_failures(failed)
                    else:
                        last_eval = self._evaluate(teacher, student, lib, episodes, make_eval_sim, device)
                    log.update(last_eval)
                    log["time/eval_s"] = time.perf_counter() - t2
                ctx.log.log(iteration, **log)
                last_stats = log
                progress_bar.update(iteration, env_steps, log)

                stop = dist.any_true(ctx.should_stop()) if parallel else ctx.should_stop()
                if stop or iteration % p.checkpoint_every == 0 or iteration >= total:
                    save(final=iteration >= total)
                if stop:
                    ctx.console.print(f"distill: stopped at iteration {iteration}; checkpoint {ckpt_path}")
                    return StageResult(checkpoint=ckpt_path, metrics=_summary(last_stats, last_eval, iteration, env_steps))
        finally:
            progress_bar.close()
            sim.close()
            for s in eval_sims.values():
                s.close()

        metrics = _summary(last_stats, last_eval, iteration, env_steps)
        latent_path = workdir / LATENT_NAME
        if parallel:
            dist.assert_in_sync(student, "distill")
        if dist.is_main():
            save_latent(latent_path, student, extra={"trainer": "distill", "metrics": metrics, "label": p.label}, spec_yaml=spec_yaml)
        return StageResult(checkpoint=latent_path, metrics=metrics)

    # ------------------------------------------------------------------------------ pieces
    @staticmethod
    def _check_dims(teacher: Imitator, student: Any, episodes: DistillEpisodes, device: torch.device) -> None:
        """Fail early, with both sizes named, when the student's output cannot match the teacher's."""
        obs = teacher.observe(episodes.sim.state, episodes.reference_next())
        with torch.no_grad():
            t_out = teacher.policy_output(obs, deterministic=True)
            try:
                s_out = student.student_action(observations_to(obs, device), sample=False)
            except (ValueError, RuntimeError) as exc:
                goal = None if obs.goal is None else obs.goal.shape[-1]
                raise StageFailed(
                    f"distill: the latent space cannot read the teacher's observation (proprio {obs.proprio.shape[-1]}, goal {goal} "
                    f"dims): {exc}; the teacher must be an imitator with the observation the latent's sizes were built for "
                    "(e.g. phc, whose proprioception and goal sizes follow the humanoid)"
                ) from None
        if tuple(s_out.shape) != tuple(t_out.shape):
            raise StageFailed(
                f"the latent space outputs {tuple(s_out.shape)}, the teacher's policy output is {tuple(t_out.shape)}: "
                "set the latent's action size to the teacher's"
            )

    def _rollout(
        self,
        teacher: Imitator,
        student: Any,
        episodes: DistillEpisodes,
        sim: Simulator,
        gen: torch.Generator,
        progress: float,
        device: torch.device,
        window: dict[str, deque[float]],
    ) -> tuple[Observations, Tensor, Tensor, dict[str, float]]:
        p = self.params
        T, N = p.horizon, p.num_envs
        beta = mixture_beta(progress, p.mixture_beta[0], p.mixture_beta[1], p.mixture_anneal_end) if p.act_with == "mixture" else None
        obs_list: list[Observations] = []
        outs = torch.zeros(T, N, 0)
        starts = torch.zeros(T, N, dtype=torch.bool)
        err_sum, gap_sum, teacher_acts = 0.0, 0.0, 0.0
        student.eval()
        # optional RL term (e.g. PULSE's Table 3 ablation): the student's hook acts, is rewarded, and
        # adds per-sample tensors (advantages, ...) to the chunk's ``extra`` for its distill_losses
        rl_hook = student.rl_hook()
        if rl_hook is not None and p.act_with != "student":
            raise DistillError("the latent's RL term is on-policy: it needs act_with: student")
        rl_info: list[dict[str, Tensor]] = []
        rl_reward, rl_terminated, rl_trunc = torch.zeros(T, N), torch.zeros(T, N, dtype=torch.bool), torch.zeros(T, N, dtype=torch.bool)
        state = sim.state
        with torch.no_grad():
            for t in range(T):
                ref = episodes.reference_next()
                obs = teacher.observe(state, ref)
                t_out = teacher.policy_output(obs, deterministic=True)
                if t == 0:
                    outs = torch.zeros(T, N, t_out.shape[-1], dtype=t_out.dtype)
                outs[t] = t_out.cpu()
                starts[t] = (episodes.progress == 0).cpu()
                obs_list.append(observations_to(obs, "cpu"))
                if p.act_with == "teacher":
                    acting = t_out
                else:
                    if rl_hook is not None:
                        s_out, info = rl_hook.act(observations_to(obs, device))
                        s_out = s_out.to(t_out)
                        rl_info.append(info)
                    else:
                        s_out = student.student_action(observations_to(obs, device), sample=p.sample_latent).to(t_out)
                    gap_sum += float((s_out - t_out).square().sum(-1).mean())
                    if beta is not None:
                        use_teacher = torch.rand(N, generator=gen) < beta
                        teacher_acts += float(use_teacher.double().mean())
                        acting = torch.where(use_teacher.to(t_out.device)[:, None], t_out, s_out)
                    else:
                        acting = s_out
                state = sim.step(teacher.to_pd_targets(obs, acting))
                res = episodes.after_step(state, ref)
                err_sum += float(res["error"].mean())
                if rl_hook is not None:
                    rl_reward[t] = rl_hook.reward(state, ref).cpu()
                    rl_terminated[t], rl_trunc[t] = res["terminated"].cpu(), res["truncated"].cpu()
                done = res["terminated"] | res["truncated"]
                if bool(done.any()):
                    ids = done.nonzero().squeeze(-1)
                    for key, val in (
                        ("length", res["length"][ids].double()),
                        ("success", res["truncated"][ids].double()),
                    ):
                        window.setdefault(key, deque(maxlen=EPISODE_WINDOW)).extend(val.cpu().tolist())
                    state = sim.state  # after the resets
        roll = {"rollout/body_error_m": err_sum / T}
        if p.act_with != "teacher":
            roll["rollout/action_gap"] = gap_sum / T
        if beta is not None:
            roll["rollout/mixture_beta"] = beta
            roll["rollout/teacher_fraction"] = teacher_acts / T
        chunk = observations_to(_stack_obs(obs_list), device)
        if rl_hook is not None:
            with torch.no_grad():
                last_obs = observations_to(teacher.observe(sim.state, episodes.reference_next()), device)
                stacked = {k: torch.stack([i[k] for i in rl_info]) for k in rl_info[0]}
                chunk.extra.update(rl_hook.finish(stacked, rl_reward.to(device), rl_terminated, rl_trunc, last_obs))
            roll["rollout/rl_reward"] = float(rl_reward.mean())
        return chunk, outs.to(device), starts.to(device), roll

    def _update(
        self,
        student: Any,
        optimizer: torch.optim.Optimizer,
        params: list[torch.nn.Parameter],
        chunk: Observations,
        teacher_out: Tensor,
        starts: Tensor,
        gen: torch.Generator,
        progress: float,
        guard: FaultGuard | None = None,
    ) -> dict[str, float]:
        p = self.params
        guard = guard or FaultGuard(0, "distill")
        N = teacher_out.shape[1]
        # data-parallel: the statistics of all ranks' chunks, merged exactly
        dist.sync_normalizers(student, lambda: student.update_normalizers(chunk))
        student.train()
        sums: dict[str, float] = {}
        steps = 0
        for _ in range(p.epochs):
            perm = torch.randperm(N, generator=gen)
            for idx in perm.split(p.minibatch_envs):
                idx = idx.to(teacher_out.device)
                losses = student.distill_losses(_columns(chunk, idx), teacher_out[:, idx], starts[:, idx], progress)
                loss = losses["loss"]
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                step_loss = loss
                if dist.active():  # average gradients (and the loss: non-finite anywhere -> skipped everywhere)
                    (step_loss,) = dist.average_gradients(params, loss)
                stepped, grad_norm = guard.step(optimizer, step_loss, params, p.max_grad_norm)
                if not stepped:
                    continue
                for key, val in losses.items():
                    name = "loss/total" if key == "loss" else f"loss/{key}"
                    sums[name] = sums.get(name, 0.0) + float(torch.as_tensor(val).detach())
                sums["grad_norm"] = sums.get("grad_norm", 0.0) + float(grad_norm)
                steps += 1
        student.eval()
        return {k: v / max(steps, 1) for k, v in sums.items()}

    def _evaluate(
        self,
        teacher: Imitator,
        student: Any,
        lib: MotionLibrary,
        episodes: DistillEpisodes,
        make_sim: Callable[[int], Simulator],
        device: torch.device,
    ) -> dict[str, float]:
        """The student as an imitator on every clip (z = encoder mean); failed clips add 1 to their counts."""
        out, failed = self._evaluate_clips(teacher, student, lib, episodes, make_sim, device)
        episodes.add_failures(failed)
        return out

    def _evaluate_clips(
        self,
        teacher: Imitator,
        student: Any,
        lib: MotionLibrary,
        episodes: DistillEpisodes,
        make_sim: Callable[[int], Simulator],
        device: torch.device,
    ) -> tuple[dict[str, float], Tensor]:
        """:meth:`_evaluate` without touching the failure counts: ``(eval metrics, failed per clip)``."""
        from mocap.evaluation import ImitationEvalParams
        from mocap.imitation_eval import evaluate_imitator

        p = self.params
        student.eval()
        horizon = p.eval_horizon if p.eval_horizon is not None else p.episode_steps * episodes.dt
        params = ImitationEvalParams(num_envs=p.eval_num_envs, horizon=horizon, threshold=p.termination_threshold, video=False)
        table = evaluate_imitator(LatentImitator(teacher, student, device), lib, make_sim, params)
        failed = torch.tensor([not table["clips"][name]["success"] for name in lib.clip_names], dtype=torch.float64)
        out = {f"eval/{k}": float(v) for k, v in table["aggregate"].items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
        return out, failed


def _own_state(ck: dict[str, Any], rank: int) -> dict[str, Any] | None:
    """This rank's rollout state in a checkpoint (rank 0: the top-level fields, which a
    single-process run also writes); None when the checkpoint lacks it."""
    if rank == 0:
        return {k: ck[k] for k in ("episodes", "generator", "rng", "episode_window")}
    return (ck.get("rank_states") or {}).get(rank)


class _Borrowed:
    """A cached evaluation simulator lent to ``evaluate_imitator`` (which closes what it gets)."""

    def __init__(self, sim: Simulator):
        self._sim = sim

    def close(self) -> None:
        pass

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sim, name)


def _summary(stats: dict[str, float], last_eval: dict[str, float], iteration: int, env_steps: int) -> dict[str, float]:
    out = {"iterations": float(iteration), "env_steps": float(env_steps)}
    for key, value in stats.items():
        if key.startswith(("episode/", "loss/")) or key in ("steps_per_s_run", "rollout/action_gap"):
            out[key] = float(value)
    out.update({k: float(v) for k, v in last_eval.items()})
    return out


__all__ = [
    "CHECKPOINT_FORMAT",
    "DistillEpisodes",
    "DistillError",
    "DistillParams",
    "DistillTrainer",
    "LATENT_FORMAT",
    "failure_weights",
    "load_latent_state",
    "mixture_beta",
    "save_latent",
]
