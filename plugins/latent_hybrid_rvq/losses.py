"""The loss terms and schedules of the hybrid latent (Alg. 1, Eq. 6; formulas in the module docstring
of :mod:`mocap_hybrid_rvq.model`, which re-exports them): the marginal quantization step, L_mm, the
Gaussian KL of the continuous baseline, the temporal regularizer and the linear weight ramp."""

from __future__ import annotations

from mocap.quantizers import Quantizer
from torch import Tensor


def ramp(start: float, end: float, progress: float, fraction: float = 1.0) -> float:
    """Linear schedule: ``start`` at progress 0, ``end`` from progress ``fraction`` on."""
    t = min(max(float(progress) / fraction, 0.0), 1.0)
    return start + (end - start) * t


def marginal_quantize(
    z: Tensor, z_p: Tensor, quantizer: Quantizer, n_active: int | None = None, *, train: bool | None = None
) -> tuple[Tensor, Tensor, Tensor, dict[str, Tensor]]:
    """Alg. 1 lines 3–5: ``(z̄, ȳ, indices, losses)`` with y = z − sg(z_p), ȳ = Q(y), z̄ = ȳ + sg(z_p).

    ȳ is straight-through (value ŷ_q, ∂ȳ/∂z = I); z̄ carries no gradient to z_p.
    """
    y = z - z_p.detach()
    y_bar, indices, losses = quantizer(y, n_active, train=train)
    return y_bar + z_p.detach(), y_bar, indices, losses


def mm_loss(z_bar: Tensor, z_p: Tensor) -> Tensor:
    """L_mm = mean ‖z̄ − z_p‖² with a **live** z_p (erratum 9.4-3): trains the prior toward z̄."""
    return (z_bar - z_p).square().mean()


def gaussian_kl(mu_q: Tensor, log_std_q: Tensor, mu_p: Tensor, log_std_p: Tensor) -> Tensor:
    """Elementwise KL(N(μ_q, σ_q²) ‖ N(μ_p, σ_p²)) = log σ_p/σ_q + (σ_q² + (μ_q − μ_p)²)/(2σ_p²) − ½."""
    var_q, var_p = (2 * log_std_q).exp(), (2 * log_std_p).exp()
    return log_std_p - log_std_q + (var_q + (mu_q - mu_p).square()) / (2 * var_p) - 0.5


def temporal_reg(x: Tensor, starts: Tensor) -> Tensor:
    """mean ‖x_t − sg(x_{t−1})‖² over (t, n) pairs that do not cross an episode start.

    ``x`` (T, N, D), ``starts`` (T, N) bool (step t is the first of an episode). Pairs with t = 0
    (no predecessor in the chunk) or ``starts[t]`` are skipped; zero (with a graph) if none remain.
    """
    if x.shape[0] < 2:
        return (x * 0).sum()
    diff = (x[1:] - x[:-1].detach()).square().mean(-1)  # (T-1, N)
    valid = (~starts[1:].bool()).to(diff.dtype)
    return (diff * valid).sum() / valid.sum().clamp_min(1.0)
