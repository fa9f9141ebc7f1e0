"""The parameters of the PULSE latent space (:mod:`mocap_pulse.latent`, which re-exports them):
:class:`PulseParams`, every paper/code switch and ablation with its provenance tag, and
:data:`ARCHITECTURE_KEYS`, the configuration keys a checkpoint must agree on."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["ARCHITECTURE_KEYS", "PulseParams"]

#: configuration keys that change the networks' shapes or forward pass: a checkpoint must agree on them
ARCHITECTURE_KEYS = (
    "proprio_dim",
    "goal_dim",
    "action_dim",
    "latent_dim",
    "encoder_hidden",
    "prior_hidden",
    "decoder_hidden",
    "activation",
    "logvar_min",
    "logvar_max",
    "normalizer",
    "obs_clip",
    "prior",
    "latent_kind",
    "vq_partitions",
    "vq_codebook_size",
    "vq_shared_codebook",
    "rl_term",
    "rl_critic_hidden",
)


class PulseParams(BaseModel):
    """PULSE hyper-parameters and switches ([P] paper, [CODE] official code, [INF], [CPU])."""

    model_config = ConfigDict(extra="forbid")

    name: str | None = Field(
        None,
        description="optional label of this configuration (e.g. a Table 3 row); a comparison spec's matrix names its cells "
        "by it (specs/latent/pulse_ablations.yaml). No effect on the model",
    )
    # ------------------------------------------------------------------------------ sizes
    latent_dim: int = Field(32, ge=1, description="latent size Z ([P] 32, about half of SMPL's 69 DoF)")
    goal_obs: Literal["rot", "keypoint"] = Field(
        "rot", description="the teacher's imitation-goal layout (must match the imitator's `obs`); sets goal_dim when it is None"
    )
    proprio_dim: int | None = Field(None, ge=1, description="s^p size; None: 15 B - 2 from the skeleton (358 on smpl)")
    goal_dim: int | None = Field(None, ge=1, description="s^g size; None: from the skeleton and goal_obs (576 on smpl with 'rot')")
    action_dim: int | None = Field(None, ge=1, description="teacher policy-output size; None: the skeleton's DoF count (69 on smpl)")
    encoder_hidden: list[int] = Field(
        default_factory=lambda: [512, 256, 256],
        min_length=1,
        description="encoder MLP hidden sizes ([P] 'three-layer'; [CODE] [1536, 1024, 512] then a 160-unit layer before the heads; [CPU] default)",
    )
    prior_hidden: list[int] = Field(
        default_factory=lambda: [512, 256, 256],
        min_length=1,
        description="prior MLP hidden sizes ([P] 'three-layer'; [CODE] [1536, 1024, 512]; [CPU] default)",
    )
    decoder_hidden: list[int] = Field(
        default_factory=lambda: [512, 512, 256],
        min_length=1,
        description="decoder MLP hidden sizes ([P] 'three-layer'; [CODE] [3096, 2048, 1024]; [CPU] default)",
    )
    activation: Literal["elu", "relu", "tanh", "silu", "gelu"] = Field("silu", description="hidden activation ([CODE] SiLU)")
    logvar_min: float = Field(-5.0, description="lower clamp of log σ² ([CODE] -5)")
    logvar_max: float = Field(2.0, description="upper clamp of log σ² ([CODE] 2)")
    # ------------------------------------------------------------------------ normalization
    normalizer: Literal["running", "teacher", "none"] = Field(
        "running",
        description="input normalization: 'running' = own running mean/std, updated by the distill trainer and saved; "
        "'teacher' = the teacher policy's statistics, copied at the start and frozen ([CODE]); 'none'",
    )
    obs_clip: float = Field(5.0, gt=0, description="clip of normalized inputs ([CODE] 5)")
    # ------------------------------------------------------------------------------ objective
    action_loss: Literal["paper", "code"] = Field(
        "paper", description="L_action: 'paper' = squared L2 ‖a^T − a‖² ([P] Eq. 3) or 'code' = un-squared L2 norm ([CODE])"
    )
    regu: bool = Field(True, description="use L_regu ([P]; Table 3 rows 1 and 3 turn it off)")
    alpha: float = Field(0.005, ge=0, description="weight α of L_regu ([P] Table 4: 0.005)")
    regu_form: Literal["paper", "code"] = Field(
        "paper",
        description="L_regu: 'paper' = ‖μ_t − μ_{t−1}‖² ([P] Eq. 3) or 'code' = ‖μ_t − φ μ_{t−1}‖ un-squared AR(1) ([CODE]); both masked at episode starts",
    )
    regu_phi: float = Field(0.99, description="φ of the 'code' AR(1) form ([CODE] 0.99)")
    beta_start: float = Field(0.01, ge=0, description="KL weight β before the anneal ([P] 0.01)")
    beta_end: float = Field(0.001, ge=0, description="KL weight β after the anneal ([P] 0.001)")
    beta_anneal: tuple[float, float] = Field(
        (0.25, 0.5),
        description="anneal window in training-progress fraction (env steps / budget), linear in between. [P] App. C.1: "
        "2.5e9 -> 5e9 samples (inconsistent with its ~1e9 total); [CODE]: epochs 2500 -> 5000 of ~10,170, i.e. ~0.246 -> 0.492 [INF]",
    )
    # ------------------------------------------------------------------------------ ablations
    prior: Literal["learned", "standard"] = Field("learned", description="'learned' R(z|s^p) ([P]) or 'standard' N(0, I) (Table 3 rows 1, 2)")
    task_action: Literal["residual", "absolute"] = Field(
        "residual", description="task action: 'residual' z = μ^p + z^task ([P] Eq. 4) or 'absolute' z = z^task (Table 3 rows 1, 2, 5)"
    )
    rl_term: bool = Field(
        False,
        description="Table 3 row 4: add a PPO term on the imitation reward to distillation, L + rl_weight L_clip + "
        "rl_value_coef L_value (mocap_pulse.rl_term; [P] it hurts: 71.0% vs 93.4% VR success; formula [INF]). Needs "
        "act_with: student in the distill trainer",
    )
    rl_weight: float = Field(1.0, ge=0, description="rl_term: weight of the policy-gradient term against the distillation loss [INF]")
    rl_policy: Literal["decoder", "encoder"] = Field(
        "decoder",
        description="rl_term: 'decoder' = the decoder as a fixed-σ Gaussian over actions, rollouts sample z and action noise "
        "([P] wording, kickstarting); 'encoder' = the encoder Gaussian over z is the policy, no action noise",
    )
    rl_action_sigma: float = Field(
        0.05, gt=0, description="rl_term 'decoder': fixed action σ in the teacher's policy-output space ([P] PHC+ σ 0.05; [CODE] e^-2.9)"
    )
    rl_gamma: float = Field(0.99, ge=0, le=1, description="rl_term: discount γ ([P] PHC+ 0.99)")
    rl_lambda: float = Field(0.95, ge=0, le=1, description="rl_term: GAE λ ([CODE] 0.95)")
    rl_clip: float = Field(0.2, gt=0, description="rl_term: PPO clip ε ([P] PHC+ 0.2)")
    rl_value_coef: float = Field(
        1.0, ge=0, description="rl_term: weight of the critic's ½(V − R)² loss (only the critic's weights get its gradient; [CODE] PPO critic_coef 5)"
    )
    rl_normalize_advantages: bool = Field(True, description="rl_term: normalize advantages per minibatch ([CODE] rl_games normalizes)")
    rl_reward_form: Literal["paper", "code"] = Field(
        "paper", description="rl_term: the phc imitation reward's error form (mocap.imitation_rewards: 'paper' norms, 'code' mean squares)"
    )
    rl_critic_hidden: list[int] = Field(default_factory=lambda: [256, 256], min_length=1, description="rl_term: critic MLP hidden sizes on [s^p | s^g] ([CPU])")
    latent_kind: Literal["gaussian", "sphere", "vq"] = Field(
        "gaussian",
        description="'gaussian' ([P]); 'sphere' (App. C.3, like ASE: z = x / ‖x‖ of the Gaussian sample x; the KL stays on the "
        "un-projected Gaussians [INF], the prior's samples are projected too: a projected Gaussian on the sphere, uniform for "
        "prior 'standard'); 'vq' (App. C.3: deterministic encoder output split into vq_partitions parts, each replaced by its "
        "nearest code, straight-through, commitment loss; [P] 64-d, 8 partitions, 64 codes; set latent_dim: 64)",
    )
    vq_partitions: int = Field(8, ge=1, description="vq: partitions G of z, each quantized on its own ([P] 8; latent_dim must be a multiple)")
    vq_codebook_size: int = Field(64, ge=2, description="vq: codes K per dictionary ([P] 64)")
    vq_shared_codebook: bool = Field(True, description="vq: one dictionary shared by all partitions (Liu et al. 2021, [INF] for PULSE) or one per partition")
    vq_commit_weight: float = Field(0.25, ge=0, description="vq: weight of the commitment loss (VQ-VAE's β = 0.25; [P] not given)")
    vq_decay: float = Field(0.99, gt=0, le=1, description="vq: EMA decay of the codebooks (VQ-VAE-EMA; 1 freezes them)")
    vq_dead_threshold: float = Field(2.0, ge=0, description="vq: codes whose EMA usage falls below this are reset from the batch (0: off)")
    vq_prior_weight: float = Field(
        1.0,
        ge=0,
        description="vq with prior 'learned': weight of the categorical prior's loss −log R(k | s^p) (= KL of the one-hot "
        "posterior to the prior); the gradient reaches only the prior",
    )
    # ----------------------------------------------------------------------------- downstream
    task_sigma: float = Field(
        0.22,
        gt=0,
        description="fixed exploration σ of a task policy's residual ([P] 0.22, a standard deviation: [CODE] VR log σ = -1.5; "
        "[CODE] generative tasks use log σ = -1, σ ≈ 0.368)",
    )

    @model_validator(mode="after")
    def _check(self) -> "PulseParams":
        if self.latent_kind == "vq" and self.latent_dim % self.vq_partitions:
            raise ValueError(f"latent_kind 'vq': latent_dim ({self.latent_dim}) must be a multiple of vq_partitions ({self.vq_partitions})")
        if self.rl_term and self.rl_policy == "encoder" and self.latent_kind == "vq":
            raise ValueError("rl_policy 'encoder' needs a stochastic encoder; the vq encoder is deterministic: use rl_policy 'decoder'")
        a, b = self.beta_anneal
        if not (0.0 <= a < b <= 1.0):
            raise ValueError(f"beta_anneal must satisfy 0 <= start < end <= 1 (progress fractions), got {self.beta_anneal}")
        if self.logvar_min >= self.logvar_max:
            raise ValueError(f"logvar_min ({self.logvar_min}) must be below logvar_max ({self.logvar_max})")
        return self
