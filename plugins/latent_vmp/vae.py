"""VMP's motion beta-VAE (paper Sec. 3.1, Sec. 4.1 "VAE", Table 1): 1-D convolutions over time, loss, schedules.

Architecture. The paper gives: 1-D conv layers, 4 conv-ResNet blocks without biases (Jukebox
style), LayerNorm, ReLU, a final linear layer to ``2 d_z`` (mean and, our choice, log-variance),
``d_z = 64``, a decoder that mirrors the encoder with transposed convolutions, about 0.8 M
parameters. Widths, kernels, strides, dilations and where LayerNorm sits are not given; ours
(our choice, an [X] reference design sized to Table 1's 0.8 M parameters)::

    encoder: Conv1d(F->C, k3, no bias) -> ReLU -> D x [Conv1d(C->C, k4, s2, p1, no bias) -> ReLU]
             -> B x ResBlock(C, dilation 3^i) -> flatten -> Linear(C*T' -> 2 d_z)
    decoder: Linear(d_z -> C*T') -> B x ResBlock -> D x [ConvTranspose1d(C->C, k4, s2, p1, no bias)
             -> ReLU] -> crop / edge-pad to 2W+1 -> Conv1d(C->F, k3, no bias)
    ResBlock(x) = x + Conv1x1(ReLU(LN(Conv3_dil(ReLU(LN(x))))))      (no conv biases)

With C = 96, B = 4, D = 2, W = 30, F = 97 this has about 0.78 M parameters (the paper's size);
the CPU default (C = 48) is about a quarter of that.

Loss (Eqs. 3-4): the mean over the window's frames of the per-frame squared error summed over the
groups ``h, theta, v, q, qd, p`` (all standardized, all weights 1), the orientation compared as
rotation matrices obtained by Gram-Schmidt (:func:`mocap.rotations.sixd_to_matrix`), averaged over
the batch; plus ``beta_eff * KL(N(mu, sigma^2) || N(0, I))`` (summed over latent dims, averaged
over the batch) with cyclical annealing of ``beta_eff``.
"""

from __future__ import annotations

import math
from typing import cast

import torch
from torch import Tensor, nn

from mocap.rotations import sixd_to_matrix
from mocap_vmp.features import GROUPS, FeatureLayout


# ------------------------------------------------------------------------------------ network
class _ChannelNorm(nn.Module):
    """LayerNorm over the channels of a (B, C, T) tensor."""

    def __init__(self, channels: int):
        super().__init__()
        self.norm = nn.LayerNorm(channels)

    def forward(self, x: Tensor) -> Tensor:
        return self.norm(x.transpose(1, 2)).transpose(1, 2)


class ResBlock(nn.Module):
    """Jukebox-style residual block without conv biases: ``x + C1(ReLU(LN(C3(ReLU(LN(x))))))``."""

    def __init__(self, channels: int, dilation: int = 1):
        super().__init__()
        self.net = nn.Sequential(
            _ChannelNorm(channels),
            nn.ReLU(),
            nn.Conv1d(channels, channels, 3, padding=dilation, dilation=dilation, bias=False),
            _ChannelNorm(channels),
            nn.ReLU(),
            nn.Conv1d(channels, channels, 1, bias=False),
        )

    def forward(self, x: Tensor) -> Tensor:
        return x + self.net(x)


class MotionVAE(nn.Module):
    """Window VAE: (N, T, F) standardized window -> (mu, logvar) (N, d_z) -> (N, T, F) reconstruction."""

    def __init__(
        self,
        feature_dim: int,
        window: int,
        latent_dim: int = 64,
        channels: int = 48,
        res_blocks: int = 4,
        downsample: int = 2,
        dilation_growth: int = 3,
    ):
        super().__init__()
        self.feature_dim, self.window, self.latent_dim = feature_dim, window, latent_dim
        C = channels
        length = window
        enc: list[nn.Module] = [nn.Conv1d(feature_dim, C, 3, padding=1, bias=False), nn.ReLU()]
        for _ in range(downsample):
            enc += [nn.Conv1d(C, C, 4, stride=2, padding=1, bias=False), nn.ReLU()]
            length = (length + 2 - 4) // 2 + 1
        if length < 1:
            raise ValueError(f"a window of {window} frames is too short for {downsample} stride-2 downsamplings")
        enc += [ResBlock(C, dilation_growth**i) for i in range(res_blocks)]
        self.enc_conv = nn.Sequential(*enc)
        self.reduced = length
        self.enc_head = nn.Linear(C * length, 2 * latent_dim)
        self.dec_in = nn.Linear(latent_dim, C * length)
        dec: list[nn.Module] = [ResBlock(C, dilation_growth**i) for i in reversed(range(res_blocks))]
        for _ in range(downsample):
            dec += [nn.ConvTranspose1d(C, C, 4, stride=2, padding=1, bias=False), nn.ReLU()]
        self.dec_conv = nn.Sequential(*dec)
        self.dec_out = nn.Conv1d(C, feature_dim, 3, padding=1, bias=False)
        self.channels = C

    def encode(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """(mu, logvar), each (N, d_z), of standardized windows ``x`` (N, T, F)."""
        h = self.enc_conv(x.transpose(1, 2))
        mu, logvar = self.enc_head(h.flatten(1)).chunk(2, dim=-1)
        return mu, logvar

    def decode(self, z: Tensor) -> Tensor:
        """(N, T, F) reconstructed standardized window (orientation channels: raw 6-D, not orthonormalized)."""
        h = self.dec_conv(self.dec_in(z).view(z.shape[0], self.channels, self.reduced))
        T = self.window
        if h.shape[-1] >= T:
            h = h[..., :T]
        else:
            h = torch.cat((h, h[..., -1:].expand(*h.shape[:-1], T - h.shape[-1])), -1)
        return self.dec_out(h).transpose(1, 2)

    def forward(self, x: Tensor, sample: bool = True) -> tuple[Tensor, Tensor, Tensor]:
        """(reconstruction, mu, logvar); ``z = mu + sigma * eps`` when ``sample`` else ``mu``."""
        mu, logvar = self.encode(x)
        z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar) if sample else mu
        return self.decode(z), mu, logvar


def num_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


# --------------------------------------------------------------------------------------- loss
def per_frame_errors(x: Tensor, y: Tensor, layout: FeatureLayout) -> dict[str, Tensor]:
    """Per-frame squared errors (..., T) per group between windows ``x`` and ``y`` (..., T, F):
    ``||a - b||^2`` summed over each group's scalars; ``theta`` as ``||R(x) - R(y)||_F^2`` of the
    Gram-Schmidt matrices."""
    out = {}
    for g, s in layout.slices.items():
        if g == "theta":
            out[g] = (sixd_to_matrix(x[..., s]) - sixd_to_matrix(y[..., s])).square().sum((-1, -2))
        else:
            out[g] = (x[..., s] - y[..., s]).square().sum(-1)
    return out


def reconstruction_loss(x: Tensor, y: Tensor, layout: FeatureLayout) -> tuple[Tensor, dict[str, Tensor]]:
    """Eq. 3: mean over frames (and windows) of the per-frame loss (Eq. 4); also each group's mean."""
    errs = per_frame_errors(x, y, layout)
    groups = {g: errs[g].mean() for g in GROUPS}
    total = cast(Tensor, sum(errs.values()))  # not the start value 0: the layout has groups
    return total.mean(), groups


def kl_divergence(mu: Tensor, logvar: Tensor) -> Tensor:
    """``KL(N(mu, exp(logvar)) || N(0, I))`` summed over latent dims, averaged over the batch."""
    return (0.5 * (mu.square() + logvar.exp() - logvar - 1.0)).sum(-1).mean()


# ---------------------------------------------------------------------------------- schedules
def cyclical_beta(step: int, total_steps: int, beta: float, cycles: int, ratio: float) -> float:
    """Cyclical KL annealing (Fu et al. 2019): ``tau = mod(step, ceil(N/M)) / (N/M)``,
    ``beta_eff = beta * min(1, tau / ratio)``; ramps from 0 at the start of each of the ``cycles``
    cycles over ``total_steps`` steps."""
    period = math.ceil(total_steps / cycles)
    tau = (step % period) / (total_steps / cycles)
    return beta * min(1.0, tau / ratio) if ratio > 0 else beta


def sgdr_lr(step: int, lr0: float, t0: int, t_mult: int, eta_min: float = 0.0) -> float:
    """SGDR (Loshchilov & Hutter 2016) learning rate after ``step`` scheduler steps: cycles of length
    ``t0, t0*t_mult, ...``, ``lr = eta_min + (lr0 - eta_min)(1 + cos(pi T_cur / T_i)) / 2``."""
    t_cur, t_i = step, t0
    while t_cur >= t_i:
        t_cur -= t_i
        t_i *= t_mult
    return eta_min + 0.5 * (lr0 - eta_min) * (1.0 + math.cos(math.pi * t_cur / t_i))


__all__ = [
    "MotionVAE",
    "ResBlock",
    "cyclical_beta",
    "kl_divergence",
    "num_parameters",
    "per_frame_errors",
    "reconstruction_loss",
    "sgdr_lr",
]
