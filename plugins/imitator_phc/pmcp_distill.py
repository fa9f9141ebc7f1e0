"""P(F) by distillation instead of RL: DAgger from the last imitation primitive driven by the get-up planner.

PHC (Sec. 3.2) trains the fail-state recovery primitive P(F) by RL: fallen and far starts, the
point-goal reward while far (Eq. 4), and in the official code an AMP-only get-up phase first. On
these cores that learned no get-up in 6M env steps from ``imitator_amp_v2`` (``bench/results/
pmcp_recovery_from_v2``), while an imitator that tracks the bundled get-up clips gets up when it is
*given* one, laid onto the fallen humanoid (:mod:`mocap_phc.recovery_planner`, ``mocap recover
--planner getup``). This method (``recovery.method: planner_distill``; neither the paper's nor the
code's) turns that driver into a policy:

* the **teacher** is the last imitation primitive (frozen) observing the planner's reference (a
  get-up clip, then a walk back), as ``mocap recover --planner getup`` runs it, without the
  recovery goal switch;
* the **student** P(F) starts from the same weights and observes what P(F) observes at test time:
  the protocol's standing-still reference (``mocap_phc.recovery_eval.pick_still_frame``) through
  the imitator's recovery goal switch (PHC Eq. 3: far from it, only its root);
* the planner and the still frame use the whole motion set, as ``mocap recover`` does (not the
  recovery phase's ``clips``, which only choose the clips P(F) is evaluated on when it freezes);
* rollouts start from fallen states (:func:`mocap.fail_states.generate_fall_states`, a share also
  ``far_range`` away), and the acting policy is the teacher for a share beta of the envs that falls
  from 1 to ``teacher_floor`` over ``teacher_until`` of the iterations (DAgger, Ross et al. 2011;
  ``teacher_floor`` 1 is behaviour cloning on the teacher's rollouts), with optional Gaussian noise
  ``action_noise`` on the executed PD targets (DART, Laskey et al. 2017: the teacher's labels then
  cover the perturbed states its own rollouts pass near); every visited state is labelled with the
  teacher's PD targets, expressed as the student's action (residual: target minus the student's
  reference pose), and the student's mean action is fitted by mean squared error on the last
  ``buffer_iterations`` rollouts.

The fallen states use the generator of the phase seed, not the seeds of ``mocap recover``; the
reference is the same still frame the protocol uses, so P(F) trains on the protocol's task.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mocap.checkpoint import load_checkpoint, save_checkpoint
from mocap.fail_states import generate_fall_states, moved
from mocap.rl.networks import ActorCritic
from mocap_phc.observation import PHCObservation
from mocap_phc.recovery_eval import far_shift, pick_still_frame, still_reference
from mocap_phc.pmcp_params import PlannerDistillParams
from mocap_phc.recovery_planner import GetUpPlanner

STATE_NAME = "distill.pt"


def teacher_share(iteration: int, iterations: int, teacher_until: float, floor: float = 0.0) -> float:
    """beta: 1 at iteration 0, falling linearly to ``floor`` at ``teacher_until`` x ``iterations``, then ``floor``."""
    span = max(1.0, teacher_until * iterations)
    return max(floor, 1.0 - (1.0 - floor) * iteration / span)


def student_targets(teacher_q: Tensor, student_ref_dof: Tensor | None, mode: str, offset: Tensor, scale: Tensor, clip: float | None) -> Tensor:
    """The student's action that gives the teacher's PD targets ``teacher_q`` (N, D) through its own
    action map: residual ``q - ref``, absolute ``(q - offset) / scale``; clamped to ``clip``."""
    if mode == "residual":
        if student_ref_dof is None:
            raise ValueError("residual actions need the student's reference DoF angles")
        a = teacher_q - student_ref_dof.to(teacher_q)
    else:
        a = (teacher_q - offset.to(teacher_q)) / scale.to(teacher_q)
    return a if clip is None else a.clamp(-clip, clip)


class PlannerDistiller:
    """One P(F) distillation run (module docstring): ``run()`` returns the student, or None when stopped."""

    def __init__(self, ctx: Any, params: PlannerDistillParams, budget: int, imitator_params: Any, skeleton: Any, library: Any, teacher: ActorCritic, seed: int):
        self.ctx, self.p, self.budget, self.sk, self.lib, self.seed = ctx, params, int(budget), skeleton, library, int(seed)
        self.teacher = teacher.eval()
        self.student = ActorCritic.from_config(teacher.config)
        self.student.load_state_dict(teacher.state_dict())
        self.student_obs = imitator_params.observation()
        self.teacher_obs = imitator_params.model_copy(update={"recovery_goal": None}).observation()
        self.amap = imitator_params.action_map(skeleton)
        self.frames = int(self.student_obs.frames)
        actor = [p for name, p in self.student.named_parameters() if not name.startswith(("critic_body", "value_head")) and p.requires_grad]
        self.opt = torch.optim.Adam(actor, lr=params.lr)
        self.clip, self.t_still = pick_still_frame(library)

    def _rollout(self, sim: Any, gen: torch.Generator, beta: float) -> tuple[Tensor, Tensor, dict[str, float]]:
        p, n = self.p, self.p.num_envs
        fallen = generate_fall_states(sim, self.sk, n, p.fall, gen)
        still = still_reference(self.lib, self.clip, self.t_still, n, self.frames)
        shift, _ = far_shift(gen, n, still.root_pos[:, :2].cpu(), fallen.root_pos[:, :2].cpu(), p.far_prob, p.far_range)
        sim.reset(torch.arange(n), moved(fallen, shift.to(fallen.root_pos)))
        state = sim.state
        dt = float(sim.dt)
        planner = GetUpPlanner(self.lib, p.planner, n, dt, self.frames)
        teach = torch.rand(n, generator=gen) < beta
        obs_rows, targets, errs = [], [], []
        am, still_body = self.amap, still.body_pos.double().cpu()
        for k in range(1, round(p.seconds / dt) + 1):
            given = planner.reference(k, state, still)
            o_t, o_s = self.teacher_obs(state, given), self.student_obs(state, still)
            flat_s = PHCObservation.flatten(o_s).float()
            with torch.no_grad():
                q_t = am(self.teacher.mean_action(PHCObservation.flatten(o_t).float()), o_t.extra.get("ref_dof_pos"))
                ref_s = o_s.extra.get("ref_dof_pos")
                q_s = am(self.student.mean_action(flat_s), ref_s)
            obs_rows.append(flat_s)
            targets.append(student_targets(q_t, ref_s, am.mode, am.offset, am.scale, am.clip).float())
            q = torch.where(teach[:, None], q_t.to(q_s), q_s)
            if p.action_noise > 0:
                q = q + p.action_noise * torch.randn(q.shape, generator=gen, dtype=q.dtype)
            state = sim.step(q)
            errs.append(torch.linalg.vector_norm(state.body_pos.double().cpu() - still_body, dim=-1).mean(-1))
        err = torch.stack(errs)
        stats = {"recovered": float((err <= 0.5).any(0).double().mean()), "beta": beta}
        student_rows = ~teach
        if bool(student_rows.any()):
            stats["recovered_student"] = float((err[:, student_rows] <= 0.5).any(0).double().mean())
        return torch.cat(obs_rows), torch.cat(targets), stats

    def _fit(self, obs: Tensor, target: Tensor, gen: torch.Generator) -> float:
        p, total, count = self.p, 0.0, 0
        self.student.train()
        for _ in range(p.epochs):
            order = torch.randperm(len(obs), generator=gen)
            for start in range(0, len(obs), p.minibatch_size):
                rows = order[start : start + p.minibatch_size]
                loss = torch.nn.functional.mse_loss(self.student.mean_action(obs[rows]), target[rows])
                self.opt.zero_grad()
                loss.backward()
                self.opt.step()
                total, count = total + float(loss.detach()), count + 1
        self.student.eval()
        return total / max(1, count)

    def run(self, phase_dir: Path) -> ActorCritic | None:
        p, ctx = self.p, self.ctx
        phase_dir.mkdir(parents=True, exist_ok=True)
        sim = ctx.build("simulator", skeleton=self.sk, num_envs=p.num_envs, seed=self.seed)
        try:
            per_iteration = p.num_envs * round(p.seconds / float(sim.dt))
            iterations = max(1, math.ceil(self.budget / per_iteration))
            gen = torch.Generator().manual_seed(self.seed)
            start = 0
            buffer: list[tuple[Tensor, Tensor]] = []
            path = phase_dir / STATE_NAME
            if path.is_file():
                saved = load_checkpoint(path)
                self.student.load_state_dict(saved["student"])
                self.opt.load_state_dict(saved["optimizer"])
                gen.set_state(saved["generator"])
                start = int(saved["iteration"])
                ctx.console.print(f"pmcp: P(F) distillation resumes at iteration {start} of {iterations} (the rollout buffer starts empty)")
            for it in range(start, iterations):
                beta = teacher_share(it, iterations, p.teacher_until, p.teacher_floor)
                obs, target, stats = self._rollout(sim, gen, beta)
                buffer = (buffer + [(obs, target)])[-p.buffer_iterations :]
                loss = self._fit(torch.cat([b[0] for b in buffer]), torch.cat([b[1] for b in buffer]), gen)
                steps = (it + 1) * per_iteration
                ctx.log.log(it + 1, env_steps=steps, loss=loss, **{f"distill/{k}": v for k, v in stats.items()})  # as PPO logs
                shown = " ".join(f"{k} {v:.2f}" for k, v in stats.items())
                ctx.console.print(f"pmcp: P(F) distillation it {it + 1}/{iterations} | {steps:,} steps | loss {loss:.4f} | {shown}")
                last = it + 1 == iterations
                if last or (it + 1) % p.checkpoint_every == 0 or ctx.should_stop():
                    payload = {
                        "student": self.student.state_dict(),
                        "optimizer": self.opt.state_dict(),
                        "generator": gen.get_state(),
                        "iteration": it + 1,
                        "env_steps": steps,
                    }
                    save_checkpoint(path, payload)
                if ctx.should_stop() and not last:
                    return None
        finally:
            sim.close()
        return self.student


def distill_recovery_primitive(trainer: Any, state: dict[str, Any], prim: dict[str, Any]) -> bool:
    """The pmcp trainer's recovery phase with ``method: planner_distill``: P(F) ``prim`` distilled from
    the primitive before it, saved as ``prim{k}/primitive.pt``, evaluated on its clips and frozen.
    False when the user stopped it (its ``distill.pt`` resumes it)."""
    from mocap.rl.networks import load_policy, save_policy
    from mocap_phc.pmcp import PRIMITIVE_NAME

    p, ctx = trainer.params, trainer.ctx
    assert p.recovery is not None
    k, ids = int(prim["index"]), list(prim["clip_ids"])
    phase_dir, seed = trainer.workdir / f"prim{k}", trainer._phase_seed(k)
    teacher = load_policy(trainer.workdir / f"prim{k - 1}" / PRIMITIVE_NAME)
    names = [trainer.clip_names[i] for i in ids]
    ctx.console.print(f"pmcp: recovery primitive P(F) {k} distilled from primitive {k - 1} driven by the get-up planner, on {', '.join(names)}")
    sub = ctx.phase(f"prim{k}", workdir=phase_dir, seed=seed)
    try:
        # the whole motion set, as `mocap recover --planner getup` runs: the planner's standing height and the
        # still frame come from it (on a walk/run/get-up subset the median first frame is a lying one)
        lib, budget = trainer._library(range(len(trainer.clip_names))), int(prim["budget_env_steps"])
        distiller = PlannerDistiller(sub, p.recovery.distill, budget, trainer.component.params, trainer.skeleton, lib, teacher, seed)
        model = distiller.run(phase_dir)
    finally:
        sub.log.close()
    if model is None:
        return False
    save_policy(
        phase_dir / PRIMITIVE_NAME,
        model,
        extra={"trainer": "pmcp", "primitive": k, "clips": names, "recovery": True, "method": "planner_distill"},
        spec_yaml=ctx.spec_yaml(),
    )

    def policy_fn(obs: Tensor) -> Tensor:
        with torch.no_grad():
            return model.mean_action(obs.float())

    ev = trainer._evaluate(ids, policy_fn, seed)
    saved = load_checkpoint(phase_dir / STATE_NAME)
    prim.update(
        {
            "status": "frozen",
            "end": "budget",
            "method": "planner_distill",
            "iterations": int(saved["iteration"]),
            "env_steps": int(saved["env_steps"]),
            "evaluation": ev,
            "evaluations": [],
        }
    )
    trainer._save_state(state)
    ctx.console.print(f"pmcp: P(F) {k} frozen after {int(saved['env_steps']):,} env steps: success {ev['success_rate']:.2f} on its {len(ids)} clip(s)")
    return True


__all__ = ["PlannerDistillParams", "PlannerDistiller", "distill_recovery_primitive", "student_targets", "teacher_share"]
