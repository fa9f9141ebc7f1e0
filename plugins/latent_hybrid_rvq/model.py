"""The hybrid latent space of Bae et al. 2025 ("Marginal Quantization", Alg. 1) and its baselines.

**Shared-teacher protocol (a deliberate departure).** The paper trains its own expert with its own
state (Eq. 7), a quaternion-difference goal (Eq. 9), residual actions ``q + a``, a multiplicative
expert reward with the AMP style term ``-5 log(1 - D)`` (Eq. 11) and a 0.5 m max-body termination,
and distills from it. Here the latent is distilled from the framework's PHC imitator, with that
imitator's observations, actions and reward, exactly as PULSE is: the comparison between the
latent spaces (PULSE vs hybrid vs VMP) then measures the latent space alone, with one teacher. The
paper's expert is not implemented; the README's method table states this too.

Networks (sizes [DEFAULT]; the paper gives none), on running-normalized inputs:

* posterior f_φ(s, s̃) → z ∈ R^D (deterministic; the continuous baseline: μ, log σ);
* prior f_θ(s) → z_p ∈ R^D, conditioned on the proprioception s only (Alg. 1; erratum 9.4-8:
  the Fig. 3 caption's (s, s̃) is not followed);
* decoder π_low(s, z̄) → the teacher's raw action (its mean; the distillation target).

**Forward pass of the hybrid (Alg. 1), with every stop-gradient** (sg = ``.detach()``)::

    z   = f_φ(s, s̃)
    z_p = f_θ(s)
    y   = z − sg(z_p)                       # margin: the quantizer never trains the prior
    ȳ   = RVQ(y)                            # straight-through: value ŷ_q = Σ e_n*, ∂ȳ/∂y = I
    z̄   = ȳ + sg(z_p)                       # ∂z̄/∂z = I, ∂z̄/∂z_p = 0
    a   = π_low(s, z̄)

So the action loss trains f_φ and π_low, never the prior; the commitment loss (on y) trains f_φ
only. **L_mm = ‖z̄ − z_p‖² with a live z_p** (erratum 9.4-3: not ‖z − sg(z_p)‖², which would
never train the prior): its value is ‖ŷ_q‖², ∂/∂z_p = −2ŷ_q (pulls the prior to the quantized
posterior) and ∂/∂z = +2ŷ_q through the straight-through (shrinks the margin). L_mm and the z_p
term of L_reg are the only signals that train the prior.

**Imitation loss (Eq. 6, weights Table 5)**::

    L = 10 L_action + α L_reg + β L_commit + γ(progress) L_mm
    L_action = mean ‖a − a_teacher‖²                               (mean over samples and dims)
    L_reg    = mean ‖ȳ_t − sg(ȳ_{t−1})‖² + mean ‖z_p,t − sg(z_p,t−1)‖²   (hybrid, α = 0.05)
    L_mm     = mean ‖z̄ − z_p‖²                                    (γ: 0.1 → 1.0, linear ramp)

The previous-step values are detached caches [DEFAULT], and L_reg skips pairs that cross an
episode start (and the first step of each chunk, which has no predecessor in the chunk). All terms
are mean-reduced over samples and latent/action dimensions [DEFAULT].

**Baselines** (switch ``variant``; Hybrid-RVQ Sec. 5.2, App. A.1, Table 5):

==================  =====================================================  ============================
variant             latent                                                 losses
==================  =====================================================  ============================
``hybrid``          MQ: z̄ = RVQ(z − sg z_p) + sg z_p, RVQ N × K           action, reg, commit, mm
``hybrid_vq``       MQ with one VQ of ``single_codebook_size`` codes         action, reg, commit, mm
``discrete``        z̄ = VQ(z), one codebook of ``single_codebook_size``    action, reg (‖z̄_t − sg z̄_{t−1}‖²), commit
``discrete_plus``   z̄ = RVQ(z), no prior                                  action, reg (same), commit
``continuous``      q = N(μ_φ(s, s̃), σ_φ), prior N(μ_p(s), σ_p(s))         action, reg (‖μ_t − sg μ_{t−1}‖², α = 0.005),
                                                                           KL(q‖p) (0.05 → 0.5)
==================  =====================================================  ============================

**Task phase (Sec. 4.1).** The prior, the codebooks and π_low are frozen (:meth:`HybridLatent.freeze`);
a task policy picks one code per active codebook, ``task_action_space = MultiDiscrete((K,) * M)``
(M = ``task_codebooks``: [P] 1 for in-betweening and navigation, 2 for HMD tracking), and
``to_latent(obs, k) = z_p(s) + Σ_{n ≤ M} B_n[k_n]`` (discrete⁺: without z_p; single-VQ variants:
one index over ``single_codebook_size`` codes; continuous: a Box residual added to μ_p(s)).
Random generation (Sec. 4.5) samples the codes uniformly (:meth:`HybridLatent.generate`).

**Observation normalization** (switch ``normalizer``). Proprioception and goal have their own
normalizers (:class:`~mocap.rl.normalizer.RunningNormalizer`, saved in the ``state_dict``):
``running`` statistics fed by :meth:`HybridLatent.update_normalizers` (the ``distill`` trainer calls
it once per rollout chunk), or the teacher's statistics copied by
:meth:`HybridLatent.init_from_teacher` (``teacher``), or none. :meth:`HybridLatent.freeze` freezes them.

**Distillation contract** (``mocap.distill``): the trainer calls ``init_from_teacher`` once,
``update_normalizers`` per chunk, ``student_action`` in rollouts (eval mode, full quantizer
depth, codebooks untouched) and ``distill_losses`` in training mode; it saves
``{"config": model.config, "state_dict": ...}``, which :func:`make_hybrid` loads back.

Code layout: :class:`HybridParams` and the variant sets live in :mod:`mocap_hybrid_rvq.hybrid_params`, the loss
terms in :mod:`mocap_hybrid_rvq.losses`; both are re-exported here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from mocap.checkpoint import CheckpointError, embedded_humanoid, load_checkpoint, save_checkpoint
from mocap.interfaces import ActionSpace, Box, LatentSample, LatentSpace, MultiDiscrete
from mocap.observations import imitation_goal_dim, proprioception_dim
from mocap.rl.networks import mlp
from mocap.rl.normalizer import RunningNormalizer
from mocap.skeleton import Skeleton
from mocap.state import Observations
from mocap.quantizers import Quantizer, ResidualVQ, VectorQuantizer
from mocap_hybrid_rvq.hybrid_params import (
    MARGINAL_VARIANTS,
    RESIDUAL_VARIANTS,
    SINGLE_VQ_VARIANTS,
    VARIANTS,
    HybridParams,
    check_compatible,
)
from mocap_hybrid_rvq.losses import gaussian_kl, marginal_quantize, mm_loss, ramp, temporal_reg
from torch import Tensor, nn

CHECKPOINT_FORMAT = "mocap_hybrid_rvq/1"


@dataclass
class PosteriorPass:
    """Intermediate values of one posterior forward pass (see the module doc for the formulas).

    ``z``: posterior output (continuous: the sample, or μ); ``z_p``: prior latent (None without a
    prior); ``y_bar``: straight-through quantized margin (hybrid) or quantized z (discrete);
    ``z_bar``: what the decoder receives; ``mu``/``log_std`` and ``mu_p``/``log_std_p``: the
    continuous baseline's Gaussians.
    """

    z: Tensor
    z_bar: Tensor
    z_p: Tensor | None = None
    y_bar: Tensor | None = None
    indices: Tensor | None = None
    losses: dict[str, Tensor] | None = None
    mu: Tensor | None = None
    log_std: Tensor | None = None
    mu_p: Tensor | None = None
    log_std_p: Tensor | None = None


class HybridLatent(LatentSpace):
    """The hybrid (Marginal Quantization) latent space and its baselines (``params.variant``).

    Implements :class:`~mocap.interfaces.LatentSpace` and the ``distill`` trainer's
    :class:`~mocap.interfaces.DistillableLatent` (``student_action``, ``distill_losses``).

    Args:
        params: :class:`HybridParams`.
        proprio_dim: P, size of ``obs.proprio``.
        goal_dim: G, size of ``obs.goal`` (the imitation goal s̃).
        action_dim: A, size of the teacher's raw policy output the decoder learns.
    """

    samples_prior = True  # random_action samples the prior

    def __init__(self, params: HybridParams, proprio_dim: int, goal_dim: int, action_dim: int):
        super().__init__()
        self.params = params
        self.variant: str = params.variant
        self.proprio_dim, self.goal_dim, self.action_dim = int(proprio_dim), int(goal_dim), int(action_dim)
        self.latent_dim = d = params.latent_dim
        act = params.activation
        self.proprio_norm = RunningNormalizer((self.proprio_dim,), clip=params.obs_clip)
        self.goal_norm = RunningNormalizer((self.goal_dim,), clip=params.obs_clip)
        gaussian = self.variant == "continuous"
        self.posterior = mlp([self.proprio_dim + self.goal_dim, *params.encoder_hidden, 2 * d if gaussian else d], act)
        self.prior_net: nn.Module | None = None
        if self.variant in MARGINAL_VARIANTS or gaussian:
            self.prior_net = mlp([self.proprio_dim, *params.prior_hidden, 2 * d if gaussian else d], act)
        self.decoder_net = mlp([self.proprio_dim + d, *params.decoder_hidden, self.action_dim], act)
        self.quantizer: Quantizer | None = None
        common: dict[str, Any] = {
            "decay": params.ema_decay,
            "eps": params.ema_eps,
            "dead_threshold": params.dead_threshold,
            "dead_threshold_mode": params.dead_threshold_mode,
            "init": params.codebook_init,
            "kmeans_iters": params.kmeans_iters,
        }
        if self.variant in RESIDUAL_VARIANTS:
            self.quantizer = ResidualVQ(
                d,
                params.num_codebooks,
                params.codebook_size,
                dropout=params.dropout,
                dropout_per_sample=params.dropout_per_sample,
                dropout_prob=params.dropout_prob,
                commitment=params.commitment,
                **common,
            )
        elif self.variant in SINGLE_VQ_VARIANTS:
            self.quantizer = VectorQuantizer(d, params.single_codebook_size, **common)

    # ------------------------------------------------------------------------------ config
    @property
    def config(self) -> dict[str, Any]:
        """Everything needed to rebuild the module (saved next to the ``state_dict``)."""
        return {
            "params": self.params.model_dump(mode="json"),
            "proprio_dim": self.proprio_dim,
            "goal_dim": self.goal_dim,
            "action_dim": self.action_dim,
        }

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> HybridLatent:
        return cls(HybridParams.model_validate(config["params"]), int(config["proprio_dim"]), int(config["goal_dim"]), int(config["action_dim"]))

    @property
    def num_task_codebooks(self) -> int:
        """M: active codebooks of the task action space (1 for the single-VQ variants)."""
        return self.params.task_codebooks if self.variant in RESIDUAL_VARIANTS else 1

    # --------------------------------------------------------------------------- normalizers
    @torch.no_grad()
    def update_normalizers(self, obs: Observations) -> None:
        """Fold observations (any leading shape, e.g. a (T, N) chunk) into the running statistics
        (``normalizer='running'`` only; the distill trainer calls this once per rollout chunk)."""
        if self.params.normalizer != "running":
            return
        self.proprio_norm.update(obs.proprio.reshape(-1, self.proprio_dim))
        if obs.goal is not None:
            self.goal_norm.update(obs.goal.reshape(-1, self.goal_dim))

    def init_from_teacher(self, teacher: Any) -> None:
        """Called by the distill trainer before training: with ``normalizer='teacher'``, copy the teacher
        policy's input statistics (``teacher.policy.obs_norm`` over [s^p | s^g]) and freeze them."""
        if self.params.normalizer != "teacher":
            return
        norm = getattr(teacher.policy, "obs_norm", None)
        if not isinstance(norm, RunningNormalizer) or norm.shape != (self.proprio_dim + self.goal_dim,):
            raise ValueError(
                "hybrid_rvq normalizer='teacher' needs a teacher policy with a running normalizer `obs_norm` over "
                f"[s^p | s^g] ({self.proprio_dim + self.goal_dim} dims); use normalizer='running'"
            )
        with torch.no_grad():
            for mine, cols in ((self.proprio_norm, slice(0, self.proprio_dim)), (self.goal_norm, slice(self.proprio_dim, None))):
                mine.mean.copy_(norm.mean[cols])
                mine.var.copy_(norm.var[cols])
                mine.count.copy_(norm.count)
                mine.freeze()

    # ------------------------------------------------------------------------------ pieces
    def _norm(self, obs: Observations) -> tuple[Tensor, Tensor | None]:
        p, g = obs.proprio, obs.goal
        if self.params.normalizer != "none":
            p = self.proprio_norm.normalize(p)
            g = self.goal_norm.normalize(g) if g is not None else None
        return p, g

    def _prior_out(self, p: Tensor) -> tuple[Tensor, Tensor | None]:
        """(z_p, None) or, for the continuous baseline, (μ_p, log σ_p)."""
        assert self.prior_net is not None
        out = self.prior_net(p)
        if self.variant == "continuous":
            mu, log_std = out.chunk(2, dim=-1)
            return mu, log_std.clamp(*self.params.log_std_bounds)
        return out, None

    def _posterior(self, p: Tensor, g: Tensor, *, train: bool, sample: bool, n_active: int | None = None) -> PosteriorPass:
        """Alg. 1 (and the baselines' equivalents) on normalized inputs (B, P), (B, G)."""
        out = self.posterior(torch.cat((p, g), dim=-1))
        if self.variant == "continuous":
            mu, log_std = out.chunk(2, dim=-1)
            log_std = log_std.clamp(*self.params.log_std_bounds)
            z = mu + log_std.exp() * torch.randn_like(mu) if sample else mu
            mu_p, log_std_p = self._prior_out(p)
            return PosteriorPass(z=z, z_bar=z, mu=mu, log_std=log_std, mu_p=mu_p, log_std_p=log_std_p, losses={})
        assert self.quantizer is not None
        if self.variant in MARGINAL_VARIANTS:
            z_p, _ = self._prior_out(p)
            z_bar, y_bar, indices, losses = marginal_quantize(out, z_p, self.quantizer, n_active, train=train)
            return PosteriorPass(z=out, z_bar=z_bar, z_p=z_p, y_bar=y_bar, indices=indices, losses=losses)
        z_bar, indices, losses = self.quantizer(out, n_active, train=train)
        return PosteriorPass(z=out, z_bar=z_bar, y_bar=z_bar, indices=indices, losses=losses)

    def _decode(self, p: Tensor, z: Tensor) -> Tensor:
        return self.decoder_net(torch.cat((p, z.to(p.dtype)), dim=-1))

    # --------------------------------------------------------------------------- LatentSpace
    def encoder(self, obs: Observations) -> LatentSample:
        """Posterior latent: z̄ (deterministic, quantized variants) with its code indices and the
        commitment loss; continuous: N(μ, σ) with a sample in training mode, μ in eval.

        Codebooks are updated (EMA, reset, dropout) only in training mode.
        """
        if obs.goal is None:
            raise ValueError("the posterior needs the imitation goal (obs.goal)")
        p, g = self._norm(obs)
        assert g is not None
        out = self._posterior(p, g, train=self.training, sample=self.training)
        if self.variant == "continuous":
            assert out.log_std is not None
            return LatentSample(mean=out.mu, std=out.log_std.exp(), z=out.z)  # type: ignore[arg-type]
        return LatentSample(mean=out.z_bar, std=None, z=out.z_bar, indices=out.indices, losses=dict(out.losses or {}))

    def decoder(self, obs: Observations, z: Tensor) -> Tensor:
        """(N, A) decoder mean: the teacher's raw action space (map with ``teacher.to_pd_targets``)."""
        p, _ = self._norm(obs)
        return self._decode(p, z)

    def prior(self, obs: Observations) -> LatentSample:
        """hybrid / hybrid_vq: deterministic z_p = f_θ(s) (``std`` None); continuous: N(μ_p, σ_p) (z = μ_p);
        discrete / discrete_plus: no learned prior: mean 0 and a uniformly sampled code latent as ``z``."""
        p, _ = self._norm(obs)
        if self.variant == "continuous":
            mu, log_std = self._prior_out(p)
            assert log_std is not None
            return LatentSample(mean=mu, std=log_std.exp(), z=mu)
        if self.variant in MARGINAL_VARIANTS:
            z_p, _ = self._prior_out(p)
            return LatentSample(mean=z_p, std=None, z=z_p)
        codes = self.sample_task_action(p.shape[0], device=p.device)
        return LatentSample(mean=torch.zeros(p.shape[0], self.latent_dim, dtype=p.dtype, device=p.device), z=self._compose(p, codes), indices=codes)

    @property
    def task_action_space(self) -> ActionSpace:
        if self.variant == "continuous":
            return Box((self.latent_dim,))
        if self.variant in SINGLE_VQ_VARIANTS:
            return MultiDiscrete((self.params.single_codebook_size,))
        return MultiDiscrete((self.params.codebook_size,) * self.params.task_codebooks)

    def _compose(self, p: Tensor, task_action: Tensor) -> Tensor:
        if self.variant == "continuous":
            mu_p, _ = self._prior_out(p)
            return mu_p + task_action.to(mu_p.dtype)
        assert self.quantizer is not None
        indices = task_action.long()
        if indices.dim() == 1:
            indices = indices.unsqueeze(-1)
        codes = self.quantizer.decode(indices).to(p.dtype) if indices.shape[-1] > 0 else p.new_zeros(p.shape[0], self.latent_dim)
        if self.variant in MARGINAL_VARIANTS:
            z_p, _ = self._prior_out(p)
            return z_p + codes
        return codes

    def to_latent(self, obs: Observations, task_action: Tensor) -> Tensor:
        """z for the decoder: hybrid z_p(s) + Σ_{n ≤ M} B_n[k_n] for code indices (N, M) long
        (any M ≤ N; M = 0 gives z_p); discrete⁺ the code sum only; continuous μ_p(s) + u."""
        p, _ = self._norm(obs)
        return self._compose(p, task_action)

    # ----------------------------------------------------------------------- random generation
    def sample_task_action(
        self, num: int, n_active: int | None = None, *, generator: torch.Generator | None = None, device: torch.device | str = "cpu"
    ) -> Tensor:
        """(num, M) uniformly random code indices (M = ``n_active`` or ``task_codebooks``), or, for the
        continuous baseline, (num, D) standard-normal residuals."""
        if self.variant == "continuous":
            return torch.randn(num, self.latent_dim, generator=generator, device=device)
        if self.variant in SINGLE_VQ_VARIANTS:
            size, m = self.params.single_codebook_size, 1 if n_active is None else n_active
        else:
            size, m = self.params.codebook_size, self.num_task_codebooks if n_active is None else n_active
        return torch.randint(0, size, (num, m), generator=generator, device=device)

    def generate(self, obs: Observations, n_active: int | None = None, *, generator: torch.Generator | None = None) -> Tensor:
        """Unconditional generation (Sec. 4.5): z from uniformly random codes of the first
        ``n_active`` levels (hybrid adds z_p); continuous: z ~ N(μ_p, σ_p)."""
        p, _ = self._norm(obs)
        if self.variant == "continuous":
            mu, log_std = self._prior_out(p)
            assert log_std is not None
            eps = torch.randn(mu.shape, generator=generator, device=mu.device, dtype=mu.dtype)
            return mu + log_std.exp() * eps
        codes = self.sample_task_action(p.shape[0], n_active, generator=generator, device=p.device)
        return self._compose(p, codes)

    def random_action(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None, n_active: int | None = None) -> Tensor:
        """(N, A) decoder output of an unconditional-generation step: :meth:`generate`'s latent
        (uniformly random codes of the first ``n_active`` levels, plus z_p for the hybrid; the
        continuous baseline samples N(μ_p, (noise_scale σ_p)²))."""
        p, _ = self._norm(obs)
        if self.variant == "continuous":
            mu, log_std = self._prior_out(p)
            assert log_std is not None
            eps = torch.randn(mu.shape, generator=generator, device=mu.device if generator is None else generator.device, dtype=mu.dtype)
            z = mu + noise_scale * log_std.exp() * eps.to(mu.device)
        else:
            z = self.generate(obs, n_active, generator=generator)
        return self._decode(p, z)

    # -------------------------------------------------------------------- DistillableLatent
    def student_action(self, obs: Observations, sample: bool = True) -> Tensor:
        """(N, A) decoder mean at the posterior latent. Rollouts use the full quantizer depth and
        never touch the codebooks (no EMA, no dropout); ``sample`` only matters for the
        continuous baseline (z sampled from the posterior, or its mean)."""
        if obs.goal is None:
            raise ValueError("the student needs the imitation goal (obs.goal)")
        p, g = self._norm(obs)
        assert g is not None
        out = self._posterior(p, g, train=False, sample=sample)
        return self._decode(p, out.z_bar)

    def distill_losses(self, obs: Observations, teacher_output: Tensor, starts: Tensor, progress: float) -> dict[str, Tensor]:
        """Eq. 6 on a (T, N) chunk in time order (see the module doc). Returns ``loss`` (the total)
        and the unweighted terms ``action``, ``reg``, ``commit``, ``mm`` (hybrid variants) or ``kl``
        (continuous), the current ramp weights, and ``perplexity`` (codebook 1, EMA usage).

        In training mode this runs the codebook EMA/reset and quantizer dropout (the observation
        normalizers are fed separately by :meth:`update_normalizers`).
        """
        if obs.goal is None:
            raise ValueError("distillation needs the imitation goal (obs.goal)")
        T, N = teacher_output.shape[:2]
        flat = Observations(proprio=obs.proprio.reshape(T * N, -1), goal=obs.goal.reshape(T * N, -1))
        p, g = self._norm(flat)
        assert g is not None
        out = self._posterior(p, g, train=self.training, sample=True)
        action = self._decode(p, out.z_bar)
        prm = self.params
        terms: dict[str, Tensor] = {}
        terms["action"] = (action - teacher_output.reshape(T * N, -1).to(action.dtype)).square().mean()
        total = prm.action_weight * terms["action"]
        if self.variant == "continuous":
            assert out.mu is not None and out.log_std is not None and out.mu_p is not None and out.log_std_p is not None
            terms["kl"] = gaussian_kl(out.mu, out.log_std, out.mu_p, out.log_std_p).mean()
            kl_w = ramp(*prm.kl_weight, progress, prm.ramp_fraction)
            terms["reg"] = temporal_reg(out.mu.reshape(T, N, -1), starts)
            total = total + kl_w * terms["kl"] + prm.effective_reg_weight * terms["reg"]
            terms["kl_weight"] = torch.tensor(kl_w)
        else:
            assert out.y_bar is not None and out.losses is not None
            terms["commit"] = out.losses["commit"]
            if self.variant in MARGINAL_VARIANTS:
                assert out.z_p is not None
                terms["reg"] = temporal_reg(out.y_bar.reshape(T, N, -1), starts) + temporal_reg(out.z_p.reshape(T, N, -1), starts)
                terms["mm"] = mm_loss(out.z_bar, out.z_p)
                mm_w = ramp(*prm.mm_weight, progress, prm.ramp_fraction)
                total = total + mm_w * terms["mm"]
                terms["mm_weight"] = torch.tensor(mm_w)
            else:
                terms["reg"] = temporal_reg(out.z_bar.reshape(T, N, -1), starts)
            total = total + prm.effective_reg_weight * terms["reg"] + prm.commit_weight * terms["commit"]
            assert self.quantizer is not None
            terms["perplexity"] = self.quantizer.perplexity()[0].detach()
        terms["loss"] = total
        return terms

    # ---------------------------------------------------------------------------- task phase
    def freeze(self) -> HybridLatent:
        """Task phase: eval mode, no parameter requires grad, normalizers and codebooks frozen."""
        self.eval()
        for prm in self.parameters():
            prm.requires_grad_(False)
        self.proprio_norm.freeze()
        self.goal_norm.freeze()
        return self


# ------------------------------------------------------------------------------- checkpoints
def save_hybrid(path: Path | str, model: HybridLatent, extra: dict[str, Any] | None = None, *, spec_yaml: str | None = None) -> None:
    """Write ``model`` (config + ``state_dict``, normalizers and codebooks included) atomically."""
    state = {k: v.detach().cpu() if isinstance(v, Tensor) else v for k, v in model.state_dict().items()}
    save_checkpoint(Path(path), {"format": CHECKPOINT_FORMAT, "config": model.config, "state_dict": state, "extra": extra or {}}, spec_yaml=spec_yaml)


def _extract_state(data: dict[str, Any], path: Path) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """(state_dict, config or None) from our format or a trainer checkpoint holding a state_dict.

    Accepted layouts: :func:`save_hybrid`'s; a dict with a state dict under ``state_dict``,
    ``model``, ``latent`` or ``student`` (and optionally our config under ``config`` or
    ``latent_config``); or a bare state dict.
    """
    if data.get("format") == CHECKPOINT_FORMAT:
        return data["state_dict"], data.get("config")
    config = None
    for key in ("config", "latent_config"):
        if isinstance(data.get(key), dict) and "params" in data[key]:
            config = data[key]
            break
    for key in ("state_dict", "model", "latent", "student"):
        value = data.get(key)
        if isinstance(value, dict) and value and all(isinstance(v, (Tensor, dict)) or v is None for v in value.values()):
            return value, config
    if data and all(isinstance(k, str) for k in data) and any(isinstance(v, Tensor) for v in data.values()):
        return data, config
    raise CheckpointError(f"{path}: no latent state_dict found (keys: {sorted(data)[:10]})")


def load_hybrid(path: Path | str, map_location: str | torch.device = "cpu", params: HybridParams | None = None) -> HybridLatent:
    """Rebuild a :class:`HybridLatent` from :func:`save_hybrid`'s file (or a trainer checkpoint that
    stores our ``config``). ``params``, when given, overrides the non-architecture fields (e.g.
    ``task_codebooks``) after a compatibility check. Returned in eval mode on ``map_location``."""
    data = load_checkpoint(Path(path), map_location=map_location)
    state, config = _extract_state(data, Path(path))
    if config is None:
        raise CheckpointError(f"{path}: the checkpoint stores no latent config; build with make_hybrid(params, skeleton=..., checkpoint=...)")
    model = HybridLatent.from_config(config)
    if params is not None:
        check_compatible(params, config, (model.proprio_dim, model.goal_dim, model.action_dim), path)
        model.params = params
    model.load_state_dict(state)
    return model.to(map_location).eval()


def latent_dims(params: HybridParams, skeleton: Skeleton) -> tuple[int, int, int]:
    """(P, G, A): proprioception, imitation-goal and action sizes from the skeleton (or overrides)."""
    b = skeleton.num_bodies
    return (
        params.proprio_dim or proprioception_dim(b),
        params.goal_dim or imitation_goal_dim(b, params.goal),
        params.action_dim or skeleton.num_dofs,
    )


def make_hybrid(params: HybridParams, *, skeleton: Skeleton, checkpoint: Path | str | None = None, device: str | torch.device = "cpu") -> HybridLatent:
    """Factory of the ``hybrid_rvq`` latent space (``register_latent_spaces``).

    Without ``checkpoint``: a fresh model (training mode). With one (a file of :func:`save_hybrid`,
    or of the ``distill`` trainer holding our ``state_dict`` and optionally ``config``): the
    weights, normalizers and codebooks are loaded after checking that the checkpoint's
    architecture matches ``params``; returned in eval mode.
    """
    dims = latent_dims(params, skeleton)
    model = HybridLatent(params, *dims)
    if checkpoint is not None:
        data = load_checkpoint(Path(checkpoint), map_location="cpu")
        state, config = _extract_state(data, Path(checkpoint))
        if config is not None:
            try:
                check_compatible(params, config, dims, checkpoint)
            except CheckpointError as exc:
                trained = embedded_humanoid(data)
                if trained in (None, skeleton.name):
                    raise
                raise CheckpointError(f"{exc}; it was trained for humanoid {trained}, the spec asks for {skeleton.name}") from None
        try:
            model.load_state_dict(state)
        except RuntimeError as exc:
            raise CheckpointError(f"{checkpoint}: not the weights of this hybrid latent ({exc})") from None
        model.eval()
    return model.to(device)


__all__ = [
    "CHECKPOINT_FORMAT",
    "VARIANTS",
    "HybridLatent",
    "HybridParams",
    "PosteriorPass",
    "gaussian_kl",
    "latent_dims",
    "load_hybrid",
    "make_hybrid",
    "marginal_quantize",
    "mm_loss",
    "ramp",
    "save_hybrid",
    "temporal_reg",
]
