"""PPO's parameters (:class:`PPOParams`) and the two rules they feed: the initial exploration σ
(:func:`initial_log_std`) and the KL-adaptive learning rate (:func:`adapt_lr`). The algorithm is in
:mod:`mocap.rl.ppo`, which re-exports all three."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from mocap.bounds import MAX_BATCH, MAX_HORIZON, EnvCount, EnvSteps, EpochCount, LayerWidth, LearningRate, LogStd, ThreadCount
from mocap.roles import Box


class PPOParams(BaseModel):
    """PPO hyper-parameters (defaults: 2-core CPU recipe; PHC's rl_games values in the descriptions)."""

    model_config = ConfigDict(extra="forbid")

    num_envs: EnvCount = Field(128, description="parallel envs (PHC: 1536)")
    horizon: int = Field(64, ge=1, le=MAX_HORIZON, description="steps per env per iteration; batch = num_envs × horizon (PHC: 32)")
    max_consecutive_faults: int = Field(10, ge=0, description="stop after this many consecutive batches with non-finite values (each is skipped); 0: only skip")
    total_env_steps: EnvSteps = Field(10_000_000, description="training budget in env steps (rounded up to whole iterations)")
    epochs: EpochCount = Field(4, description="passes over each batch (PHC: 6 mini-epochs)")
    minibatch_size: int = Field(2048, ge=1, le=MAX_BATCH, description="samples per gradient step; ≤ batch; a remainder is dropped each epoch (PHC: 16384)")
    lr: LearningRate = Field(3e-4, description="Adam learning rate (PHC: 2e-5)")
    lr_schedule: Literal["constant", "linear", "adaptive"] = Field(
        "constant",
        description="'linear' anneals lr to 0 over the budget; 'adaptive' divides lr by 1.5 after a minibatch whose KL "
        "to the rollout policy exceeds 2 x desired_kl and multiplies it by 1.5 when below desired_kl / 2, within "
        "[lr_min, lr_max] (the rl_games / rsl_rl rule; the lr lives in the optimizer state, so it resumes exactly) "
        "(PHC: constant)",
    )
    desired_kl: float = Field(0.01, gt=0, description="KL target of the 'adaptive' schedule (rl_games / rsl_rl: 0.008-0.01)")
    lr_min: LearningRate = Field(1e-6, description="floor of the 'adaptive' schedule")
    lr_max: LearningRate = Field(1e-2, description="ceiling of the 'adaptive' schedule")
    gamma: float = Field(0.95, ge=0, le=1, description="discount γ (PHC: 0.99)")
    gae_lambda: float = Field(0.95, ge=0, le=1, description="GAE λ (PHC: 0.95)")
    clip: float = Field(0.2, gt=0, description="PPO ratio clip ε (PHC: 0.2)")
    value_clip: float | None = Field(None, gt=0, description="value clipping ε; None = no value clipping (PHC: none)")
    value_coef: float = Field(
        0.5,
        ge=0,
        description="critic loss weight; with separate networks and Adam it matters mainly through the shared grad-norm clip (PHC: 5)",
    )
    entropy_coef: float = Field(0.0, ge=0, description="entropy bonus weight (PHC: 0)")
    bounds_coef: float = Field(0.0, ge=0, description="weight of the bound loss on the Gaussian mean (PHC: 10)")
    soft_bound: float = Field(1.0, gt=0, description="the bound loss penalizes |μ_i| beyond this (PHC: 1.0)")
    max_grad_norm: float | None = Field(1.0, gt=0, description="global gradient-norm clip; None = off (PHC: 50)")
    normalize_advantage: bool = Field(True, description="standardize advantages over the batch (PHC: yes)")
    normalize_obs: bool = Field(True, description="running mean/std observation normalization, saved with the policy (PHC: yes)")
    obs_clip: float = Field(5.0, gt=0, description="clip of normalized observations")
    normalize_value: bool = Field(
        False,
        description="the critic regresses value targets standardized by their running mean/std (updated once per batch; no PopArt output rescaling) (PHC: yes)",
    )
    actor_hidden: list[LayerWidth] = Field(default_factory=lambda: [512, 256], description="actor MLP hidden sizes (PHC: [1024, 512])")
    critic_hidden: list[LayerWidth] = Field(default_factory=lambda: [512, 256], description="critic MLP hidden sizes (PHC: [1024, 512])")
    activation: Literal["elu", "relu", "tanh", "silu", "gelu"] = Field("elu", description="hidden activation (PHC: relu)")
    log_std_init: LogStd | None = Field(
        None,
        description="initial log σ of the Gaussian head; None: the action space's own exploration σ where its method "
        "prescribes one (PULSE's task_sigma 0.22, Sec. 3.3), else -1.2 (PHC: −2.9, fixed)",
    )
    learn_std: bool = Field(True, description="train log σ (PHC: no, fixed σ)")
    torch_threads: ThreadCount | None = Field(
        1,
        description="torch intra-op threads for this stage (None: keep the process setting, i.e. the spec's "
        "torch_threads or torch's default). 1 is safe whenever anything else shares the cores; on an otherwise idle "
        "2-core machine 2 threads make the update about 1.75x faster, but under contention they were several times "
        "slower than 1 (up to 30x measured on a 2-core machine)",
    )
    init_policy: Path | None = Field(
        None,
        description="start from this policy file's weights and normalizers instead of random ones (relative to the "
        "spec file; same architecture). Used only when the stage has no ppo.pt yet; the budget counts this stage's steps",
    )
    init_policy_repeat_tail: int | None = Field(
        None,
        ge=1,
        description="with init_policy: this network may take more observation dims than the policy, appended as repeats "
        "of the policy's last init_policy_repeat_tail dims (PHC with goal_frames K > 1 from a one-frame policy: the "
        "goal block, 24 x bodies for obs 'rot'); they start with zero weights and the repeated block's normalizer "
        "statistics, so the first policy is the source's. None: the architectures must match",
    )
    init_log_std: LogStd | None = Field(None, description="with init_policy: reset log σ to this value (e.g. a fixed σ); None keeps the policy's σ")
    init_lr: LearningRate | None = Field(
        1e-5,
        description="with init_policy: the learning rate of the first update (the 'adaptive' schedule moves on from it; "
        "'constant' and 'linear' use lr). A trained policy under a fresh Adam at lr 3e-4 had a first-update KL of "
        "5-9 and 92% of its ratios clipped: the committed skill was partly destroyed before the schedule could react. "
        "None starts at lr",
    )
    checkpoint_every: int = Field(10, ge=1, description="iterations between checkpoints (also saved at the end and on Ctrl-C)")
    print_every: int = Field(10, ge=1, description="iterations between progress lines when the console is not a terminal")

    @model_validator(mode="after")
    def _minibatch_fits(self) -> "PPOParams":
        if self.num_envs * self.horizon > MAX_BATCH:
            raise ValueError(
                f"the batch num_envs × horizon = {self.num_envs * self.horizon:,} samples exceeds {MAX_BATCH:,} "
                "(its buffers are allocated whole); lower num_envs or horizon"
            )
        if self.minibatch_size > self.num_envs * self.horizon:
            raise ValueError(f"minibatch_size {self.minibatch_size} exceeds the batch num_envs × horizon = {self.num_envs * self.horizon}")
        if self.init_log_std is not None and self.init_policy is None:
            raise ValueError("init_log_std needs init_policy (log_std_init sets the σ of a fresh network)")
        if self.init_policy_repeat_tail is not None and self.init_policy is None:
            raise ValueError("init_policy_repeat_tail needs init_policy")
        return self

    def start_lr(self, fresh: bool) -> float:
        """The optimizer's first learning rate: ``init_lr`` for a fresh stage that starts from
        ``init_policy`` under the 'adaptive' schedule, else ``lr`` (a resumed stage restores its own)."""
        if fresh and self.init_policy is not None and self.init_lr is not None and self.lr_schedule == "adaptive":
            return self.init_lr
        return self.lr

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.horizon

    @property
    def iterations(self) -> int:
        return math.ceil(self.total_env_steps / self.batch_size)


#: initial log σ when neither the spec nor the action space sets one
DEFAULT_LOG_STD = -1.2


def initial_log_std(spec_value: float | None, action_space: Any) -> float:
    """The spec's ``log_std_init``, else log of the action space's ``exploration_sigma`` (a
    :class:`~mocap.interfaces.Box` that prescribes one), else :data:`DEFAULT_LOG_STD`."""
    if spec_value is not None:
        return float(spec_value)
    sigma = action_space.exploration_sigma if isinstance(action_space, Box) else None
    return math.log(sigma) if sigma is not None else DEFAULT_LOG_STD


def adapt_lr(lr: float, kl: float, desired_kl: float, lr_min: float, lr_max: float) -> float:
    """One step of the KL-adaptive learning rate (rl_games, rsl_rl): /1.5 when ``kl > 2·desired``,
    ×1.5 when ``kl < desired/2``, unchanged in between; the result is clamped to ``[lr_min, lr_max]``.
    A non-finite ``kl`` counts as too large."""
    if not math.isfinite(kl) or kl > 2.0 * desired_kl:
        lr = lr / 1.5
    elif kl < 0.5 * desired_kl:
        lr = lr * 1.5
    return min(max(lr, lr_min), lr_max)


__all__ = ["DEFAULT_LOG_STD", "PPOParams", "adapt_lr", "initial_log_std"]
