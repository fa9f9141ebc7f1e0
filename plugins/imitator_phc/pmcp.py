"""PMCP (PHC Sec. 3.2, Alg. 1): progressive primitives and their composer, as one trainer ``pmcp``.

The trainer runs, inside one ``imitator`` stage, what PHC's official code does by hand (train,
``forward_pmcp.py``, train again, then the composer config):

1. **Primitive 0** is PPO on every clip (the :class:`~mocap_phc.env.ImitationEnv`, with its RSI and
   hard-negative clip weights as configured in ``PHCParams``). Every ``eval_every`` PPO iterations
   the current deterministic policy is evaluated with the env's protocol
   (:meth:`~mocap_phc.env.ImitationEnv.evaluate_clips`: every clip of the primitive's set once from
   its first frame, deterministic actions, failure = mean body error above ``eval_threshold``;
   looping clips keep cycling for the training episode, ``episode_steps``, like ``mocap eval
   --loop``, so a primitive that tracks one period of ``walk`` but drifts off later hands it on).
   The primitive is **frozen** when it plateaus (:class:`PlateauTracker`), when every clip of its
   set succeeds (``stop_on_success``), or when its env-step budget ends.
2. At the freeze it is evaluated once more on its clip set; the clips it fails form the next hard
   set. **Subset rule** (:func:`next_hard_set`): ``H_0`` = all clips, ``H_{k+1}`` = the clips of
   ``H_k`` that primitive ``k`` fails at its freeze; the sets nest, ``H_{k+1} ⊆ H_k`` ([P]
   Algorithm 1, with the index typo read as ``Q_hard^(k)``). Primitive ``k+1`` trains on a motion
   library holding only ``H_{k+1}``, starting from primitive ``k``'s weights (``init="copy"``: [P]
   variant (b) "weight sharing", [C] ``forward_pmcp.py`` copies ``actors.k`` into ``actors.k+1``;
   the critic and the observation normalizer are copied too, [P] "the value function is not
   re-initialized") or from a fresh random init (``init="fresh"``; PNN lateral connections, [P]
   variant (a), are not implemented). The primitive phase ends when ``H_{k+1}`` is empty, when
   ``max_primitives`` primitives exist or when the primitive budget (``ppo.total_env_steps``, summed
   over the primitives) is spent.
3. **Composer**: PPO on every clip through :class:`ComposerEnv`, a VecEnv around an
   ``ImitationEnv`` with the same observation. The composer's PPO action is the weight vector
   ``w`` (K entries, one per primitive); the env acts with (:func:`compose`)::

       weighted_sum   ([C]):  a = sum_i relu(w_i) mu_i                               (unnormalized)
       multiplicative ([P]):  c_i = relu(w_i) + eps,  a = sum_i c_i mu_i / sum_i c_i

   where ``mu_i`` is frozen primitive ``i``'s deterministic mean on the observation normalized with
   *its own* saved normalizer. The multiplicative form is PHC Eq. 5/6 (MCP's product of Gaussians)
   with the primitives' equal, fixed sigma, where the precision weighting reduces to a weighted
   mean; ``relu`` gives [P]'s ``C_i >= 0``. With ``eps = 0`` and all ``w_i <= 0`` it falls back
   to the plain mean of the means.

**Resume.** ``ctx.workdir/pmcp_state.json`` (written atomically after every decision) records the
phase, each primitive's clip set, budget, status and freeze evaluation; each PPO run lives in its
own subdirectory (``prim0/``, ``prim1/``, ..., ``composer/``) with PPO's own resumable
``ppo.pt``. The plateau tracker is part of the wrapped env's ``state_dict``, so it is inside
``ppo.pt`` too. Rerunning the stage continues in the phase it was stopped in.

**Output.** ``ctx.workdir/pmcp.pt`` (format ``mocap_phc.pmcp/1``): every primitive (network config,
weights, its observation normalizer), the composer, the composer form and the clip sets. ``make_phc``
with that file returns a :class:`CompositeImitator`, so ``mocap eval pmcp.pt`` works unchanged. A
per-clip report ``pmcp.md`` is published to the run directory.

**Recovery** (``recovery:``, PHC Sec. 3.2 "Fail-state Recovery"): after the imitation primitives, the fail-state
primitive P(F) is trained (phase ``recovery``) on the locomotion and get-up clips, initialized from
the last imitation primitive, with fallen and far starts, bonus recovery episodes and the
point-goal reward while far (PHC Eq. 4, ``RecoveryGoalParams.reward = "point"``); it is frozen at
the end of its budget and the composer mixes K + 1 primitives, trained with fail starts
interleaved (``composer_fail_states``). It needs the imitator's ``recovery_goal`` (Eq. 3's goal
switch), which then applies to every primitive. ``mocap recover`` measures the recovery rate.

With ``recovery.getup`` set, P(F) first runs [C]'s AMP-only get-up phase (in ``prim{k}_getup/``:
fallen starts only, task weight 0, AMP weight 1, initialized from the last imitation primitive) and
the point-goal phase starts from its weights.

With the imitator's ``amp`` on, each phase continues the previous phase's discriminator
(``carry_discriminator``, [P] Sec. 3.2 and Alg. 1: the value function and discriminator are fine-tuned, not
re-initialized); its demo windows come from the new phase's clips.

Not implemented: PNN lateral connections.

The code is split over sibling modules (re-exported here): the parameters in
:mod:`mocap_phc.pmcp_params`, the composer and composite imitator in :mod:`mocap_phc.pmcp_composite`,
the freeze / hard-set rules and the report in :mod:`mocap_phc.pmcp_rules`, the phase envs and PPO
plumbing in :mod:`mocap_phc.pmcp_phases`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

import torch
from pydantic import ValidationError
from torch import Tensor

from mocap.checkpoint import atomic_write_json, atomic_write_text, load_checkpoint, save_checkpoint
from mocap.interfaces import Box, StageResult, Trainer
from mocap.rl.networks import ActorCritic, load_policy, save_policy
from mocap.rl.ppo import PPOTrainer
from mocap import trainer_scaffold as scaffold
from mocap.errors import CheckpointError
from mocap_phc.pmcp_composite import (
    PMCP_FORMAT,
    CompositeImitator,
    CompositePolicy,
    _net,
    compose,
    composer_bias,
    composite_policy_from,
    is_pmcp_checkpoint,
    make_composite_imitator,
)
from mocap_phc.pmcp_params import GetupPhaseParams, PMCPParams, RecoveryPhaseParams
from mocap_phc.pmcp_phases import ComposerEnv, PrimitiveEnv
from mocap_phc.pmcp_rules import PlateauTracker, next_hard_set, pmcp_report, unique_clip_names
from mocap_phc.recovery import FailStateParams

STATE_FILE = "pmcp_state.json"
STATE_FORMAT = 1
FINAL_NAME = "pmcp.pt"
REPORT_NAME = "pmcp.md"
PRIMITIVE_NAME = "primitive.pt"


class PMCPTrainer(Trainer):
    """The ``pmcp`` trainer of the ``imitator`` stage (module docstring)."""

    def __init__(self, params: PMCPParams | None = None):
        self.params = params or PMCPParams()

    # ----------------------------------------------------------------------------- helpers
    def _setup(self, ctx: Any) -> None:
        self.ctx = ctx
        state_path, _ = scaffold.begin(ctx, self.params.ppo.torch_threads, STATE_FILE)  # threads, workdir, seeds
        self.workdir = state_path.parent
        self.component = ctx.stage_component()
        from mocap_phc.imitator import PHCImitator

        if not isinstance(self.component, PHCImitator):
            raise TypeError("the pmcp trainer needs the phc imitator")
        self.skeleton = self.component.skeleton
        motion_set = ctx.build("motions").load(self.skeleton)
        for path, reason in motion_set.skipped:
            ctx.console.print(f"[yellow]skipped[/] {path}: {reason}")
        self.clips = list(motion_set.clips)
        if not self.clips:
            raise ValueError("pmcp: the motion set has no clips")
        self.clip_names = unique_clip_names([c.name for c in self.clips])
        if self.params.recovery is not None and self.component.params.recovery_goal is None:
            from mocap.errors import UserError

            raise UserError(
                "pmcp recovery needs the fail-state goal switch: set imitator.params.recovery_goal (e.g. {form: paper}); "
                "every primitive and the composer observe through it"
            )
        if self.params.recovery is not None and self.params.recovery.getup is not None:
            self._getup_params()  # checked before primitive 0's evaluation and P(F), not hours into the run
        if self.params.recovery is not None and self.params.recovery.method == "planner_distill":
            from mocap.errors import UserError
            from mocap_phc.recovery_planner import GetUpPlanner

            try:  # the teacher's planner needs get-up clips and a looping approach clip in the motion set
                GetUpPlanner(self._library(range(len(self.clips))), self.params.recovery.distill.planner, 1, 1.0 / 30.0)
            except ValueError as err:
                raise UserError(f"pmcp recovery.method planner_distill: {err}") from None

    def _library(self, ids: Sequence[int]) -> Any:
        from mocap.motion.library import MotionLibrary

        return MotionLibrary([self.clips[i] for i in ids], self.skeleton)

    def _imitation_env(self, ids: Sequence[int], num_envs: int, seed: int, params: Any = None) -> Any:
        from mocap_phc.env import ImitationEnv

        ctx, sk = self.ctx, self.skeleton
        sim = ctx.build("simulator", skeleton=sk, num_envs=num_envs, seed=seed)

        def eval_sim(n: int) -> Any:
            return ctx.build("simulator", skeleton=sk, num_envs=n, seed=seed)

        params = self._subset_params(params if params is not None else self.component.params, ids)
        return ImitationEnv(params, sk, self._library(ids), sim, seed=seed, eval_simulator_factory=eval_sim)

    def _subset_params(self, params: Any, ids: Sequence[int]) -> Any:
        """``params`` for an env on clips ``ids`` only: without ``getup_starts`` when none of them is a
        get-up clip (a probe, an evaluation, a hard set or P(F)'s set may lack one; those fallen starts
        need a get-up clip to track). The full motion set keeps the user's check (a clear error)."""
        from mocap.getup_starts import getup_clip_names

        starts = params.getup_starts
        if starts is None or len(ids) == len(self.clip_names):
            return params
        if getup_clip_names([self.clip_names[i] for i in ids], list(starts.clips)):
            return params
        return params.model_copy(update={"getup_starts": None})

    def _recovery_params(self, fail_states: FailStateParams | None) -> Any:
        """The imitator's params with fallen/far starts and the point-goal reward while far (PHC Eq. 4)."""
        base = self.component.params
        goal = base.recovery_goal.model_copy(update={"reward": "point"})
        return base.model_copy(update={"fail_states": fail_states, "recovery_goal": goal})

    def recovery_clip_ids(self) -> list[int]:
        rec = self.params.recovery
        assert rec is not None
        ids = [i for i, n in enumerate(self.clip_names) if any(key in n for key in rec.clips)]
        if not ids:
            raise ValueError(f"pmcp recovery: no clip name contains any of {rec.clips} (clips: {', '.join(self.clip_names)})")
        return ids

    def _evaluate(self, ids: Sequence[int], policy_fn: Callable[[Tensor], Tensor], seed: int) -> dict[str, Any]:
        """The env's protocol on clips ``ids``: per full-library name -> success/tracked steps."""
        env = self._imitation_env(ids, 1, seed)
        try:
            res = env.evaluate_clips(policy_fn)
        finally:
            env.close()
        sub = env.library.clip_names
        clips = {self.clip_names[c]: res["clips"][sub[i]] for i, c in enumerate(ids)}
        return {"success_rate": res["success_rate"], "clips": clips, "failed": [n for n, r in clips.items() if not r["success"]]}

    def _phase_seed(self, index: int) -> int:
        return (int(self.ctx.seed) + 7919 * (index + 1)) % (2**31)

    def _save_state(self, state: dict[str, Any]) -> None:
        atomic_write_json(self.workdir / STATE_FILE, state)

    def _load_state(self) -> dict[str, Any]:
        path = self.workdir / STATE_FILE
        state = scaffold.resume_state_file(path, STATE_FORMAT, "PMCP")
        if state is not None:
            if state.get("clip_names") != self.clip_names:
                raise CheckpointError(f"{path}: made with a different motion set; remove the stage's directory to start over")
            return state
        state = {
            "format": STATE_FORMAT,
            "phase": "primitives",
            "clip_names": self.clip_names,
            "primitives": [],
            "stop_reason": None,
            "composer": None,
        }
        self._add_primitive(state, list(range(len(self.clip_names))))
        self._save_state(state)
        return state

    def _add_primitive(self, state: dict[str, Any], ids: list[int]) -> None:
        p = self.params
        used = sum(int(prim.get("env_steps", 0)) for prim in state["primitives"])
        remaining = p.ppo.total_env_steps - used
        budget = remaining if p.primitive_env_steps is None else min(p.primitive_env_steps, remaining)
        state["primitives"].append({"index": len(state["primitives"]), "clip_ids": ids, "budget_env_steps": int(budget), "status": "training"})

    def _primitive_budget_left(self, state: dict[str, Any]) -> int:
        used = sum(int(prim.get("env_steps", 0)) for prim in state["primitives"])
        return self.params.ppo.total_env_steps - used

    # -------------------------------------------------------------------------------- run
    def run(self, ctx: Any) -> StageResult:
        self._setup(ctx)
        state = self._load_state()
        while state["phase"] == "primitives":
            prim = state["primitives"][-1]
            if prim["status"] == "training" and not self._train_primitive(state, prim):
                return self._stopped(state)
            # frozen: decide what comes next
            if not self._next_primitive(state):
                if self.params.recovery is not None:
                    state["phase"] = "recovery"
                    ids = self.recovery_clip_ids()
                    state["primitives"].append(
                        {
                            "index": len(state["primitives"]),
                            "clip_ids": ids,
                            "budget_env_steps": int(self.params.recovery.env_steps),
                            "status": "training",
                            "recovery": True,
                        }
                    )
                else:
                    state["phase"] = "composer"
                    state["composer"] = {"status": "training"}
                self._save_state(state)
            if ctx.should_stop():
                return self._stopped(state)
        if state["phase"] == "recovery":
            prim = state["primitives"][-1]
            getup = prim.get("getup")
            if getup is None and self.params.recovery is not None and self.params.recovery.getup is not None and prim["status"] == "training":
                getup = prim["getup"] = {"status": "training", "budget_env_steps": int(self.params.recovery.getup.env_steps)}
                self._save_state(state)
            if getup is not None and getup["status"] == "training" and not self._train_primitive(state, prim, getup=True):
                return self._stopped(state)
            if prim["status"] == "training" and not self._train_primitive(state, prim):
                return self._stopped(state)
            state["phase"] = "composer"
            state["composer"] = {"status": "training"}
            self._save_state(state)
            if ctx.should_stop():
                return self._stopped(state)
        if state["phase"] == "composer" and not self._train_composer(state):
            return self._stopped(state)
        return self._finish(state)

    def _stopped(self, state: dict[str, Any]) -> StageResult:
        self.ctx.console.print(f"pmcp: stopped in phase {state['phase']!r}; rerun the stage to resume")
        return StageResult(checkpoint=self.workdir / STATE_FILE, metrics={})

    # ---------------------------------------------------------------------------- primitives
    def _given_primitive(self, state: dict[str, Any], prim: dict[str, Any]) -> None:
        """Primitive 0 from ``primitive0``: checked against this imitator's sizes, copied into
        ``prim0/``, evaluated on its clips and frozen (``end: given``)."""
        from mocap.errors import UserError

        p, ctx = self.params, self.ctx
        assert p.primitive0 is not None
        source = Path(p.primitive0)
        if not source.is_file():
            raise UserError(f"pmcp primitive0: {source} does not exist")
        model = load_policy(source)
        ids = list(prim["clip_ids"])
        probe = self._imitation_env(ids[:1], 1, self._phase_seed(0))
        try:
            obs_dim, act_dim = int(probe.obs_dim), int(probe.action_space.shape[0])
        finally:
            probe.close()
        expected = PPOTrainer(p.ppo).build_model(obs_dim, Box((act_dim,)))
        got = {k: tuple(v.shape) for k, v in model.state_dict().items() if isinstance(v, Tensor)}
        want = {k: tuple(v.shape) for k, v in expected.state_dict().items() if isinstance(v, Tensor)}
        if got != want:
            bad = sorted(k for k in set(got) | set(want) if got.get(k) != want.get(k))[:3]
            raise UserError(
                f"pmcp primitive0: {source} does not fit this imitator (observation {obs_dim}, actions {act_dim}, actor "
                f"{list(p.ppo.actor_hidden)}, critic {list(p.ppo.critic_hidden)}); differing tensors: {', '.join(bad)}"
            )
        phase_dir = self.workdir / "prim0"
        phase_dir.mkdir(parents=True, exist_ok=True)
        save_policy(phase_dir / PRIMITIVE_NAME, model, extra={"trainer": "pmcp", "primitive": 0, "given": str(source)}, spec_yaml=ctx.spec_yaml())
        model.eval()

        def policy_fn(obs: Tensor) -> Tensor:
            with torch.no_grad():
                return model.mean_action(obs.float())

        ev = self._evaluate(ids, policy_fn, self._phase_seed(0))
        prim.update({"status": "frozen", "end": "given", "source": str(source), "iterations": 0, "env_steps": 0, "evaluation": ev, "evaluations": []})
        self._save_state(state)
        ctx.console.print(f"pmcp: primitive 0 given ({source}): success {ev['success_rate']:.2f} on its {len(ids)} clip(s)")

    def _carry_discriminator(self, env: Any, previous: Path, phase_dir: Path) -> None:
        """A new phase's env continues the discriminator of the phase in ``previous`` (its ``ppo.pt``),
        when ``carry_discriminator`` is on, both phases have one and this phase has not started yet
        (a resumed phase restores its own from its ``ppo.pt``)."""
        if not self.params.carry_discriminator or env.amp_trainer is None or (phase_dir / "ppo.pt").is_file():
            return
        source = previous / "ppo.pt"
        if not source.is_file():
            return
        saved = load_checkpoint(source)["env"]
        saved = saved.get("inner", saved)  # a primitive's env wraps the imitation env; the composer's does not
        if "amp" in saved:
            env.amp_trainer.carry_from(saved["amp"]["trainer"])
            self.ctx.console.print(f"pmcp: the AMP discriminator continues from {previous.name}")

    def _getup_params(self) -> Any:
        """The imitator's params for [C]'s get-up phase: its fallen starts and imitator overrides."""
        rec = self.params.recovery
        assert rec is not None and rec.getup is not None
        base = self._recovery_params(rec.getup.fail_states)
        try:
            return type(base).model_validate({**base.model_dump(), **rec.getup.imitator})
        except ValidationError as exc:
            from mocap.errors import UserError

            why = "; ".join(str(e["msg"]) for e in exc.errors())
            raise UserError(f"pmcp recovery.getup.imitator: the get-up phase's imitator params are invalid: {why}") from None

    def _train_primitive(self, state: dict[str, Any], prim: dict[str, Any], getup: bool = False) -> bool:
        """Train primitive ``prim`` until it should be frozen; freeze it. False when stopped by the user.
        ``getup``: run P(F)'s get-up phase instead (``prim["getup"]``, directory ``prim{k}_getup``)."""
        p, ctx = self.params, self.ctx
        k, ids = int(prim["index"]), list(prim["clip_ids"])
        if k == 0 and p.primitive0 is not None:
            self._given_primitive(state, prim)
            return True
        if prim.get("recovery") and not getup and p.recovery is not None and p.recovery.method == "planner_distill":
            from mocap_phc.pmcp_distill import distill_recovery_primitive

            return distill_recovery_primitive(self, state, prim)
        phase = f"prim{k}_getup" if getup else f"prim{k}"
        phase_dir = self.workdir / phase
        seed = self._phase_seed(k) + (104729 if getup else 0)
        holder: dict[str, PrimitiveEnv] = {}
        recovery = bool(prim.get("recovery"))
        if getup:
            env_params = self._getup_params()
        else:
            env_params = self._recovery_params(p.recovery.fail_states) if recovery and p.recovery is not None else None
        # P(F) trains for its whole budget: its job (getting up, coming back) is not what the plateau evaluation measures
        patience, stop = (0, False) if recovery else (p.plateau_evals, p.stop_on_success)
        record = prim["getup"] if getup else prim

        after_getup = recovery and not getup and prim.get("getup") is not None
        previous = self.workdir / (f"prim{k}_getup" if after_getup else f"prim{k - 1}")

        def make_env(n: int) -> PrimitiveEnv:
            inner = self._imitation_env(ids, n, seed, env_params)
            self._carry_discriminator(inner, previous, phase_dir)
            env = PrimitiveEnv(inner, p.eval_every, patience, stop)
            holder["env"] = env
            return env

        init = None
        if after_getup or (k > 0 and p.init == "copy"):
            source = load_policy(previous / PRIMITIVE_NAME)

            def init(model: ActorCritic) -> None:
                model.load_state_dict(source.state_dict())

        ppo_params = p.ppo.model_copy(update={"total_env_steps": max(1, int(record["budget_env_steps"]))})
        sub = ctx.phase(phase, workdir=phase_dir, seed=seed, env_factory=make_env, stop=lambda: "env" in holder and holder["env"].done)
        names = [self.clip_names[i] for i in ids]
        what = "get-up phase of P(F)" if getup else ("recovery primitive P(F)" if recovery else "primitive")
        ctx.console.print(f"pmcp: {what} {k} on {len(ids)} clip(s): {', '.join(names[:8])}{' ...' if len(names) > 8 else ''}")
        try:
            result = PPOTrainer(ppo_params, init_model=init).run(sub)
        finally:
            sub.log.close()
        env = holder.get("env")
        ck = load_checkpoint(phase_dir / "ppo.pt")
        finished = bool(ck.get("finished")) or int(ck["iteration"]) >= ppo_params.iterations
        converged = env is not None and env.done
        if not (finished or converged):
            return False  # the user stopped; PPO saved ppo.pt
        assert result.checkpoint is not None  # PPO always returns its policy / checkpoint file
        model = load_policy(result.checkpoint)
        save_policy(
            phase_dir / PRIMITIVE_NAME,
            model,
            extra={"trainer": "pmcp", "primitive": k, "clips": names, "recovery": recovery, "getup": getup},
            spec_yaml=ctx.spec_yaml(),
        )
        if getup:
            record.update({"status": "done", "iterations": int(ck["iteration"]), "env_steps": int(ck["env_steps"])})
            self._save_state(state)
            ctx.console.print(f"pmcp: get-up phase of P(F) done after {int(ck['env_steps']):,} env steps")
            return True

        def policy_fn(obs: Tensor) -> Tensor:
            with torch.no_grad():
                return model.mean_action(obs.float())

        ev = self._evaluate(ids, policy_fn, seed)
        tracker = env.tracker if env is not None else None
        if converged and tracker is not None:
            end = "all_success" if tracker.all_success and p.stop_on_success else "plateau"
        else:
            end = "budget"
        prim.update(
            {
                "status": "frozen",
                "end": end,
                "iterations": int(ck["iteration"]),
                "env_steps": int(ck["env_steps"]),
                "evaluation": ev,
                "evaluations": tracker.history if tracker is not None else [],
            }
        )
        self._save_state(state)
        ctx.console.print(f"pmcp: primitive {k} frozen ({end}): success {ev['success_rate']:.2f} on its {len(ids)} clip(s)")
        return True

    def _next_primitive(self, state: dict[str, Any]) -> bool:
        """Append the next primitive (True) or record why the primitive phase ends (False)."""
        p = self.params
        prim = state["primitives"][-1]
        ids = list(prim["clip_ids"])
        success = [bool(prim["evaluation"]["clips"][self.clip_names[i]]["success"]) for i in ids]
        hard = next_hard_set(ids, success)
        batch = p.ppo.num_envs * p.ppo.horizon
        if not hard:
            reason = "no_failures"
        elif len(state["primitives"]) >= p.max_primitives:
            reason = "max_primitives"
        elif self._primitive_budget_left(state) < batch:
            reason = "budget"
        else:
            self._add_primitive(state, hard)
            self._save_state(state)
            return True
        state["stop_reason"] = reason
        return False

    # ------------------------------------------------------------------------------ composer
    def _primitives(self, state: dict[str, Any]) -> list[ActorCritic]:
        return [load_policy(self.workdir / f"prim{int(pr['index'])}" / PRIMITIVE_NAME) for pr in state["primitives"]]

    def _train_composer(self, state: dict[str, Any]) -> bool:
        p, ctx = self.params, self.ctx
        prims = self._primitives(state)
        K = len(prims)
        ids = list(range(len(self.clip_names)))
        seed = self._phase_seed(1000)
        phase_dir = self.workdir / "composer"
        w0 = composer_bias(p.composer_init_weight, K)

        def init(model: ActorCritic) -> None:
            with torch.no_grad():
                model.action_head.bias.copy_(w0)

        env_params = self._recovery_params(p.recovery.composer_fail_states) if p.recovery is not None else None

        last = self.workdir / f"prim{int(state['primitives'][-1]['index'])}"

        def make_env(n: int) -> ComposerEnv:
            inner = self._imitation_env(ids, n, seed, env_params)
            self._carry_discriminator(inner, last, phase_dir)
            return ComposerEnv(inner, prims, p.composer_form, p.composer_eps)

        sub = ctx.phase("composer", workdir=phase_dir, seed=seed, env_factory=make_env)
        ctx.console.print(f"pmcp: composer ({p.composer_form}) over {K} primitive(s) on all {len(ids)} clips")
        try:
            result = PPOTrainer(p.composer_ppo, init_model=init).run(sub)
        finally:
            sub.log.close()
        ck = load_checkpoint(phase_dir / "ppo.pt")
        if not (bool(ck.get("finished")) or int(ck["iteration"]) >= p.composer_ppo.iterations):
            return False
        assert result.checkpoint is not None  # PPO always returns its policy / checkpoint file
        state["composer"] = {
            "status": "trained",
            "iterations": int(ck["iteration"]),
            "env_steps": int(ck["env_steps"]),
            "policy": str(Path(result.checkpoint).relative_to(self.workdir)),
        }
        state["phase"] = "final"
        self._save_state(state)
        return True

    # --------------------------------------------------------------------------------- final
    def _finish(self, state: dict[str, Any]) -> StageResult:
        p, ctx = self.params, self.ctx
        prims = self._primitives(state)
        composer = load_policy(self.workdir / "composer" / "policy.pt")
        composite = CompositePolicy(prims, composer, p.composer_form, p.composer_eps)
        ids = list(range(len(self.clip_names)))
        ev = state.get("final_evaluation")
        if ev is None:
            ev = self._evaluate(ids, composite.mean_action, self._phase_seed(2000))
            state["final_evaluation"] = ev
        final = self.workdir / FINAL_NAME
        save_checkpoint(
            final,
            {
                "format": PMCP_FORMAT,
                "composer_form": p.composer_form,
                "composer_eps": p.composer_eps,
                "primitives": [_net(m) for m in prims],
                "composer": _net(composer),
                "clip_names": self.clip_names,
                "primitive_clips": [[self.clip_names[i] for i in pr["clip_ids"]] for pr in state["primitives"]],
                "stop_reason": state["stop_reason"],
                "params": p.model_dump(mode="json"),
            },
            spec_yaml=ctx.spec_yaml(),
        )
        atomic_write_text(ctx.publish(REPORT_NAME), pmcp_report(state, p))
        state["phase"] = "done"
        self._save_state(state)
        metrics = {
            "num_primitives": float(len(prims)),
            "success_rate": float(ev["success_rate"]),
            "primitive_env_steps": float(sum(int(pr.get("env_steps", 0)) for pr in state["primitives"])),
            "composer_env_steps": float(state["composer"]["env_steps"]),
        }
        for pr in state["primitives"]:
            metrics[f"prim{pr['index']}/clips"] = float(len(pr["clip_ids"]))
            metrics[f"prim{pr['index']}/success_rate"] = float(pr["evaluation"]["success_rate"])
        ctx.console.print(f"pmcp: {len(prims)} primitive(s) + composer; success {ev['success_rate']:.2f} on all clips; {final}")
        return StageResult(checkpoint=final, metrics=metrics)


def make_pmcp(params: PMCPParams | None = None) -> PMCPTrainer:
    """Registry factory of the ``pmcp`` trainer."""
    return PMCPTrainer(params)


__all__ = [
    "ComposerEnv",
    "CompositeImitator",
    "CompositePolicy",
    "GetupPhaseParams",
    "PMCPParams",
    "PMCPTrainer",
    "PlateauTracker",
    "PrimitiveEnv",
    "RecoveryPhaseParams",
    "compose",
    "composer_bias",
    "composite_policy_from",
    "is_pmcp_checkpoint",
    "make_composite_imitator",
    "next_hard_set",
    "pmcp_report",
    "unique_clip_names",
]
