"""PMCP (PHC Sec. 4, digest phc §4): progressive primitives and their composer, as one trainer ``pmcp``.

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

**Recovery** (``recovery:``, PHC §4.4 / §4.6): after the imitation primitives, the fail-state
primitive P(F) is trained (phase ``recovery``) on the locomotion and get-up clips, initialized from
the last imitation primitive, with fallen and far starts, bonus recovery episodes and the
point-goal reward while far (PHC Eq. 4, ``RecoveryGoalParams.reward = "point"``); it is frozen at
the end of its budget and the composer mixes K + 1 primitives, trained with fail starts
interleaved (``composer_fail_states``). It needs the imitator's ``recovery_goal`` (Eq. 3's goal
switch), which then applies to every primitive. ``mocap recover`` measures the recovery rate.

With ``recovery.getup`` set, P(F) first runs [C]'s AMP-only get-up phase (in ``prim{k}_getup/``:
fallen starts only, task weight 0, AMP weight 1, initialized from the last imitation primitive) and
the point-goal phase starts from its weights.

Not implemented (see the digest): PNN lateral connections; carrying an AMP discriminator from one
phase to the next (with ``amp`` on, each phase starts a new discriminator).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Literal, Sequence

import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor, nn

from mocap.checkpoint import atomic_write_json, atomic_write_text, load_checkpoint, save_checkpoint
from mocap.interfaces import Box, StageResult, Trainer
from mocap.rl.env import StepResult
from mocap.rl.networks import ActorCritic, load_policy, save_policy
from mocap.rl.ppo import PPOParams, PPOTrainer
from mocap_phc.imitator import PHCImitator
from mocap_phc.recovery import FailStateParams

PMCP_FORMAT = "mocap_phc.pmcp/1"
STATE_FILE = "pmcp_state.json"
STATE_FORMAT = 1
FINAL_NAME = "pmcp.pt"
REPORT_NAME = "pmcp.md"
PRIMITIVE_NAME = "primitive.pt"
ComposerForm = Literal["weighted_sum", "multiplicative"]


# ------------------------------------------------------------------------------------ params
def _recovery_fail_default() -> FailStateParams:
    return FailStateParams(fall_init_prob=0.3, far_init_prob=0.3, recovery_episode_prob=0.5)


def _getup_fail_default() -> FailStateParams:
    return FailStateParams(fall_init_prob=1.0, far_init_prob=0.0, recovery_episode_prob=0.0)


def _getup_imitator_default() -> dict[str, Any]:
    return {"amp": True, "task_reward_weight": 0.0, "amp_reward_weight": 1.0}


class GetupPhaseParams(BaseModel):
    """[C]'s first P(F) phase (``getup_schedule`` before ``getup_udpate_epoch``; digest phc §4.4): pure
    AMP get-up learning from fallen states. The paper does not mention it; the official code runs
    it for about 8e4 of its ~1e5 epochs before the point-goal phase."""

    model_config = ConfigDict(extra="forbid")

    env_steps: int = Field(2_000_000, ge=1, description="env-step budget of the get-up phase (rounded up to whole PPO iterations)")
    fail_states: FailStateParams = Field(
        default_factory=_getup_fail_default,
        description="episode starts ([C] phase 1: every reset from a stored fallen state, fallInitProb 1, no far starts, "
        "no bonus recovery episodes; each start has the recovery window, after which tracking failures end the episode)",
    )
    imitator: dict[str, Any] = Field(
        default_factory=_getup_imitator_default,
        description="imitator params changed for this phase only (validated as the imitator's params): by default the AMP "
        "reward on with task weight 0 and AMP weight 1 ([C] phase 1); e.g. amp_hidden for a CPU-sized discriminator. "
        "The discriminator starts fresh and is not carried into the point-goal phase",
    )


class RecoveryPhaseParams(BaseModel):
    """The fail-state recovery primitive P(F) (PHC §4.4 / digest phc §4.4, §4.6)."""

    model_config = ConfigDict(extra="forbid")

    clips: list[str] = Field(
        default_factory=lambda: ["walk", "run", "getup"],
        description="clips of P(F)'s training set: every clip whose name contains one of these strings ([P] Q^loco, a "
        "hand-picked locomotion subset of AMASS; here the bundled walk/run clips plus the get-up clips [I])",
    )
    env_steps: int = Field(2_000_000, ge=1, description="env-step budget of P(F) (rounded up to whole PPO iterations)")
    fail_states: FailStateParams = Field(
        default_factory=_recovery_fail_default,
        description="episode starts of P(F): fallen / far starts and bonus recovery episodes ([C] phase 2: fallInitProb 0.3, "
        "recoveryEpisodeProb 0.5; [P] far starts 2-5 m); [C]'s phase 1 is ``getup``",
    )
    getup: GetupPhaseParams | None = Field(
        None,
        description="first train P(F) in [C]'s AMP-only get-up phase (fallen starts only), then the point-goal phase "
        "above starts from its weights; None: no get-up phase ([P] mentions none)",
    )
    composer_fail_states: FailStateParams | None = Field(
        default_factory=_recovery_fail_default,
        description="episode starts while training the composer ([P] 'fail-state recovery training is interleaved during "
        "composer training'); None: RSI only",
    )


def _composer_ppo_default() -> PPOParams:
    return PPOParams(log_std_init=-2.9, learn_std=False)


class PMCPParams(BaseModel):
    """Parameters of the ``pmcp`` trainer ([P] PHC paper, [C] official code, [I] this implementation)."""

    model_config = ConfigDict(extra="forbid")

    ppo: PPOParams = Field(
        default_factory=PPOParams,
        description="PPO of every primitive; its total_env_steps is the budget of the whole primitive phase, summed over "
        "the primitives ([I]; [P] trains each primitive 'until convergence')",
    )
    primitive_env_steps: int | None = Field(
        None,
        ge=1,
        description="env-step budget of one primitive (rounded up to whole PPO iterations); None: whatever is left of "
        "ppo.total_env_steps ([I])",
    )
    primitive0: Path | None = Field(
        None,
        description="a trained single-primitive imitator (a policy.pt of this imitator's observation and action, the "
        "network sizes of ppo) used as primitive 0: not trained, only evaluated on every clip to find the hard set of "
        "primitive 1 ([I]; PHC+ on top of an existing PHC; [C] likewise starts PMCP from a trained imitator's checkpoint). "
        "Relative to the spec file",
    )
    max_primitives: int = Field(
        3, ge=1, description="most imitation primitives ([P] 3 imitation primitives + the recovery primitive; [C] num_prim 4)"
    )
    eval_every: int = Field(
        50,
        ge=1,
        description="PPO iterations between the plateau evaluations of a primitive (every clip of its set from frame 0, "
        "deterministic); reuses the env's hard-negative evaluation when both fall on one iteration ([C] evaluates every "
        "few thousand epochs)",
    )
    plateau_evals: int = Field(
        5,
        ge=0,
        description="freeze a primitive after this many consecutive evaluations without improvement (PlateauTracker: no "
        "more clips succeeding than ever before and no clip succeeding for the first time); 0: train for the whole budget "
        "([P] 'until the success rate no longer increases'; [C] forward_pmcp uses the last 5 evaluations)",
    )
    stop_on_success: bool = Field(
        True, description="freeze a primitive as soon as an evaluation succeeds on every clip of its set ([I])"
    )
    init: Literal["copy", "fresh"] = Field(
        "copy",
        description="primitive k+1 starts from primitive k's weights, critic and normalizer ('copy': [P] variant (b) weight "
        "sharing, [C] forward_pmcp copies actors.k into actors.k+1, value function continued) or from a fresh random init "
        "('fresh'; [P] variant (a) adds PNN lateral connections, not implemented)",
    )
    composer_form: ComposerForm = Field(
        "multiplicative",
        description="how the composer's weights w mix the frozen primitives' means mu_i: 'multiplicative' = "
        "sum_i c_i mu_i / sum_i c_i with c_i = relu(w_i) + composer_eps ([P] Eq. 5/6, MCP with the primitives' equal "
        "fixed sigma) or 'weighted_sum' = sum_i relu(w_i) mu_i, unnormalized ([C] ReLU composer output)",
    )
    composer_eps: float = Field(
        1e-6, ge=0.0, description="multiplicative form: added to every relu(w_i) so that the normalizer never vanishes ([I])"
    )
    composer_init_weight: float | None = Field(
        None,
        description="initial composer output (the action head's bias) for every primitive; None: 1/K, i.e. the mean of the "
        "primitives' means in both forms ([I]; [C] starts from a random ReLU MLP)",
    )
    recovery: RecoveryPhaseParams | None = Field(
        None,
        description="train the fail-state recovery primitive P(F) after the imitation primitives (initialized from the last "
        "one, point-goal reward while far, fallen/far starts) and give the composer K+1 primitives ([P] 3 + P(F)); needs "
        "the imitator's recovery_goal (the observation switch of PHC Eq. 3). None: no recovery primitive",
    )
    composer_ppo: PPOParams = Field(
        default_factory=_composer_ppo_default,
        description="PPO of the composer on all clips (its actor_hidden / activation are the composer MLP: [C] [1024, 512], "
        "ReLU); default exploration on the weights with fixed sigma = exp(-2.9) ([C])",
    )


# ----------------------------------------------------------------------------- composer math
def compose(weights: Tensor, means: Tensor, form: ComposerForm, eps: float = 1e-6) -> Tensor:
    """Mix the primitives' means (N, K, A) with composer weights (N, K) into actions (N, A).

    * ``weighted_sum`` ([C]): ``a = sum_i relu(w_i) mu_i``;
    * ``multiplicative`` ([P], MCP with equal sigma): ``c_i = relu(w_i) + eps``,
      ``a = sum_i c_i mu_i / sum_i c_i`` (the mean of the means where ``sum_i c_i = 0``).
    """
    w = torch.relu(weights.to(means.dtype))
    if form == "weighted_sum":
        return (w.unsqueeze(-1) * means).sum(-2)
    if form == "multiplicative":
        c = w + eps
        total = c.sum(-1, keepdim=True)
        mixed = (c.unsqueeze(-1) * means).sum(-2) / total.clamp_min(torch.finfo(means.dtype).tiny)
        return torch.where(total > 0, mixed, means.mean(-2))
    raise ValueError(f"unknown composer form {form!r}; choose 'weighted_sum' or 'multiplicative'")


class CompositePolicy(nn.Module):
    """Frozen primitives + composer as one policy on PHC's flat observation (``mean_action``/``act``).

    ``mean_action(obs)``: composer mean weights -> :func:`compose` of the primitives' means.
    ``act(obs)``: the same with weights sampled from the composer's Gaussian (the primitives stay
    deterministic, as in [C]). ``weights(obs)`` gives the composer's deterministic weights.
    """

    def __init__(self, primitives: Sequence[ActorCritic], composer: ActorCritic, form: ComposerForm, eps: float = 1e-6):
        super().__init__()
        if composer.action_dim != len(primitives):
            raise ValueError(f"the composer outputs {composer.action_dim} weights for {len(primitives)} primitives")
        self.primitives = nn.ModuleList(primitives)
        self.composer = composer
        self.form = form
        self.eps = float(eps)
        self.obs_dim = int(composer.obs_dim)
        for p in self.parameters():
            p.requires_grad_(False)
        self.eval()

    @property
    def obs_norm(self) -> Any:
        """The composer's observation normalizer (fit on every clip), for consumers of ``policy.obs_norm``
        such as PULSE's ``normalizer='teacher'``."""
        return self.composer.obs_norm

    def primitive_means(self, obs: Tensor) -> Tensor:
        """(N, K, A) the primitives' deterministic actions, each on its own normalized observation."""
        return torch.stack([p.mean_action(obs) for p in self.primitives], dim=-2)

    def weights(self, obs: Tensor) -> Tensor:
        return self.composer.mean_action(obs)

    @torch.no_grad()
    def mean_action(self, obs: Tensor) -> Tensor:
        return compose(self.weights(obs), self.primitive_means(obs), self.form, self.eps)

    @torch.no_grad()
    def act(self, obs: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        w, logp, value = self.composer.act(obs)
        return compose(w, self.primitive_means(obs), self.form, self.eps), logp, value

    def forward(self, obs: Tensor) -> Tensor:
        return self.mean_action(obs)


# ------------------------------------------------------------------------------- the logic
class PlateauTracker:
    """When to freeze a primitive, from its evaluations (per-clip success vectors).

    Evaluation ``j`` with success set ``S_j`` **improves** when ``|S_j| > max_{i<j} |S_i|`` (more
    clips succeed than at any earlier evaluation; the first evaluation always improves) or when
    ``S_j`` holds a clip that no earlier evaluation succeeded on. ``stale`` counts the consecutive
    non-improving evaluations since the last improvement; the plateau is reached when
    ``patience > 0`` and ``stale >= patience``. ``all_success`` is true when the last evaluation
    succeeded on every clip.
    """

    def __init__(self, patience: int, num_clips: int):
        self.patience = int(patience)
        self.num_clips = int(num_clips)
        self.best_count = -1
        self.ever = [False] * self.num_clips
        self.stale = 0
        self.last_all = False
        self.history: list[dict[str, Any]] = []  # per evaluation: iteration, number of clips succeeded, improved

    def update(self, iteration: int, success: Sequence[bool]) -> bool:
        s = [bool(x) for x in success]
        if len(s) != self.num_clips:
            raise ValueError(f"expected {self.num_clips} clip results, got {len(s)}")
        count = sum(s)
        improved = count > self.best_count or any(x and not e for x, e in zip(s, self.ever))
        self.best_count = max(self.best_count, count)
        self.ever = [x or e for x, e in zip(s, self.ever)]
        self.stale = 0 if improved else self.stale + 1
        self.last_all = all(s)
        self.history.append({"iteration": int(iteration), "succeeded": count, "improved": improved})
        return improved

    @property
    def plateaued(self) -> bool:
        return self.patience > 0 and self.stale >= self.patience

    @property
    def all_success(self) -> bool:
        return self.last_all

    def state_dict(self) -> dict[str, Any]:
        return {
            "patience": self.patience,
            "num_clips": self.num_clips,
            "best_count": self.best_count,
            "ever": list(self.ever),
            "stale": self.stale,
            "last_all": self.last_all,
            "history": [dict(h) for h in self.history],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if int(state["num_clips"]) != self.num_clips:
            raise ValueError(f"plateau state for {state['num_clips']} clips, this tracker has {self.num_clips}")
        self.best_count = int(state["best_count"])
        self.ever = [bool(x) for x in state["ever"]]
        self.stale = int(state["stale"])
        self.last_all = bool(state["last_all"])
        self.history = [dict(h) for h in state["history"]]


def unique_clip_names(names: Sequence[str]) -> list[str]:
    """Clip names as :class:`~mocap.motion.library.MotionLibrary` spells them (``#2``, ``#3``... on repeats)."""
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}#{seen[n]}")
    return out


def next_hard_set(clip_ids: Sequence[int], success: Sequence[bool]) -> list[int]:
    """The next primitive's clips: those of ``clip_ids`` (full-library indices) whose freeze
    evaluation failed (``success[i]`` is the result of ``clip_ids[i]``). A subset by construction."""
    if len(clip_ids) != len(success):
        raise ValueError("one success flag per clip")
    return [int(c) for c, ok in zip(clip_ids, success) if not ok]


# -------------------------------------------------------------------------------- the envs
class PrimitiveEnv:
    """A primitive's training env: an :class:`~mocap_phc.env.ImitationEnv` whose ``after_iteration``
    also feeds a :class:`PlateauTracker` every ``eval_every`` iterations; the tracker travels in
    ``state_dict``. ``done`` turns True once the primitive should be frozen."""

    def __init__(self, inner: Any, eval_every: int, patience: int, stop_on_success: bool):
        self.inner = inner
        self.num_envs = inner.num_envs
        self.obs_dim = inner.obs_dim
        self.action_space = inner.action_space
        self.device = getattr(inner, "device", torch.device("cpu"))
        self.eval_every = int(eval_every)
        self.stop_on_success = bool(stop_on_success)
        self.tracker = PlateauTracker(patience, inner.library.num_clips)

    @property
    def done(self) -> bool:
        return self.tracker.plateaued or (self.stop_on_success and self.tracker.all_success)

    def reset(self) -> Tensor:
        return self.inner.reset()

    def step(self, actions: Tensor) -> StepResult:
        return self.inner.step(actions)

    def after_iteration(self, iteration: int, policy_fn: Callable[[Tensor], Tensor]) -> dict[str, float]:
        before = self.inner.last_evaluation
        out = dict(self.inner.after_iteration(iteration, policy_fn) or {})
        if iteration > 0 and iteration % self.eval_every == 0:
            res = self.inner.last_evaluation
            if res is None or res is before:  # the env did not evaluate on this iteration
                res = self.inner.evaluate_clips(policy_fn)
            names = self.inner.library.clip_names
            improved = self.tracker.update(iteration, [res["clips"][n]["success"] for n in names])
            out.update(
                {
                    "pmcp/success_rate": res["success_rate"],
                    "pmcp/improved": float(improved),
                    "pmcp/stale_evals": float(self.tracker.stale),
                }
            )
        return out

    def state_dict(self) -> dict[str, Any]:
        return {"inner": self.inner.state_dict(), "plateau": self.tracker.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.inner.load_state_dict(state["inner"])
        self.tracker.load_state_dict(state["plateau"])

    def close(self) -> None:
        self.inner.close()


class ComposerEnv:
    """The composer's VecEnv: same observations as the wrapped ``ImitationEnv``; the action is the
    composer's weight vector (K,), mapped to the imitation action by :func:`compose` of the frozen
    primitives' deterministic means on the current observation."""

    def __init__(self, inner: Any, primitives: Sequence[ActorCritic], form: ComposerForm, eps: float = 1e-6):
        self.inner = inner
        self.num_envs = inner.num_envs
        self.obs_dim = inner.obs_dim
        self.device = getattr(inner, "device", torch.device("cpu"))
        self.primitives = [p.eval() for p in primitives]
        for p in self.primitives:
            for q in p.parameters():
                q.requires_grad_(False)
        self.form = form
        self.eps = float(eps)
        self.num_primitives = K = len(self.primitives)
        self.action_space = Box((K,))

    def means(self, obs: Tensor) -> Tensor:
        with torch.no_grad():
            return torch.stack([p.mean_action(obs.float()) for p in self.primitives], dim=-2)

    def to_action(self, obs: Tensor, weights: Tensor) -> Tensor:
        return compose(torch.as_tensor(weights).to(obs.device).float(), self.means(obs), self.form, self.eps)

    def reset(self) -> Tensor:
        return self.inner.reset()

    def step(self, weights: Tensor) -> StepResult:
        obs = self.inner.current_obs()
        res = self.inner.step(self.to_action(obs, weights))
        w = torch.relu(torch.as_tensor(weights).float())
        for i in range(self.num_primitives):
            res.info[f"composer/w{i}"] = w[:, i]
        return res

    def after_iteration(self, iteration: int, policy_fn: Callable[[Tensor], Tensor]) -> dict[str, float]:
        def composite(obs: Tensor) -> Tensor:
            return self.to_action(obs, policy_fn(obs))

        return self.inner.after_iteration(iteration, composite)

    def state_dict(self) -> dict[str, Any]:
        return self.inner.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.inner.load_state_dict(state)

    def close(self) -> None:
        self.inner.close()


# ----------------------------------------------------------------------------- the trainer
class _SeededPPO(PPOTrainer):
    """PPO whose freshly built model is first passed to ``init_model`` (copied weights, composer bias).
    A resumed run overwrites it from ``ppo.pt`` as usual."""

    def __init__(self, params: PPOParams, init_model: Callable[[ActorCritic], None] | None = None):
        super().__init__(params)
        self.init_model = init_model

    def build_model(self, obs_dim: int, action_space: Any) -> ActorCritic:
        model = super().build_model(obs_dim, action_space)
        if self.init_model is not None:
            self.init_model(model)
        return model


class _PhaseLog:
    """A metrics logger for one phase: its own stage label (``imitator/prim0``) in the same
    ``metrics.jsonl``, so that PPO's resume truncation touches only this phase's lines."""

    def __new__(cls, parent: Any, phase: str) -> Any:
        from mocap.runlog import MetricsLogger

        path = getattr(parent, "path", None)
        stage = getattr(parent, "stage", "stage")
        if path is None:
            return _PassLog(parent)
        return MetricsLogger(Path(path), f"{stage}/{phase}", tensorboard_dir=getattr(parent, "_tb_dir", None))


class _PassLog:
    def __init__(self, parent: Any):
        self.parent = parent

    def log(self, step: int, **metrics: float) -> None:
        self.parent.log(step, **metrics)

    def truncate_after(self, step: int) -> None:
        pass

    def close(self) -> None:
        pass


@dataclass
class _PhaseContext:
    """What :class:`PPOTrainer` uses of a stage context, for one PMCP phase."""

    parent: Any
    workdir: Path
    seed: int
    env_factory: Callable[[int], Any]
    log: Any
    halt: Callable[[], bool]

    @property
    def device(self) -> Any:
        return getattr(self.parent, "device", "cpu")

    @property
    def console(self) -> Any:
        return self.parent.console

    def make_rl_env(self, num_envs: int) -> Any:
        return self.env_factory(num_envs)

    def should_stop(self) -> bool:
        return bool(self.halt()) or bool(self.parent.should_stop())

    def spec_yaml(self) -> str:
        return self.parent.spec_yaml()


class PMCPTrainer(Trainer):
    """The ``pmcp`` trainer of the ``imitator`` stage (module docstring)."""

    def __init__(self, params: PMCPParams | None = None):
        self.params = params or PMCPParams()

    # ----------------------------------------------------------------------------- helpers
    def _setup(self, ctx: Any) -> None:
        self.ctx = ctx
        self.workdir = Path(ctx.workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.component = ctx.stage_component()
        if not hasattr(self.component, "params") or not hasattr(self.component, "observation"):
            raise TypeError("the pmcp trainer needs the phc imitator")
        self.skeleton = self.component.skeleton
        motion_set = ctx.build("motions").load(self.skeleton)
        for path, reason in getattr(motion_set, "skipped", []):
            ctx.console.print(f"[yellow]skipped[/] {path}: {reason}")
        self.clips = list(motion_set.clips)
        if not self.clips:
            raise ValueError("pmcp: the motion set has no clips")
        self.clip_names = unique_clip_names([c.name for c in self.clips])
        if self.params.recovery is not None and getattr(self.component.params, "recovery_goal", None) is None:
            from mocap.errors import UserError

            raise UserError(
                "pmcp recovery needs the fail-state goal switch: set imitator.params.recovery_goal (e.g. {form: paper}); "
                "every primitive and the composer observe through it"
            )

    def _library(self, ids: Sequence[int]) -> Any:
        from mocap.motion.library import MotionLibrary

        return MotionLibrary([self.clips[i] for i in ids], self.skeleton)

    def _imitation_env(self, ids: Sequence[int], num_envs: int, seed: int, params: Any = None) -> Any:
        from mocap_phc.env import ImitationEnv

        ctx, sk = self.ctx, self.skeleton
        sim = ctx.build("simulator", skeleton=sk, num_envs=num_envs, seed=seed)

        def eval_sim(n: int) -> Any:
            return ctx.build("simulator", skeleton=sk, num_envs=n, seed=seed)

        return ImitationEnv(
            params if params is not None else self.component.params, sk, self._library(ids), sim, seed=seed, eval_simulator_factory=eval_sim
        )

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
        if path.is_file():
            state = json.loads(path.read_text(encoding="utf-8"))
            if state.get("format") != STATE_FORMAT:
                raise ValueError(f"{path}: not a PMCP state file (format {state.get('format')!r})")
            if state["clip_names"] != self.clip_names:
                raise ValueError(f"{path}: made with a different motion set")
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
        state["primitives"].append(
            {"index": len(state["primitives"]), "clip_ids": ids, "budget_env_steps": int(budget), "status": "training"}
        )

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

    def _getup_params(self) -> Any:
        """The imitator's params for [C]'s get-up phase: its fallen starts and imitator overrides."""
        rec = self.params.recovery
        assert rec is not None and rec.getup is not None
        base = self._recovery_params(rec.getup.fail_states)
        return type(base).model_validate({**base.model_dump(), **rec.getup.imitator})

    def _train_primitive(self, state: dict[str, Any], prim: dict[str, Any], getup: bool = False) -> bool:
        """Train primitive ``prim`` until it should be frozen; freeze it. False when stopped by the user.
        ``getup``: run P(F)'s get-up phase instead (``prim["getup"]``, directory ``prim{k}_getup``)."""
        p, ctx = self.params, self.ctx
        k, ids = int(prim["index"]), list(prim["clip_ids"])
        if k == 0 and p.primitive0 is not None:
            self._given_primitive(state, prim)
            return True
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

        def make_env(n: int) -> PrimitiveEnv:
            env = PrimitiveEnv(self._imitation_env(ids, n, seed, env_params), p.eval_every, patience, stop)
            holder["env"] = env
            return env

        init = None
        after_getup = recovery and not getup and prim.get("getup") is not None
        if after_getup or (k > 0 and p.init == "copy"):
            source = load_policy(self.workdir / (f"prim{k}_getup" if after_getup else f"prim{k - 1}") / PRIMITIVE_NAME)

            def init(model: ActorCritic) -> None:
                model.load_state_dict(source.state_dict())

        ppo_params = p.ppo.model_copy(update={"total_env_steps": max(1, int(record["budget_env_steps"]))})
        log = _PhaseLog(ctx.log, phase)
        sub = _PhaseContext(ctx, phase_dir, seed, make_env, log, lambda: "env" in holder and holder["env"].done)
        names = [self.clip_names[i] for i in ids]
        what = "get-up phase of P(F)" if getup else ("recovery primitive P(F)" if recovery else "primitive")
        ctx.console.print(f"pmcp: {what} {k} on {len(ids)} clip(s): {', '.join(names[:8])}{' ...' if len(names) > 8 else ''}")
        try:
            result = _SeededPPO(ppo_params, init).run(sub)
        finally:
            log.close()
        env = holder.get("env")
        ck = load_checkpoint(phase_dir / "ppo.pt")
        finished = bool(ck.get("finished")) or int(ck["iteration"]) >= ppo_params.iterations
        converged = env is not None and env.done
        if not (finished or converged):
            return False  # the user stopped; PPO saved ppo.pt
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
        w0 = 1.0 / K if p.composer_init_weight is None else float(p.composer_init_weight)

        def init(model: ActorCritic) -> None:
            with torch.no_grad():
                model.action_head.bias.fill_(w0)

        env_params = self._recovery_params(p.recovery.composer_fail_states) if p.recovery is not None else None

        def make_env(n: int) -> ComposerEnv:
            return ComposerEnv(self._imitation_env(ids, n, seed, env_params), prims, p.composer_form, p.composer_eps)

        log = _PhaseLog(ctx.log, "composer")
        sub = _PhaseContext(ctx, phase_dir, seed, make_env, log, lambda: False)
        ctx.console.print(f"pmcp: composer ({p.composer_form}) over {K} primitive(s) on all {len(ids)} clips")
        try:
            result = _SeededPPO(p.composer_ppo, init).run(sub)
        finally:
            log.close()
        ck = load_checkpoint(phase_dir / "ppo.pt")
        if not (bool(ck.get("finished")) or int(ck["iteration"]) >= p.composer_ppo.iterations):
            return False
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


def _net(model: ActorCritic) -> dict[str, Any]:
    return {"config": model.config, "state_dict": {k: v.detach().cpu() if isinstance(v, Tensor) else v for k, v in model.state_dict().items()}}


def _unnet(data: dict[str, Any], device: Any) -> ActorCritic:
    model = ActorCritic.from_config(data["config"])
    model.load_state_dict(data["state_dict"])
    return model.to(device).eval()


def pmcp_report(state: dict[str, Any], params: PMCPParams) -> str:
    """The per-clip markdown report: each primitive's clip set and freeze evaluation, the composite's."""
    names: list[str] = state["clip_names"]
    prims = state["primitives"]
    lines = [
        "# PMCP",
        "",
        (
            f"{len(prims)} primitive(s) (init {params.init!r}), composer {params.composer_form!r}; "
            f"primitive phase ended: {state.get('stop_reason')}."
        ),
        "",
        "| primitive | clips | end | iterations | env steps | success on its clips |",
        "|---|---|---|---|---|---|",
    ]
    for pr in prims:
        ev = pr.get("evaluation") or {}
        rate = ev.get("success_rate")
        getup = pr.get("getup")
        tag = " (recovery)" if pr.get("recovery") else ""
        if getup is not None:
            tag = f" (recovery, after a get-up phase of {getup.get('env_steps', '-')} env steps)"
        lines.append(
            f"| {pr['index']}{tag} | {len(pr['clip_ids'])} | {pr.get('end', '-')} | {pr.get('iterations', '-')} | "
            f"{pr.get('env_steps', '-')} | {'-' if rate is None else f'{rate:.3f}'} |"
        )
    final = state.get("final_evaluation") or {}
    if final:
        lines += ["", f"Composite (composer + {len(prims)} primitives) on all clips: success {final['success_rate']:.3f}."]
    header = "| clip | " + " | ".join(f"prim {pr['index']}" for pr in prims) + " | composite |"
    lines += ["", "Per clip: `ok` / `fail` at the primitive's freeze evaluation (blank: not in its set), and the composite.", ""]
    lines += [header, "|---|" + "---|" * (len(prims) + 1)]
    for name in names:
        cells = []
        for pr in prims:
            r = ((pr.get("evaluation") or {}).get("clips") or {}).get(name)
            cells.append("" if r is None else ("ok" if r["success"] else "fail"))
        r = (final.get("clips") or {}).get(name)
        cells.append("" if r is None else ("ok" if r["success"] else "fail"))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ the imitator
def is_pmcp_checkpoint(data: Any) -> bool:
    return isinstance(data, dict) and data.get("format") == PMCP_FORMAT


def composite_policy_from(data: dict[str, Any], device: Any = "cpu") -> CompositePolicy:
    """The :class:`CompositePolicy` stored in a ``pmcp.pt`` payload."""
    if not is_pmcp_checkpoint(data):
        raise ValueError(f"not a PMCP checkpoint (format {data.get('format')!r}, expected {PMCP_FORMAT!r})")
    prims = [_unnet(d, device) for d in data["primitives"]]
    return CompositePolicy(prims, _unnet(data["composer"], device), data["composer_form"], float(data["composer_eps"])).to(device)


class CompositeImitator(PHCImitator):
    """The PHC imitator acting with a PMCP composite (:class:`CompositePolicy`): ``observe``,
    ``policy_output`` (the mixed action, before the action map), ``to_pd_targets`` and ``act``
    exactly as for a single policy (:class:`~mocap_phc.env.PolicyImitator`)."""

    def __init__(self, params: Any, skeleton: Any, composite: CompositePolicy, device: Any = "cpu"):
        super().__init__(params, skeleton, composite, device)
        self.composite = composite

    @property
    def num_primitives(self) -> int:
        return len(self.composite.primitives)


def make_composite_imitator(params: Any, skeleton: Any, data: dict[str, Any], device: Any = "cpu") -> CompositeImitator:
    """``make_phc`` on a ``pmcp.pt`` payload."""
    composite = composite_policy_from(data, device)
    imitator = CompositeImitator(params, skeleton, composite, device)
    if composite.obs_dim != imitator.obs_dim:
        raise ValueError(
            f"the PMCP checkpoint takes {composite.obs_dim} observation dims, but phc with obs={params.obs!r} on "
            f"{skeleton.name!r} ({skeleton.num_bodies} bodies) produces {imitator.obs_dim}"
        )
    return imitator


def make_pmcp(params: PMCPParams | None = None) -> PMCPTrainer:
    """Registry factory of the ``pmcp`` trainer."""
    return PMCPTrainer(params)


__all__ = [
    "ComposerEnv",
    "CompositeImitator",
    "CompositePolicy",
    "PMCPParams",
    "PMCPTrainer",
    "PlateauTracker",
    "PrimitiveEnv",
    "compose",
    "composite_policy_from",
    "is_pmcp_checkpoint",
    "make_composite_imitator",
    "next_hard_set",
    "pmcp_report",
    "unique_clip_names",
]
