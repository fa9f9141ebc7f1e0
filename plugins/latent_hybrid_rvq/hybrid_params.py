"""The parameters of the ``hybrid_rvq`` latent space: :class:`HybridParams`, the variant sets that
switch its parts on (:data:`MARGINAL_VARIANTS`, ...) and the checkpoint compatibility check on the
architecture fields; :mod:`mocap_hybrid_rvq.model` re-exports them."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from mocap.bounds import ACTIVATION_NAMES, LayerWidth
from mocap.errors import CheckpointError
from pydantic import BaseModel, ConfigDict, Field, model_validator

Variant = Literal["hybrid", "continuous", "discrete", "discrete_plus", "hybrid_vq"]
VARIANTS: tuple[str, ...] = ("hybrid", "continuous", "discrete", "discrete_plus", "hybrid_vq")
#: variants whose latent adds the (stop-gradient) prior z_p to the quantized margin
MARGINAL_VARIANTS = frozenset({"hybrid", "hybrid_vq"})
#: variants with a residual (multi-level) quantizer
RESIDUAL_VARIANTS = frozenset({"hybrid", "discrete_plus"})
#: variants with a single codebook of ``single_codebook_size`` codes
SINGLE_VQ_VARIANTS = frozenset({"discrete", "hybrid_vq"})

#: fields that fix the shapes of the weights; a checkpoint must agree with the spec on them
ARCHITECTURE_FIELDS: tuple[str, ...] = (
    "variant",
    "latent_dim",
    "num_codebooks",
    "codebook_size",
    "single_codebook_size",
    "encoder_hidden",
    "prior_hidden",
    "decoder_hidden",
    "activation",
)


class HybridParams(BaseModel):
    """Parameters of the ``hybrid_rvq`` latent space ([P] paper value, [DEFAULT] ours)."""

    model_config = ConfigDict(extra="forbid")

    variant: Variant = Field(
        "hybrid",
        description="'hybrid' = MQ + RVQ ([P] ours); baselines: 'continuous' (PULSE-like Gaussian posterior/prior + KL), "
        "'discrete' (one VQ on z, NCP), 'discrete_plus' (RVQ on z, no prior), 'hybrid_vq' (MQ + one VQ, App. A.1)",
    )
    # ------------------------------------------------------------------------------ latent
    latent_dim: int = Field(32, ge=1, description="latent / code dimension D ([DEFAULT] 32 as PULSE; not in the paper)")
    num_codebooks: int = Field(8, ge=1, description="RVQ depth N ([P] 8)")
    codebook_size: int = Field(1024, ge=1, description="codes per RVQ codebook K ([P] 1024)")
    single_codebook_size: int = Field(8192, ge=1, description="codes of the single VQ of 'discrete' / 'hybrid_vq' ([P] 8192)")
    task_codebooks: int = Field(1, ge=1, description="active codebooks M of the task action space ([P] 1: in-betweening, navigation; 2: HMD tracking)")
    # --------------------------------------------------------------------------- quantizer
    ema_decay: float = Field(0.99, gt=0.0, le=1.0, description="EMA decay of the codebooks ([DEFAULT] 0.99; [P] EMA is used)")
    ema_eps: float = Field(1e-5, gt=0.0, description="Laplace smoothing of the EMA cluster sizes ([DEFAULT])")
    dead_threshold: float = Field(2.0, ge=0.0, description="codes with EMA cluster size below this are reset from the batch ([DEFAULT] 2.0; 0 disables)")
    dead_threshold_mode: Literal["absolute", "relative"] = Field(
        "absolute",
        description="'absolute': dead_threshold is an EMA count per batch (vector-quantize-pytorch's threshold_ema_dead_code; "
        "[P] names no threshold); 'relative': a fraction of the mean use per code, batch rows / codebook size (the same "
        "meaning at every batch size). bench/results/quantizer_b512.json (B = 512, the spec's minibatch, 8 x 1024): "
        "absolute 2 gives relative MSE 0.240 (vector-quantize-pytorch 0.244); relative 0.1 and 1.0 give 0.38 and 0.35, "
        "so absolute stays the default",
    )
    codebook_init: Literal["kmeans", "random"] = Field(
        "kmeans", description="codebook initialization from the first training batch ([DEFAULT] k-means, as SoundStream)"
    )
    kmeans_iters: int = Field(10, ge=0, description="Lloyd iterations of the k-means initialization")
    dropout: bool = Field(True, description="quantizer dropout during training ([P] used; RVQ variants only)")
    dropout_per_sample: bool = Field(True, description="draw the depth M per sample ([DEFAULT], SoundStream) or once per batch")
    dropout_prob: float = Field(1.0, ge=0.0, le=1.0, description="share of samples/batches with a random depth ([DEFAULT] 1.0)")
    commitment: Literal["per_level", "total"] = Field(
        "per_level", description="commitment loss: sum over levels of ‖r_n‖² ([DEFAULT]) or ‖y − sg(ŷ_q)‖² on the total"
    )
    # ---------------------------------------------------------------------------- networks
    encoder_hidden: list[LayerWidth] = Field(default_factory=lambda: [512, 256], description="posterior MLP hidden sizes ([DEFAULT])")
    prior_hidden: list[LayerWidth] = Field(default_factory=lambda: [512, 256], description="prior MLP hidden sizes ([DEFAULT])")
    decoder_hidden: list[LayerWidth] = Field(default_factory=lambda: [512, 256], description="decoder MLP hidden sizes ([DEFAULT])")
    activation: str = Field("silu", description="MLP activation ([DEFAULT] SiLU as PULSE): " + ", ".join(sorted(ACTIVATION_NAMES)))
    log_std_bounds: tuple[float, float] = Field((-5.0, 2.0), description="'continuous': clamp of the predicted log σ")
    # ------------------------------------------------------------------------ observations
    goal: Literal["rot", "keypoint"] = Field("rot", description="imitation goal layout of the teacher (sets the goal size)")
    proprio_dim: int | None = Field(None, ge=1, description="override the proprioception size (default: from the skeleton)")
    goal_dim: int | None = Field(None, ge=1, description="override the imitation-goal size (default: from the skeleton and `goal`)")
    action_dim: int | None = Field(None, ge=1, description="override the action size (default: the skeleton's DoF count)")
    normalizer: Literal["running", "teacher", "none"] = Field(
        "running",
        description="input normalization: 'running' = own running mean/std, fed by the distill trainer's "
        "update_normalizers; 'teacher' = copy the teacher policy's statistics over [s^p | s^g] and freeze them "
        "(init_from_teacher); 'none'",
    )
    obs_clip: float | None = Field(5.0, gt=0.0, description="clip of the normalized observations (None: none)")
    # ------------------------------------------------------------------------------ losses
    action_weight: float = Field(10.0, ge=0.0, description="weight of L_action ([P] Table 5: 10)")
    reg_weight: float | None = Field(None, ge=0.0, description="weight α of L_reg; None: [P] 0.05 (discrete, hybrid) or 0.005 (continuous)")
    commit_weight: float = Field(1.0, ge=0.0, description="weight β of L_commit ([P] 1.0)")
    mm_weight: tuple[float, float] = Field((0.1, 1.0), description="γ of L_mm, ramped start → end ([P] 0.1 → 1.0)")
    kl_weight: tuple[float, float] = Field((0.05, 0.5), description="'continuous': KL weight start → end ([P] 0.05 → 0.5)")
    ramp_fraction: float = Field(1.0, gt=0.0, le=1.0, description="training progress at which the linear ramps reach their end ([DEFAULT]; not in paper)")

    @model_validator(mode="after")
    def _check(self) -> HybridParams:
        if self.activation not in ACTIVATION_NAMES:
            raise ValueError(f"activation {self.activation!r} unknown; choose one of {sorted(ACTIVATION_NAMES)}")
        if self.variant in RESIDUAL_VARIANTS and self.task_codebooks > self.num_codebooks:
            raise ValueError(f"task_codebooks ({self.task_codebooks}) exceeds num_codebooks ({self.num_codebooks})")
        if self.variant in SINGLE_VQ_VARIANTS and self.task_codebooks != 1:
            raise ValueError(f"variant {self.variant!r} has one codebook; task_codebooks must be 1")
        if self.log_std_bounds[0] >= self.log_std_bounds[1]:
            raise ValueError("log_std_bounds must be (low, high) with low < high")
        return self

    @property
    def effective_reg_weight(self) -> float:
        if self.reg_weight is not None:
            return self.reg_weight
        return 0.005 if self.variant == "continuous" else 0.05


def check_compatible(params: HybridParams, config: dict[str, Any], dims: tuple[int, int, int], path: Path | str = "") -> None:
    """Raise ``ValueError`` naming every architecture field / size where the checkpoint differs."""
    stored = HybridParams.model_validate(config["params"])
    problems = [
        f"{name}: spec {getattr(params, name)!r}, checkpoint {getattr(stored, name)!r}"
        for name in ARCHITECTURE_FIELDS
        if getattr(params, name) != getattr(stored, name)
    ]
    for name, value in zip(("proprio_dim", "goal_dim", "action_dim"), dims):
        if int(config[name]) != value:
            problems.append(f"{name}: spec {value}, checkpoint {config[name]}")
    if problems:
        raise CheckpointError(f"{path}: checkpoint does not match the latent spec: " + "; ".join(problems))
