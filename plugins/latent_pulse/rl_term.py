"""The "RL term added to distillation" ablation (PULSE Table 3 row 4, "No RL" = ✗).

What the paper says (Sec. 4.2): "While we can optimize π_PULSE with the RL objective by treating the
decoder D as a Gaussian distribution with fixed diagonal covariance matrix (similar to kickstarting
(Schmitt et al., 2018)), we find that sampling the latent code together with random exploration
sampling for RL introduces too much instability [...] optimizing with RL and supervised objectives
combined creates a noisy latent space that is worse than without." Table 3 row 4: 71.0% vs 93.4% VR
success. The paper gives no formula, reward, weight or PPO setting for the combined objective, and
the official code has no such mode ([CODE]: the distillation is purely supervised), so everything
below is [INF], with switches where a choice matters:

* **Loss** (kickstarting: RL + supervised): ``L = L_PULSE + w_rl L_clip + c_v L_value``, where
  ``L_clip = −mean(min(ρ Â, clip(ρ, 1 ± ε) Â))`` is PPO's clipped surrogate (to minimize) with
  ``ρ = π(a | s) / π_old(a | s)``, and ``L_value = ½ mean (V(s) − R)²`` trains a critic
  ``V([s^p | s^g])`` owned by the latent (used only here). Advantages are GAE(γ, λ) of the imitation
  reward (PHC's Eq. 2 terms from ``mocap.imitation_rewards``, ``rl_reward_form``), normalized per minibatch
  when ``rl_normalize_advantages``.
* **Policy** (``rl_policy``), i.e. which stochastic variable the policy gradient acts on:
    - ``"decoder"`` (the paper's wording): the action is ``a ~ N(D(s^p, z), σ_a² I)`` with a fixed
      ``σ_a = rl_action_sigma`` and ``z = μ^e + σ^e ε`` sampled from the encoder; the rollout draws
      *both* (the "latent code together with random exploration sampling" the paper blames for the
      instability). ``log π`` is ``log N(a; D(s^p, z(ε)), σ_a²)`` with the rollout's ε held fixed,
      so the gradient reaches decoder and encoder (reparameterization). The exact marginal over z
      is intractable; this is the usual latent-conditioned surrogate.
    - ``"encoder"``: no action noise (the student acts with the decoder mean, as in plain PULSE
      rollouts); the policy is the encoder Gaussian and ``log π = log N(z; μ^e, σ^e²)`` of the
      rollout's (pre-projection) z. Not defined for the deterministic VQ encoder.
* **Time limits**: GAE bootstraps a truncated episode from V(s_t) of its last step (the post-step
  observation is gone after the auto-reset), a terminated one from 0; the rollout's last step from
  V of the next observation.
* The distill trainer drives this through :meth:`mocap_pulse.latent.PulseLatent.rl_hook`
  (:class:`PulseRLHook`): ``act`` per step, ``reward`` after each step, ``finish`` per chunk; the
  per-sample tensors travel in ``obs.extra`` (keys ``rl_*``) to :meth:`PulseLatent.distill_losses`.
  Rollouts must be the student's (``act_with: student``): PPO is on-policy. The hook always
  samples z from the encoder (the trainer's ``sample_latent`` does not apply). With
  ``normalizer: running`` the input statistics move once per chunk before the update, so ρ starts
  slightly off 1; with the teacher's frozen statistics ρ = 1 exactly at the first minibatch.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from mocap.rl.ppo import clipped_surrogate, compute_gae, value_loss
from mocap.state import HumanoidState, Observations

if TYPE_CHECKING:  # pragma: no cover
    from mocap_pulse.latent import PulseLatent

#: keys of the per-sample tensors the hook adds to a chunk's ``obs.extra``
RL_KEYS = ("rl_eps", "rl_z", "rl_action", "rl_logp", "rl_value", "rl_adv", "rl_ret")


def gaussian_log_prob(x: Tensor, mu: Tensor, logvar: Tensor) -> Tensor:
    """``log N(x; μ, diag(e^ℓ))`` summed over the last dim: ``−½ Σ [ℓ + (x − μ)² e^{−ℓ} + log 2π]``."""
    return -0.5 * (logvar + (x - mu).square() * torch.exp(-logvar) + math.log(2.0 * math.pi)).sum(-1)


def policy_gradient_loss(logp_new: Tensor, logp_old: Tensor, advantages: Tensor, clip: float) -> Tensor:
    """PPO's clipped surrogate as a loss to minimize: ``−mean min(ρ Â, clip(ρ, 1 − ε, 1 + ε) Â)``,
    ``ρ = exp(log π − log π_old)``. Raising ``log π`` of a positive-advantage sample (inside the clip
    range) lowers it; so does lowering ``log π`` of a negative-advantage one."""
    ratio = torch.exp(logp_new - logp_old)
    return -clipped_surrogate(ratio, advantages, clip).mean()


def normalize_advantages(adv: Tensor, eps: float = 1e-8) -> Tensor:
    """``(Â − mean) / (std + eps)`` (unchanged when there is a single sample)."""
    if adv.numel() < 2:
        return adv
    return (adv - adv.mean()) / (adv.std() + eps)


class PulseRLHook:
    """The rollout side of the RL term for the distill trainer (module doc). One per chunk is fine;
    it keeps no state between calls."""

    def __init__(self, latent: PulseLatent):
        from mocap.imitation_rewards import ImitationReward  # the phc imitator's reward (PHC Eq. 2)

        self.latent = latent
        self.reward_fn = ImitationReward(form=latent.params.rl_reward_form)

    @torch.no_grad()
    def act(self, obs: Observations) -> tuple[Tensor, dict[str, Tensor]]:
        """The acting output (N, A) and per-env tensors to keep: ``rl_eps`` (the encoder noise),
        ``rl_z`` (the pre-projection latent sample), ``rl_action`` (what was applied), ``rl_logp``
        (its log-probability) and ``rl_value``."""
        lat = self.latent
        p, g, _ = lat._inputs(obs)
        mu, logvar = lat._posterior(p, g)
        eps = torch.randn_like(mu)
        z_pre = mu if logvar is None else mu + torch.exp(0.5 * logvar) * eps
        mean = lat._decode(p, lat._to_decoder_latent(z_pre, train=False))
        if lat.params.rl_policy == "decoder":
            log_sigma = math.log(lat.params.rl_action_sigma)
            action = mean + lat.params.rl_action_sigma * torch.randn_like(mean)
            logp = gaussian_log_prob(action, mean, torch.full_like(mean, 2.0 * log_sigma))
        else:
            assert logvar is not None
            action = mean
            logp = gaussian_log_prob(z_pre, mu, logvar)
        value = lat.value(p, g)
        return action, {
            "rl_eps": eps,
            "rl_z": z_pre,
            "rl_action": action,
            "rl_logp": logp,
            "rl_value": value,
        }

    @torch.no_grad()
    def reward(self, state: HumanoidState, ref: HumanoidState) -> Tensor:
        """(N,) the imitation reward of the state a step reached against the reference it aimed at."""
        return self.reward_fn(state, ref)[0].float()

    @torch.no_grad()
    def finish(
        self,
        extras: dict[str, Tensor],
        rewards: Tensor,
        terminated: Tensor,
        truncated: Tensor,
        last_obs: Observations,
    ) -> dict[str, Tensor]:
        """(T, N, ...) tensors for ``obs.extra``: the stacked ``act`` outputs plus GAE advantages
        ``rl_adv`` and value targets ``rl_ret`` (module doc: bootstrapping)."""
        lat = self.latent
        pp = lat.params
        values = extras["rl_value"]
        p, g, _ = lat._inputs(last_obs)
        last = lat.value(p, g).to(values)
        next_values = torch.cat((values[1:], last[None]), 0)
        term, trunc = (
            terminated.to(values.device).bool(),
            truncated.to(values.device).bool(),
        )
        next_values = torch.where(trunc & ~term, values, next_values)
        adv, ret = compute_gae(
            rewards.to(values),
            values,
            next_values,
            term,
            term | trunc,
            pp.rl_gamma,
            pp.rl_lambda,
        )
        return {**extras, "rl_adv": adv, "rl_ret": ret}


def rl_losses(
    latent: PulseLatent,
    p: Tensor,
    g: Tensor,
    mu: Tensor,
    logvar: Tensor | None,
    extra: dict[str, Any],
) -> dict[str, Tensor]:
    """``policy`` (clipped surrogate) and ``value`` losses of a flattened minibatch (rows of ``p``)."""
    pp = latent.params
    flat = {k: extra[k].reshape(p.shape[0], *extra[k].shape[2:]).to(p) for k in RL_KEYS}
    if pp.rl_policy == "decoder":
        eps = flat["rl_eps"]
        z_pre = mu if logvar is None else mu + torch.exp(0.5 * logvar) * eps
        mean = latent._decode(p, latent._to_decoder_latent(z_pre, train=False))
        logp = gaussian_log_prob(
            flat["rl_action"],
            mean,
            torch.full_like(mean, 2.0 * math.log(pp.rl_action_sigma)),
        )
    else:
        assert logvar is not None
        logp = gaussian_log_prob(flat["rl_z"], mu, logvar)
    adv = flat["rl_adv"]
    if pp.rl_normalize_advantages:
        adv = normalize_advantages(adv)
    pg = policy_gradient_loss(logp, flat["rl_logp"], adv, pp.rl_clip)
    v = latent.value(p, g)
    vl = value_loss(v, flat["rl_value"], flat["rl_ret"])
    return {
        "rl_policy": pg,
        "rl_value": vl,
        "rl_ratio": torch.exp(logp - flat["rl_logp"]).mean().detach(),
    }


__all__ = [
    "RL_KEYS",
    "PulseRLHook",
    "gaussian_log_prob",
    "normalize_advantages",
    "policy_gradient_loss",
    "rl_losses",
]
