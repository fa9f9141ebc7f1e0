"""PULSE: parameters, networks and the latent space (digest pulse §4).

Three diagonal-Gaussian / deterministic MLPs (Eq. 1):

* encoder ``E(z | s^p, s^g) = N(μ^e, σ^e)`` on proprioception + imitation goal;
* prior ``R(z | s^p) = N(μ^p, σ^p)`` on proprioception only (or the fixed N(0, I) of the ablation);
* decoder ``D(a | s^p, z)``: the action mean, in the **teacher's raw policy-output space**
  (:meth:`mocap.interfaces.Imitator.policy_output`, e.g. PHC's normalized absolute targets).

Log-variances are clamped to ``[logvar_min, logvar_max]`` ([CODE] [−5, 2]). Inputs are normalized
by running mean/std normalizers saved with the weights (or the teacher's frozen statistics, as the
official code does). During distillation ``z`` is sampled from E; for evaluation ``z = μ^e``.

Downstream (Eq. 4): a task policy outputs a residual ``z^task`` and ``z = μ^p + z^task``; its
fixed exploration σ is :attr:`PulseParams.task_sigma` (0.22). PD targets come from the teacher's
mapping, which the latent does not own: :meth:`PulseLatent.decoder` needs an imitator attached
with :meth:`PulseLatent.attach_imitator` (:class:`mocap.latent_imitator.LatentImitator` does it).

Provenance tags in the parameter descriptions: [P] paper, [CODE] official code (reference only),
[INF] inference, [CPU] a small default for 2-core CPU runs.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Literal

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import Tensor, nn

from mocap.interfaces import Box, Imitator, LatentSample, LatentSpace
from mocap.observations import imitation_goal_dim, proprioception_dim
from mocap.rl.networks import ACTIVATIONS, mlp
from mocap.rl.normalizer import RunningNormalizer
from mocap.skeleton import Skeleton
from mocap.state import Observations
from mocap_pulse.losses import (
    action_loss,
    beta_schedule,
    gaussian_kl,
    project_to_sphere,
    reparameterize,
    standard_normal_kl,
    temporal_regularizer,
)

LATENT_FORMAT = "mocap_pulse/1"

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
)


class PulseParams(BaseModel):
    """PULSE hyper-parameters and switches ([P] paper, [CODE] official code, [INF], [CPU])."""

    model_config = ConfigDict(extra="forbid")

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
        description="L_regu: 'paper' = ‖μ_t − μ_{t−1}‖² ([P] Eq. 3) or 'code' = ‖μ_t − φ μ_{t−1}‖ un-squared AR(1) ([CODE]); "
        "both masked at episode starts",
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
    prior: Literal["learned", "standard"] = Field(
        "learned", description="'learned' R(z|s^p) ([P]) or 'standard' N(0, I) (Table 3 rows 1, 2)"
    )
    task_action: Literal["residual", "absolute"] = Field(
        "residual", description="task action: 'residual' z = μ^p + z^task ([P] Eq. 4) or 'absolute' z = z^task (Table 3 rows 1, 2, 5)"
    )
    rl_term: bool = Field(
        False,
        description="add a PPO term to distillation (Table 3 row 4). NOT BUILT: the distill trainer is purely supervised; "
        "true is rejected. The paper found it hurts (71.0% vs 93.4% VR success)",
    )
    latent_kind: Literal["gaussian", "sphere", "vq"] = Field(
        "gaussian",
        description="'gaussian' ([P]); 'sphere' (App. C.3: z projected to the unit sphere after sampling, KL on the un-projected "
        "Gaussians [INF from the code's project_to_norm]); 'vq' (App. C.3: 64-d, 8 partitions, 64 codes): NOT BUILT, rejected "
        "(see the hybrid_rvq latent for a quantized space)",
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
        if self.rl_term:
            raise ValueError(
                "rl_term: an RL (PPO) term added to distillation (PULSE Table 3 row 4) is not built in this project; "
                "the distill trainer is purely supervised. Set rl_term: false"
            )
        if self.latent_kind == "vq":
            raise ValueError(
                "latent_kind: 'vq' (PULSE App. C.3 vector-quantized variant) is not built in the pulse plugin; "
                "use 'gaussian' or 'sphere', or the hybrid_rvq latent space for a quantized latent"
            )
        a, b = self.beta_anneal
        if not (0.0 <= a < b <= 1.0):
            raise ValueError(f"beta_anneal must satisfy 0 <= start < end <= 1 (progress fractions), got {self.beta_anneal}")
        if self.logvar_min >= self.logvar_max:
            raise ValueError(f"logvar_min ({self.logvar_min}) must be below logvar_max ({self.logvar_max})")
        return self


# ------------------------------------------------------------------------------------ networks
class GaussianMLP(nn.Module):
    """MLP trunk (activated) -> two linear heads: mean and clamped log-variance (N, Z)."""

    def __init__(self, in_dim: int, hidden: list[int], out_dim: int, activation: str, logvar_bounds: tuple[float, float]):
        super().__init__()
        self.trunk = mlp([in_dim, *hidden], activation, activate_last=True)
        self.mu = nn.Linear(hidden[-1], out_dim)
        self.logvar = nn.Linear(hidden[-1], out_dim)
        self.logvar_bounds = logvar_bounds

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        h = self.trunk(x)
        lo, hi = self.logvar_bounds
        return self.mu(h), self.logvar(h).clamp(lo, hi)


def _flatten_obs(obs: Observations) -> tuple[Tensor, Tensor | None, tuple[int, ...]]:
    """(M, P) proprio, (M, G) goal and the leading batch shape of possibly (T, N, ...) observations."""
    lead = tuple(obs.proprio.shape[:-1])
    p = obs.proprio.reshape(-1, obs.proprio.shape[-1])
    g = None if obs.goal is None else obs.goal.reshape(-1, obs.goal.shape[-1])
    return p, g, lead


class PulseLatent(LatentSpace):
    """The PULSE latent space (module docstring); implements :class:`mocap.interfaces.DistillableLatent`.

    Args:
        params: :class:`PulseParams`.
        proprio_dim, goal_dim, action_dim: input and output sizes (see :func:`make_pulse`).
    """

    def __init__(self, params: PulseParams, proprio_dim: int, goal_dim: int, action_dim: int):
        super().__init__()
        p = self.params = params
        self.proprio_dim, self.goal_dim, self.action_dim = int(proprio_dim), int(goal_dim), int(action_dim)
        self.latent_dim = Z = int(p.latent_dim)
        bounds = (float(p.logvar_min), float(p.logvar_max))
        if p.activation not in ACTIVATIONS:  # pragma: no cover - pydantic already checks
            raise ValueError(p.activation)
        self.proprio_norm = RunningNormalizer((self.proprio_dim,), clip=p.obs_clip)
        self.goal_norm = RunningNormalizer((self.goal_dim,), clip=p.obs_clip)
        self.enc = GaussianMLP(self.proprio_dim + self.goal_dim, list(p.encoder_hidden), Z, p.activation, bounds)
        self.pri = GaussianMLP(self.proprio_dim, list(p.prior_hidden), Z, p.activation, bounds) if p.prior == "learned" else None
        self.dec = mlp([self.proprio_dim + Z, *p.decoder_hidden, self.action_dim], p.activation)
        self._pd_map: Callable[[Observations, Tensor], Tensor] | None = None

    # ------------------------------------------------------------------------- bookkeeping
    @property
    def config(self) -> dict[str, Any]:
        """Everything needed to rebuild the module (saved in checkpoints)."""
        return {
            "format": LATENT_FORMAT,
            "proprio_dim": self.proprio_dim,
            "goal_dim": self.goal_dim,
            "action_dim": self.action_dim,
            **self.params.model_dump(mode="json"),
        }

    @property
    def device(self) -> torch.device:
        return self.proprio_norm.mean.device

    @property
    def task_log_std(self) -> float:
        """log of the fixed task exploration σ (:attr:`PulseParams.task_sigma`), for the task policy's Gaussian."""
        return math.log(self.params.task_sigma)

    def attach_imitator(self, imitator: Imitator) -> "PulseLatent":
        """Use ``imitator.to_pd_targets`` to turn decoder outputs into PD targets (:meth:`decoder`)."""
        self._pd_map = imitator.to_pd_targets
        return self

    def init_from_teacher(self, teacher: Any) -> None:
        """Called by the distill trainer before training: with ``normalizer='teacher'`` copy the teacher
        policy's input statistics (``teacher.policy.obs_norm`` over [s^p | s^g]) and freeze them ([CODE])."""
        if self.params.normalizer != "teacher":
            return
        norm = getattr(getattr(teacher, "policy", None), "obs_norm", None)
        if not isinstance(norm, RunningNormalizer) or norm.shape != (self.proprio_dim + self.goal_dim,):
            raise ValueError(
                "pulse normalizer='teacher' needs a teacher whose policy has a running normalizer `obs_norm` over "
                f"[s^p | s^g] ({self.proprio_dim + self.goal_dim} dims), e.g. a phc imitator trained by ppo; use normalizer='running'"
            )
        P = self.proprio_dim
        with torch.no_grad():
            for mine, sl in ((self.proprio_norm, slice(0, P)), (self.goal_norm, slice(P, None))):
                mine.mean.copy_(norm.mean[sl])
                mine.var.copy_(norm.var[sl])
                mine.count.copy_(norm.count)
                mine.freeze()

    @torch.no_grad()
    def update_normalizers(self, obs: Observations) -> None:
        """Fold a batch of observations (any leading shape) into the running statistics ('running' only)."""
        if self.params.normalizer != "running":
            return
        p, g, _ = _flatten_obs(obs)
        self.proprio_norm.update(p)
        if g is not None:
            self.goal_norm.update(g)

    # ---------------------------------------------------------------------------- networks
    def _inputs(self, obs: Observations) -> tuple[Tensor, Tensor | None, tuple[int, ...]]:
        p, g, lead = _flatten_obs(obs)
        if p.shape[-1] != self.proprio_dim:
            raise ValueError(f"pulse expects proprioception of {self.proprio_dim} dims, got {p.shape[-1]}")
        p = p.to(self.device, torch.float32)
        if g is not None:
            if g.shape[-1] != self.goal_dim:
                raise ValueError(
                    f"pulse expects an imitation goal of {self.goal_dim} dims, got {g.shape[-1]} (does goal_obs match the imitator's obs?)"
                )
            g = g.to(self.device, torch.float32)
        if self.params.normalizer != "none":
            p = self.proprio_norm.normalize(p)
            g = None if g is None else self.goal_norm.normalize(g)
        return p, g, lead

    def _posterior(self, p: Tensor, g: Tensor | None) -> tuple[Tensor, Tensor]:
        if g is None:
            raise ValueError("the pulse encoder needs the imitation goal (obs.goal)")
        return self.enc(torch.cat((p, g), -1))

    def _prior(self, p: Tensor) -> tuple[Tensor, Tensor]:
        if self.pri is None:
            z = p.new_zeros(p.shape[0], self.latent_dim)
            return z, z.clone()
        return self.pri(p)

    def _project(self, z: Tensor) -> Tensor:
        return project_to_sphere(z) if self.params.latent_kind == "sphere" else z

    def _decode(self, p: Tensor, z: Tensor) -> Tensor:
        return self.dec(torch.cat((p, z), -1))

    # -------------------------------------------------------------------------- LatentSpace
    def encoder(self, obs: Observations, sample: bool = False) -> LatentSample:
        """E(z | s^p, s^g): mean μ^e, std σ^e and ``z`` (a reparameterized sample with ``sample``, else μ^e;
        projected to the unit sphere for ``latent_kind='sphere'``)."""
        p, g, lead = self._inputs(obs)
        mu, logvar = self._posterior(p, g)
        z = self._project(reparameterize(mu, logvar) if sample else mu)
        std = torch.exp(0.5 * logvar)
        return LatentSample(mean=mu.reshape(*lead, -1), std=std.reshape(*lead, -1), z=z.reshape(*lead, -1))

    def prior(self, obs: Observations) -> LatentSample:
        """R(z | s^p) (or N(0, I)): mean μ^p, std σ^p, ``z`` = μ^p (projected for 'sphere')."""
        p, _, lead = self._inputs(Observations(proprio=obs.proprio))
        mu, logvar = self._prior(p)
        return LatentSample(mean=mu.reshape(*lead, -1), std=torch.exp(0.5 * logvar).reshape(*lead, -1), z=self._project(mu).reshape(*lead, -1))

    def decode_action(self, obs: Observations, z: Tensor) -> Tensor:
        """D(a | s^p, z): the decoder's mean action in the teacher's raw policy-output space."""
        p, _, lead = self._inputs(Observations(proprio=obs.proprio))
        return self._decode(p, z.reshape(-1, self.latent_dim).to(p)).reshape(*lead, -1)

    def decoder(self, obs: Observations, z: Tensor) -> Tensor:
        """PD targets: :meth:`decode_action` mapped by the attached imitator's ``to_pd_targets``."""
        if self._pd_map is None:
            raise RuntimeError(
                "PulseLatent.decoder returns PD targets through the teacher's mapping: call attach_imitator(imitator) first "
                "(LatentImitator does), or use decode_action for the raw decoder output"
            )
        return self._pd_map(obs, self.decode_action(obs, z))

    @property
    def task_action_space(self) -> Box:
        """A continuous Z-d residual (Eq. 4), unbounded; explore with σ = :attr:`PulseParams.task_sigma`."""
        return Box((self.latent_dim,))

    def to_latent(self, obs: Observations, task_action: Tensor) -> Tensor:
        """Eq. 4: ``z = μ^p(s^p) + z^task`` ('residual'), or ``z = z^task`` ('absolute'); sphere-projected
        for 'sphere'. Linear in ``z^task`` before the projection."""
        r = task_action.to(self.device, torch.float32)
        if self.params.task_action == "residual":
            r = self.prior(obs).mean.reshape(r.shape) + r
        return self._project(r)

    def sample_prior(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None) -> Tensor:
        """Random generation: ``z = μ^p + noise_scale · σ^p · ε`` (N(0, I) prior: ``noise_scale · ε``).

        The paper: varying the noise biases generation toward smoother (less) or more energetic (more) motion.
        """
        prior = self.prior(obs)
        assert prior.std is not None
        eps = torch.randn(prior.mean.shape, generator=generator, device=prior.mean.device if generator is None else generator.device)
        return self._project(prior.mean + noise_scale * prior.std * eps.to(prior.mean))

    def random_action(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None) -> Tensor:
        """The raw action of a random rollout from the prior: ``D(s^p, z)`` with ``z`` from :meth:`sample_prior`."""
        return self.decode_action(obs, self.sample_prior(obs, noise_scale, generator))

    # ------------------------------------------------------------------------ distillation
    def student_action(self, obs: Observations, sample: bool = True) -> Tensor:
        """(N, A) ``D(s^p, z)`` with ``z`` sampled from E (``sample``) or ``z = μ^e``."""
        p, g, lead = self._inputs(obs)
        mu, logvar = self._posterior(p, g)
        z = self._project(reparameterize(mu, logvar) if sample else mu)
        return self._decode(p, z).reshape(*lead, -1)

    def distill_losses(self, obs: Observations, teacher_output: Tensor, starts: Tensor, progress: float) -> dict[str, Tensor]:
        """Eq. 3 on a (T, N) chunk: ``L = L_action + α L_regu + β(progress) L_KL``.

        Returns ``loss`` and its terms ``action``, ``regu``, ``kl`` (batch means), ``beta`` and
        diagnostics (``sigma_e``, ``sigma_p``: mean standard deviations; ``mu_e_norm``).
        """
        pp = self.params
        T, N = starts.shape
        p, g, _ = self._inputs(obs)
        mu_e, logvar_e = self._posterior(p, g)
        z = self._project(reparameterize(mu_e, logvar_e))
        a = self._decode(p, z)
        target = teacher_output.reshape(-1, self.action_dim).to(a)
        l_action = action_loss(a, target, pp.action_loss)
        if self.pri is None:
            kl = standard_normal_kl(mu_e, logvar_e).mean()
            sigma_p = torch.ones((), device=a.device)
        else:
            mu_p, logvar_p = self._prior(p)
            kl = gaussian_kl(mu_e, logvar_e, mu_p, logvar_p).mean()
            sigma_p = torch.exp(0.5 * logvar_p).mean()
        if pp.regu and pp.alpha > 0:
            regu = temporal_regularizer(mu_e.reshape(T, N, -1), starts.to(a.device), pp.regu_form, pp.regu_phi)
        else:
            regu = a.new_zeros(())
        beta = beta_schedule(progress, pp.beta_start, pp.beta_end, pp.beta_anneal)
        loss = l_action + (pp.alpha if pp.regu else 0.0) * regu + beta * kl
        return {
            "loss": loss,
            "action": l_action.detach(),
            "regu": regu.detach(),
            "kl": kl.detach(),
            "beta": torch.tensor(beta),
            "sigma_e": torch.exp(0.5 * logvar_e).mean().detach(),
            "sigma_p": sigma_p.detach(),
            "mu_e_norm": mu_e.norm(dim=-1).mean().detach(),
        }


# ------------------------------------------------------------------------------------ factory
def pulse_dims(params: PulseParams, skeleton: Skeleton) -> tuple[int, int, int]:
    """(proprio, goal, action) sizes: the params' values, else derived from the skeleton (PHC layout)."""
    B = skeleton.num_bodies
    return (
        params.proprio_dim or proprioception_dim(B),
        params.goal_dim or imitation_goal_dim(B, params.goal_obs),
        params.action_dim or skeleton.num_dofs,
    )


def make_pulse(
    params: PulseParams | None = None,
    *,
    skeleton: Skeleton,
    checkpoint: str | Path | None = None,
    device: torch.device | str = "cpu",
) -> PulseLatent:
    """Registry factory: an untrained PULSE (to distill), or with ``checkpoint`` (the distill trainer's
    ``latent.pt``, or its resumable ``distill.pt``) the trained one, in eval mode."""
    params = params or PulseParams()
    latent = PulseLatent(params, *pulse_dims(params, skeleton))
    if checkpoint is not None:
        from mocap.distill import load_latent_state

        saved = load_latent_state(Path(checkpoint))
        config = saved.get("config") or {}
        diff = [k for k in ARCHITECTURE_KEYS if k in config and _jsonable(config[k]) != _jsonable(latent.config[k])]
        if diff:
            detail = ", ".join(f"{k}: checkpoint {config[k]!r} vs spec {latent.config[k]!r}" for k in diff)
            raise ValueError(f"{checkpoint}: the saved pulse latent does not match the spec ({detail})")
        try:
            latent.load_state_dict(saved["state_dict"])
        except RuntimeError as exc:
            raise ValueError(f"{checkpoint}: not the weights of this pulse latent ({exc})") from None
        latent.eval()
    return latent.to(device)


def _jsonable(v: Any) -> Any:
    return list(v) if isinstance(v, tuple) else v


__all__ = ["ARCHITECTURE_KEYS", "GaussianMLP", "PulseLatent", "PulseParams", "make_pulse", "pulse_dims"]
