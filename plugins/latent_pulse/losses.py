"""The math of PULSE's objective (Eq. 3) as small pure tensor functions.

``L = L_action + α L_regu + β L_KL`` with, per sample (PULSE Sec. 4.2):

* ``L_action``: the distance between the student's decoder action and the teacher's;
* ``L_regu``: a temporal smoothness term on consecutive encoder means, never across an episode start;
* ``L_KL``: KL from the encoder's diagonal Gaussian to the prior's (learned R(z|s^p) or N(0, I));
* β annealed linearly from ``beta_start`` to ``beta_end`` over a window of training progress.

Gaussians are given by mean ``mu`` and log-variance ``logvar`` = log σ².
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

RegularizerForm = Literal["paper", "code"]
ActionLossForm = Literal["paper", "code"]


def reparameterize(mu: Tensor, logvar: Tensor, eps: Tensor | None = None) -> Tensor:
    """``z = μ + exp(ℓ / 2) ε`` with ``ε ~ N(0, I)`` (drawn when ``eps`` is None): a sample of
    ``N(μ, exp(ℓ))`` that is differentiable in ``μ`` and ``ℓ`` (Kingma & Welling 2014)."""
    if eps is None:
        eps = torch.randn_like(mu)
    return mu + torch.exp(0.5 * logvar) * eps


def gaussian_kl(mu_q: Tensor, logvar_q: Tensor, mu_p: Tensor, logvar_p: Tensor) -> Tensor:
    """KL(N(μ_q, e^{ℓ_q}) ‖ N(μ_p, e^{ℓ_p})) of diagonal Gaussians, summed over the last dim::

        ½ Σ_i [ ℓ_p − ℓ_q + e^{ℓ_q − ℓ_p} + (μ_q − μ_p)² / e^{ℓ_p} − 1 ]

    (the closed form the paper's Eq. 2 implies, Sec. 4.2; the paper does not print it). Shape: the inputs' batch shape.
    Gradients flow into both distributions (no stop-gradient, as in the official code).
    """
    return 0.5 * (logvar_p - logvar_q + torch.exp(logvar_q - logvar_p) + (mu_q - mu_p).square() * torch.exp(-logvar_p) - 1.0).sum(-1)


def standard_normal_kl(mu: Tensor, logvar: Tensor) -> Tensor:
    """KL(N(μ, e^ℓ) ‖ N(0, I)) = −½ Σ_i (1 + ℓ − μ² − e^ℓ) (the prior-free ablation, Table 3 R1/R2)."""
    return -0.5 * (1.0 + logvar - mu.square() - torch.exp(logvar)).sum(-1)


def action_loss(student: Tensor, teacher: Tensor, form: ActionLossForm = "paper") -> Tensor:
    """Batch mean of the per-sample action distance (last dim = action).

    * ``"paper"``: ``‖a^teacher − a‖²₂`` (Eq. 3, squared norm, summed over action dims);
    * ``"code"``: ``‖a^teacher − a‖₂`` (official code: the un-squared norm, "RMSE").
    """
    sq = (student - teacher).square().sum(-1)
    per_sample = sq if form == "paper" else torch.sqrt(sq + 1e-12)
    return per_sample.mean()


def temporal_regularizer(mu: Tensor, starts: Tensor, form: RegularizerForm = "paper", phi: float = 0.99) -> Tensor:
    """L_regu over a (T, N, Z) sequence of encoder means in time order; ``starts`` (T, N) marks
    the first step of an episode. Pairs (t − 1, t) with ``t ≥ 1`` and ``not starts[t]`` count::

        "paper":  ‖μ_t − μ_{t−1}‖²₂         (Eq. 3)
        "code":   ‖μ_t − φ μ_{t−1}‖₂        (official code: AR(1) with φ = 0.99, un-squared)

    Returns the mean over the valid pairs (0 when there is none), so a pair straddling an episode
    start never contributes and whole episodes may be reordered without changing the value. (The
    official code also skips the first two steps after a reset; not replicated: only the pair that
    crosses the start is dropped. The first step of a chunk has no predecessor in the chunk.)
    """
    if mu.shape[0] < 2:
        return mu.sum() * 0.0
    prev, cur = mu[:-1], mu[1:]
    diff = cur - (prev if form == "paper" else phi * prev)
    sq = diff.square().sum(-1)
    per_pair = sq if form == "paper" else torch.sqrt(sq + 1e-12)
    valid = (~starts[1:].bool()).to(per_pair.dtype)
    return (per_pair * valid).sum() / valid.sum().clamp_min(1.0)


def beta_schedule(progress: float, start: float = 0.01, end: float = 0.001, window: tuple[float, float] = (0.25, 0.5)) -> float:
    """The KL weight at training ``progress`` (fraction of the budget in [0, 1]).

    ``start`` until ``window[0]``, ``end`` from ``window[1]`` on, linear in between (continuous,
    and monotone between the two values). The paper anneals 0.01 → 0.001 "from 2.5×10⁹ to 5×10⁹
    samples" (App. C.1, inconsistent with its ~10⁹ total); the official code anneals over epochs
    2500 → 5000 of about 10,170, i.e. progress ≈ 0.246 → 0.492, hence the default window.
    """
    a, b = window
    if progress <= a:
        return float(start)
    if progress >= b:
        return float(end)
    f = (progress - a) / (b - a)
    return float(start + (end - start) * f)


def project_to_sphere(z: Tensor, eps: float = 1e-8) -> Tensor:
    """``z / ‖z‖`` over the last dim (the App. C.3 spherical-latent variant, like ASE/CALM).

    A vector of norm below ``eps`` has no direction (e.g. the N(0, I) prior's mean, or a zero
    residual on it); it maps to the first basis vector ``e_1``, so every output is on the sphere.
    """
    norm = z.norm(dim=-1, keepdim=True)
    e1 = torch.zeros_like(z)
    e1[..., 0] = 1.0
    return torch.where(norm > eps, z / norm.clamp_min(eps), e1)


__all__ = [
    "action_loss",
    "beta_schedule",
    "gaussian_kl",
    "project_to_sphere",
    "reparameterize",
    "standard_normal_kl",
    "temporal_regularizer",
]
