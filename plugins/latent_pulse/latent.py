"""PULSE: parameters, networks and the latent space (PULSE Sec. 4.2-4.3, Eqs. 1-4).

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

Ablations (Table 3) and App. C.3 variants, all switches of :class:`PulseParams`:

* ``prior``: learned R(z | s^p) or N(0, I) (rows 1, 2); ``task_action``: residual z = μ^p + z^task
  or absolute (rows 1, 2, 5); ``regu``: L_regu on/off (rows 1, 3);
* ``rl_term``: a PPO term on the imitation reward added to distillation (row 4;
  :mod:`mocap_pulse.rl_term`, driven by the distill trainer through :meth:`PulseLatent.rl_hook`);
* ``latent_kind``: ``gaussian``; ``sphere`` (z = x / ‖x‖ of the Gaussian sample x, KL on the
  un-projected Gaussians, prior samples projected: uniform on the sphere with prior 'standard');
  ``vq`` (:mod:`mocap_pulse.vq`: deterministic encoder, partitioned straight-through quantization with
  the hybrid plugin's EMA quantizer, commitment loss; prior 'learned' = a categorical code prior
  R(k | s^p) trained on the encoder's codes, 'standard' = uniform codes; tasks pick one code per
  partition; random generation samples codes from the prior, with temperature ``noise_scale``).

Provenance tags in the parameter descriptions: [P] paper, [CODE] official code (reference only),
[INF] inference, [CPU] a small default for 2-core CPU runs.

Code layout: :class:`PulseParams` and :data:`ARCHITECTURE_KEYS` live in :mod:`mocap_pulse.pulse_params`
(re-exported here).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import torch
from torch import Tensor, nn

from mocap.interfaces import ActionSpace, Box, Imitator, LatentSample, LatentSpace, MultiDiscrete
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
from mocap_pulse.pulse_params import ARCHITECTURE_KEYS, PulseParams
from mocap_pulse.rl_term import RL_KEYS, rl_losses

if TYPE_CHECKING:  # pragma: no cover
    from mocap_pulse.vq import PartitionedVQ

LATENT_FORMAT = "mocap_pulse/1"


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

    samples_prior = True  # random_action samples the prior

    def __init__(self, params: PulseParams, proprio_dim: int, goal_dim: int, action_dim: int):
        super().__init__()
        p = self.params = params
        self.proprio_dim, self.goal_dim, self.action_dim = int(proprio_dim), int(goal_dim), int(action_dim)
        self.latent_dim = Z = int(p.latent_dim)
        bounds = (float(p.logvar_min), float(p.logvar_max))
        if p.activation not in ACTIVATIONS:  # pragma: no cover - pydantic already checks
            raise ValueError(p.activation)
        P, G = self.proprio_dim, self.goal_dim
        self.proprio_norm = RunningNormalizer((P,), clip=p.obs_clip)
        self.goal_norm = RunningNormalizer((G,), clip=p.obs_clip)
        self.vq: PartitionedVQ | None = None
        self.code_prior: nn.Module | None = None
        self.pri: GaussianMLP | None = None
        if p.latent_kind == "vq":
            # deterministic encoder output, quantized; a categorical prior over the codes (or uniform).
            # Imported here: only this variant needs the hybrid_rvq plugin's quantizer.
            from mocap_pulse.vq import PartitionedVQ

            self.enc: nn.Module = mlp([P + G, *p.encoder_hidden, Z], p.activation)
            self.vq = PartitionedVQ(Z, p.vq_partitions, p.vq_codebook_size, shared=p.vq_shared_codebook, decay=p.vq_decay, dead_threshold=p.vq_dead_threshold)
            if p.prior == "learned":
                self.code_prior = mlp([P, *p.prior_hidden, p.vq_partitions * p.vq_codebook_size], p.activation)
        else:
            self.enc = GaussianMLP(P + G, list(p.encoder_hidden), Z, p.activation, bounds)
            self.pri = GaussianMLP(P, list(p.prior_hidden), Z, p.activation, bounds) if p.prior == "learned" else None
        self.dec = mlp([P + Z, *p.decoder_hidden, self.action_dim], p.activation)
        self.critic = mlp([P + G, *p.rl_critic_hidden, 1], p.activation) if p.rl_term else None
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

    def attach_imitator(self, imitator: Imitator) -> "PulseLatent":
        """Use ``imitator.to_pd_targets`` to turn decoder outputs into PD targets (:meth:`decoder`)."""
        self._pd_map = imitator.to_pd_targets
        return self

    def init_from_teacher(self, teacher: Any) -> None:
        """Called by the distill trainer before training: with ``normalizer='teacher'`` copy the teacher
        policy's input statistics (``teacher.policy.obs_norm`` over [s^p | s^g]) and freeze them ([CODE])."""
        if self.params.normalizer != "teacher":
            return
        norm = getattr(teacher.policy, "obs_norm", None)
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
                raise ValueError(f"pulse expects an imitation goal of {self.goal_dim} dims, got {g.shape[-1]} (does goal_obs match the imitator's obs?)")
            g = g.to(self.device, torch.float32)
        if self.params.normalizer != "none":
            p = self.proprio_norm.normalize(p)
            g = None if g is None else self.goal_norm.normalize(g)
        return p, g, lead

    def _posterior(self, p: Tensor, g: Tensor | None) -> tuple[Tensor, Tensor | None]:
        """Encoder mean and log-variance (``None`` for the deterministic vq encoder)."""
        if g is None:
            raise ValueError("the pulse encoder needs the imitation goal (obs.goal)")
        x = torch.cat((p, g), -1)
        if self.vq is not None:
            return self.enc(x), None
        return self.enc(x)

    def _prior(self, p: Tensor) -> tuple[Tensor, Tensor]:
        if self.pri is None:
            z = p.new_zeros(p.shape[0], self.latent_dim)
            return z, z.clone()
        return self.pri(p)

    def _code_logits(self, p: Tensor) -> Tensor:
        """(M, G, K) logits of the learned categorical code prior R(k_g | s^p) (vq, prior 'learned')."""
        assert self.code_prior is not None and self.vq is not None
        return self.code_prior(p).reshape(p.shape[0], self.vq.partitions, self.vq.codebook_size)

    def _project(self, z: Tensor) -> Tensor:
        return project_to_sphere(z) if self.params.latent_kind == "sphere" else z

    def _to_decoder_latent(self, z: Tensor, train: bool = False) -> Tensor:
        """What the decoder receives for an encoder-side latent ``z``: ``z`` ('gaussian'), ``z / ‖z‖``
        ('sphere') or its straight-through quantization ('vq'; ``train`` updates the codebooks)."""
        if self.vq is not None:
            return self.vq(z, train=train).quantized
        return self._project(z)

    def _decode(self, p: Tensor, z: Tensor) -> Tensor:
        return self.dec(torch.cat((p, z), -1))

    def value(self, p: Tensor, g: Tensor | None) -> Tensor:
        """(M,) the RL term's critic V([s^p | s^g]) on normalized inputs (``rl_term`` only)."""
        if self.critic is None or g is None:
            raise RuntimeError("the pulse critic exists only with rl_term: true and needs the imitation goal")
        return self.critic(torch.cat((p, g), -1)).squeeze(-1)

    def rl_hook(self) -> Any:
        """The distill trainer's optional RL hook (:class:`mocap_pulse.rl_term.PulseRLHook`) when
        ``rl_term`` is on, else ``None`` (pure supervised distillation)."""
        if not self.params.rl_term:
            return None
        from mocap_pulse.rl_term import PulseRLHook

        return PulseRLHook(self)

    # -------------------------------------------------------------------------- LatentSpace
    def encoder(self, obs: Observations, sample: bool = False) -> LatentSample:
        """E(z | s^p, s^g): mean μ^e, std σ^e and ``z`` (a reparameterized sample with ``sample``, else μ^e;
        projected to the unit sphere for 'sphere'). 'vq': ``std`` None, ``z`` the codes of μ^e and
        ``indices`` (N, G) their indices."""
        p, g, lead = self._inputs(obs)
        mu, logvar = self._posterior(p, g)
        if self.vq is not None:
            q = self.vq(mu, train=False)
            return LatentSample(mean=mu.reshape(*lead, -1), z=q.quantized.reshape(*lead, -1), indices=q.indices.reshape(*lead, -1))
        assert logvar is not None
        z = self._project(reparameterize(mu, logvar) if sample else mu)
        std = torch.exp(0.5 * logvar)
        return LatentSample(mean=mu.reshape(*lead, -1), std=std.reshape(*lead, -1), z=z.reshape(*lead, -1))

    def prior(self, obs: Observations) -> LatentSample:
        """R(z | s^p) (or N(0, I)): mean μ^p, std σ^p, ``z`` = μ^p (projected for 'sphere').

        'vq': the most likely code of each partition under the learned categorical prior (``mean`` =
        ``z`` = those codes, ``indices`` them, ``std`` None); with prior 'standard' (uniform codes)
        ``mean`` = ``z`` = 0 and no indices."""
        p, _, lead = self._inputs(Observations(proprio=obs.proprio))
        if self.vq is not None:
            if self.code_prior is None:
                z = p.new_zeros(p.shape[0], self.latent_dim)
                return LatentSample(mean=z.reshape(*lead, -1), z=z.reshape(*lead, -1))
            idx = self._code_logits(p).argmax(-1)
            z = self.vq.decode(idx).to(p)
            return LatentSample(mean=z.reshape(*lead, -1), z=z.reshape(*lead, -1), indices=idx.reshape(*lead, -1))
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
    def task_action_space(self) -> ActionSpace:
        """A continuous Z-d residual (Eq. 4), unbounded; explore with σ = :attr:`PulseParams.task_sigma`.
        'vq': one code index per partition (``MultiDiscrete((K,) * G)``, NCP-style; ``task_action`` unused)."""
        if self.vq is not None:
            return MultiDiscrete((self.vq.codebook_size,) * self.vq.partitions)
        return Box((self.latent_dim,), exploration_sigma=self.params.task_sigma)

    def to_latent(self, obs: Observations, task_action: Tensor) -> Tensor:
        """Eq. 4: ``z = μ^p(s^p) + z^task`` ('residual'), or ``z = z^task`` ('absolute'); sphere-projected
        for 'sphere'. Linear in ``z^task`` before the projection. 'vq': the codes of the (N, G) indices."""
        if self.vq is not None:
            idx = task_action.to(self.device).long().reshape(-1, self.vq.partitions)
            return self.vq.decode(idx).to(torch.float32).reshape(*task_action.shape[:-1], self.latent_dim)
        r = task_action.to(self.device, torch.float32)
        if self.params.task_action == "residual":
            r = self.prior(obs).mean.reshape(r.shape) + r
        return self._project(r)

    def sample_prior(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None) -> Tensor:
        """Random generation: ``z = μ^p + noise_scale · σ^p · ε`` (N(0, I) prior: ``noise_scale · ε``),
        projected for 'sphere' (uniform on the sphere with the N(0, I) prior).

        'vq': per partition a code index drawn from the learned categorical prior with temperature
        ``noise_scale`` (softmax(logits / noise_scale); 0 = the most likely code), or uniformly over
        the K codes with prior 'standard' (``noise_scale`` unused). The paper (App. C.3) found random
        VQ samples incoherent, with code-switching jitter.

        The paper: varying the noise biases generation toward smoother (less) or more energetic (more) motion.
        """
        if self.vq is not None:
            p, _, lead = self._inputs(Observations(proprio=obs.proprio))
            dev = p.device if generator is None else generator.device
            M, Gp, K = p.shape[0], self.vq.partitions, self.vq.codebook_size
            if self.code_prior is None:
                idx = torch.randint(0, K, (M, Gp), generator=generator, device=dev)
            else:
                logits = self._code_logits(p)
                if noise_scale <= 0:
                    idx = logits.argmax(-1)
                else:
                    probs = torch.softmax(logits / noise_scale, -1).reshape(M * Gp, K).to(dev)
                    idx = torch.multinomial(probs, 1, generator=generator).reshape(M, Gp)
            return self.vq.decode(idx.to(p.device)).to(p).reshape(*lead, self.latent_dim)
        prior = self.prior(obs)
        assert prior.std is not None
        eps = torch.randn(prior.mean.shape, generator=generator, device=prior.mean.device if generator is None else generator.device)
        return self._project(prior.mean + noise_scale * prior.std * eps.to(prior.mean))

    def random_action(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None) -> Tensor:
        """The raw action of a random rollout from the prior: ``D(s^p, z)`` with ``z`` from :meth:`sample_prior`."""
        return self.decode_action(obs, self.sample_prior(obs, noise_scale, generator))

    # ------------------------------------------------------------------------ distillation
    def student_action(self, obs: Observations, sample: bool = True) -> Tensor:
        """(N, A) ``D(s^p, z)`` with ``z`` sampled from E (``sample``) or ``z = μ^e`` ('vq': the codes of
        μ^e either way; never updates the codebooks)."""
        p, g, lead = self._inputs(obs)
        mu, logvar = self._posterior(p, g)
        z = mu if (logvar is None or not sample) else reparameterize(mu, logvar)
        return self._decode(p, self._to_decoder_latent(z, train=False)).reshape(*lead, -1)

    def distill_losses(self, obs: Observations, teacher_output: Tensor, starts: Tensor, progress: float) -> dict[str, Tensor]:
        """Eq. 3 on a (T, N) chunk: ``L = L_action + α L_regu + β(progress) L_KL`` and the variants' terms.

        * 'vq': no Gaussian KL; ``+ vq_commit_weight · L_commit`` and, with the learned code prior,
          ``+ vq_prior_weight · (−log R(k | s^p))`` (logged as ``kl``: the KL of the one-hot posterior
          to the categorical prior; it trains only the prior). In training mode the codebooks take
          an EMA step.
        * ``rl_term``: ``+ rl_weight · L_clip + rl_value_coef · L_value`` from the rollout tensors
          in ``obs.extra`` (:mod:`mocap_pulse.rl_term`); without them (e.g. a caller without the
          hook) the term is skipped.

        Returns ``loss`` and its terms ``action``, ``regu``, ``kl`` (batch means), ``beta`` and
        diagnostics (``sigma_e``, ``sigma_p``: mean standard deviations; ``mu_e_norm``), plus
        ``commit``, ``perplexity`` ('vq') and ``rl_policy``, ``rl_value``, ``rl_ratio`` (``rl_term``).
        """
        pp = self.params
        T, N = starts.shape
        p, g, _ = self._inputs(obs)
        mu_e, logvar_e = self._posterior(p, g)
        out: dict[str, Tensor] = {}
        extra_loss = p.new_zeros(())
        if self.vq is not None:
            q = self.vq(mu_e, train=self.training)
            a = self._decode(p, q.quantized)
            out["commit"] = q.commit.detach()
            extra_loss = extra_loss + pp.vq_commit_weight * q.commit
            if self.code_prior is not None:
                logits = self._code_logits(p)
                kl = torch.nn.functional.cross_entropy(logits.reshape(-1, self.vq.codebook_size), q.indices.reshape(-1), reduction="none")
                kl = kl.reshape(p.shape[0], -1).sum(-1).mean()
                extra_loss = extra_loss + pp.vq_prior_weight * kl
            else:
                kl = p.new_zeros(())
            counts = torch.bincount(q.indices.reshape(-1), minlength=self.vq.codebook_size).to(p)
            probs = counts / counts.sum().clamp_min(1.0)
            out["perplexity"] = torch.exp(-(probs * torch.log(probs.clamp_min(1e-12))).sum()).detach()
            sigma_e = p.new_zeros(())
            sigma_p = p.new_zeros(())
            beta = 0.0
        else:
            assert logvar_e is not None
            z = self._project(reparameterize(mu_e, logvar_e))
            a = self._decode(p, z)
            if self.pri is None:
                kl = standard_normal_kl(mu_e, logvar_e).mean()
                sigma_p = torch.ones((), device=a.device)
            else:
                mu_p, logvar_p = self._prior(p)
                kl = gaussian_kl(mu_e, logvar_e, mu_p, logvar_p).mean()
                sigma_p = torch.exp(0.5 * logvar_p).mean()
            sigma_e = torch.exp(0.5 * logvar_e).mean()
            beta = beta_schedule(progress, pp.beta_start, pp.beta_end, pp.beta_anneal)
        target = teacher_output.reshape(-1, self.action_dim).to(a)
        l_action = action_loss(a, target, pp.action_loss)
        if pp.regu and pp.alpha > 0:
            regu = temporal_regularizer(mu_e.reshape(T, N, -1), starts.to(a.device), pp.regu_form, pp.regu_phi)
        else:
            regu = a.new_zeros(())
        if pp.rl_term and all(k in obs.extra for k in RL_KEYS):
            rl = rl_losses(self, p, g, mu_e, logvar_e, obs.extra)  # type: ignore[arg-type]
            extra_loss = extra_loss + pp.rl_weight * rl["rl_policy"] + pp.rl_value_coef * rl["rl_value"]
            out.update({k: v.detach() for k, v in rl.items()})
        loss = l_action + (pp.alpha if pp.regu else 0.0) * regu + beta * kl + extra_loss
        return {
            "loss": loss,
            "action": l_action.detach(),
            "regu": regu.detach(),
            "kl": kl.detach(),
            "beta": torch.tensor(beta),
            "sigma_e": sigma_e.detach(),
            "sigma_p": sigma_p.detach(),
            "mu_e_norm": mu_e.norm(dim=-1).mean().detach(),
            **out,
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
        from mocap.checkpoint import CheckpointError, embedded_humanoid
        from mocap.distill_files import load_latent_state

        try:
            saved = load_latent_state(Path(checkpoint))
        except CheckpointError:
            raise
        except ValueError as exc:  # another kind of file: a user error, not a bug
            raise CheckpointError(str(exc)) from None
        config = saved.get("config") or {}
        diff = [k for k in ARCHITECTURE_KEYS if k in config and _jsonable(config[k]) != _jsonable(latent.config[k])]
        if diff:
            detail = ", ".join(f"{k}: checkpoint {config[k]!r} vs spec {latent.config[k]!r}" for k in diff)
            trained = embedded_humanoid(saved)
            where = f"; it was trained for humanoid {trained}, the spec asks for {skeleton.name}" if trained not in (None, skeleton.name) else ""
            raise CheckpointError(f"{checkpoint}: the saved pulse latent does not match the spec ({detail}){where}")
        try:
            latent.load_state_dict(saved["state_dict"])
        except RuntimeError as exc:
            raise CheckpointError(f"{checkpoint}: not the weights of this pulse latent ({exc})") from None
        latent.eval()
    return latent.to(device)


def _jsonable(v: Any) -> Any:
    return list(v) if isinstance(v, tuple) else v


__all__ = ["ARCHITECTURE_KEYS", "GaussianMLP", "PulseLatent", "PulseParams", "make_pulse", "pulse_dims"]
