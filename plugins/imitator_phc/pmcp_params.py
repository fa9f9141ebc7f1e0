"""Parameters of the ``pmcp`` trainer (:mod:`mocap_phc.pmcp`): :class:`PMCPParams`, the fail-state
recovery primitive's :class:`RecoveryPhaseParams` with its optional get-up phase
(:class:`GetupPhaseParams`), and the composer forms (``ComposerForm``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from mocap.rl.ppo_params import PPOParams
from mocap.fail_state_params import FailStateParams
from mocap_phc.planner_params import GetUpPlannerParams

ComposerForm = Literal["weighted_sum", "multiplicative"]


# ------------------------------------------------------------------------------------ params
def _recovery_fail_default() -> FailStateParams:
    return FailStateParams(fall_init_prob=0.3, far_init_prob=0.3, recovery_episode_prob=0.5)


def _getup_fail_default() -> FailStateParams:
    return FailStateParams(fall_init_prob=1.0, far_init_prob=0.0, recovery_episode_prob=0.0)


def _getup_imitator_default() -> dict[str, Any]:
    return {"amp": True, "task_reward_weight": 0.0, "amp_reward_weight": 1.0, "getup_starts": None}


class GetupPhaseParams(BaseModel):
    """[C]'s first P(F) phase (``getup_schedule`` before ``getup_udpate_epoch``; official code
    phc/env/tasks/humanoid_im_getup.py ``update_getup_schedule``): pure AMP get-up learning from
    fallen states. The paper does not mention it; the official code runs it for about 8e4 of its
    ~1e5 epochs before the point-goal phase."""

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
        "reward on with task weight 0 and AMP weight 1 ([C] phase 1) and no get-up starts (they track a get-up clip; AMP "
        "excludes them); e.g. amp_hidden for a CPU-sized discriminator. "
        "The discriminator starts fresh and is not carried into the point-goal phase",
    )


class PlannerDistillParams(BaseModel):
    """DAgger of P(F) from the planner-driven primitive (module docstring); the env-step budget is
    the recovery phase's ``env_steps``."""

    model_config = ConfigDict(extra="forbid")
    num_envs: int = Field(64, ge=1, description="fallen starts simulated in parallel per rollout")
    seconds: float = Field(10.0, gt=0, description="length of a rollout, s (the recovery protocol's 10 s)")
    far_prob: float = Field(0.5, ge=0, le=1, description="share of the starts also moved away from the reference (the protocol's 0.5)")
    far_range: tuple[float, float] = Field((2.0, 5.0), description="distance of a far start, m (PHC's 2-5 m)")
    fall: FailStateParams = Field(default_factory=FailStateParams, description="how the fallen states are made (the protocol's defaults)")
    planner: GetUpPlannerParams = Field(default_factory=GetUpPlannerParams, description="the teacher's get-up planner")
    teacher_until: float = Field(0.3, gt=0, le=1, description="share of the iterations over which beta (teacher-acting envs) falls from 1 to teacher_floor")
    teacher_floor: float = Field(0.0, ge=0, le=1, description="beta never falls below this (1: the teacher always acts, behaviour cloning)")
    action_noise: float = Field(0.0, ge=0, description="std of Gaussian noise added to the executed PD targets, rad (DART; 0: none)")
    buffer_iterations: int = Field(4, ge=1, description="rollouts kept for fitting (the newest)")
    epochs: int = Field(4, ge=1, description="passes over the kept rollouts per iteration")
    minibatch_size: int = Field(4096, ge=1, description="samples per gradient step")
    lr: float = Field(1e-4, gt=0, description="Adam learning rate of the student's actor")
    checkpoint_every: int = Field(5, ge=1, description="iterations between resumable checkpoints")


class RecoveryPhaseParams(BaseModel):
    """The fail-state recovery primitive P(F) (PHC Sec. 3.2 "Fail-state Recovery", Eqs. 3-4;
    official code phc/env/tasks/humanoid_im_getup.py)."""

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
    method: Literal["rl", "planner_distill"] = Field(
        "rl",
        description="how P(F) learns: 'rl' = PPO with the point-goal reward ([P] Sec. 3.2, [C]); 'planner_distill' = DAgger "
        "from the last imitation primitive driven by the get-up planner (mocap_phc.pmcp_distill; [I], neither the paper's "
        "nor the code's), on fallen starts with the recovery protocol's still reference; env_steps is its budget",
    )
    distill: PlannerDistillParams = Field(default_factory=PlannerDistillParams, description="the 'planner_distill' method's settings")
    composer_fail_states: FailStateParams | None = Field(
        default_factory=_recovery_fail_default,
        description="episode starts while training the composer ([P] 'fail-state recovery training is interleaved during composer training'); None: RSI only",
    )

    @model_validator(mode="after")
    def _one_method(self) -> "RecoveryPhaseParams":
        if self.method == "planner_distill" and self.getup is not None:
            raise ValueError("recovery.getup is the RL method's first phase; with method 'planner_distill' leave it out")
        return self


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
        description="env-step budget of one primitive (rounded up to whole PPO iterations); None: whatever is left of ppo.total_env_steps ([I])",
    )
    primitive0: Path | None = Field(
        None,
        description="a trained single-primitive imitator (a policy.pt of this imitator's observation and action, the "
        "network sizes of ppo) used as primitive 0: not trained, only evaluated on every clip to find the hard set of "
        "primitive 1 ([I]; PHC+ on top of an existing PHC; [C] likewise starts PMCP from a trained imitator's checkpoint). "
        "Relative to the spec file",
    )
    max_primitives: int = Field(3, ge=1, description="most imitation primitives ([P] 3 imitation primitives + the recovery primitive; [C] num_prim 4)")
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
    stop_on_success: bool = Field(True, description="freeze a primitive as soon as an evaluation succeeds on every clip of its set ([I])")
    init: Literal["copy", "fresh"] = Field(
        "copy",
        description="primitive k+1 starts from primitive k's weights, critic and normalizer ('copy': [P] variant (b) weight "
        "sharing, [C] forward_pmcp copies actors.k into actors.k+1, value function continued) or from a fresh random init "
        "('fresh'; [P] variant (a) adds PNN lateral connections, not implemented)",
    )
    carry_discriminator: bool = Field(
        True,
        description="with the imitator's amp on: each phase (next primitive, P(F)'s get-up and point-goal phases, the "
        "composer) continues the previous phase's AMP discriminator (network, optimizer, update count) instead of a new "
        "one; its demo windows come from the new phase's clips ([P] Sec. 3.2 and Alg. 1, and [C]: the value function and the "
        "discriminator are not re-initialized between primitives, only fine-tuned). False: a fresh discriminator per phase",
    )
    composer_form: ComposerForm = Field(
        "multiplicative",
        description="how the composer's weights w mix the frozen primitives' means mu_i: 'multiplicative' = "
        "sum_i c_i mu_i / sum_i c_i with c_i = relu(w_i) + composer_eps ([P] Eq. 5/6, MCP with the primitives' equal "
        "fixed sigma) or 'weighted_sum' = sum_i relu(w_i) mu_i, unnormalized ([C] ReLU composer output)",
    )
    composer_eps: float = Field(1e-6, ge=0.0, description="multiplicative form: added to every relu(w_i) so that the normalizer never vanishes ([I])")
    composer_init_weight: float | list[float] | None = Field(
        None,
        description="initial composer output (the action head's bias): one value for every primitive, or one per primitive "
        "in order (P(F) last; e.g. [1, 0] starts the composite as primitive 0 alone, so it tracks as that primitive does "
        "before the composer has learned when to hand over); None: 1/K, i.e. the mean of the primitives' means in both "
        "forms ([I]; [C] starts from a random ReLU MLP)",
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

    @model_validator(mode="after")
    def _init_weights_fit(self) -> "PMCPParams":
        w = self.composer_init_weight
        most = self.max_primitives + (1 if self.recovery is not None else 0)
        if isinstance(w, list) and not 1 <= len(w) <= most:
            raise ValueError(f"composer_init_weight has {len(w)} values; the composer mixes at most {most} primitives (max_primitives + P(F))")
        return self
