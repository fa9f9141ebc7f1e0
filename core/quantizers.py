"""Vector quantizers with EMA codebooks: a single-codebook :class:`VectorQuantizer` and a
:class:`ResidualVQ` (Hybrid-RVQ paper, Bae et al. 2025, Sec. 4.2 and Eq. 5).

Both implement the small :class:`Quantizer` interface::

    out = quantizer(x)                 # x (B, D)
    out.quantized                      # (B, D) straight-through: value Σ_n e_n*, ∂/∂x = I (Eq. 4)
    out.indices                        # (B, N) long, -1 at levels a sample did not use
    out.losses["commit"]               # scalar commitment loss (unweighted)
    quantizer.decode(out.indices)      # == out.quantized in eval mode (the task phase relies on it)
    quantizer.codebooks                # (N, K, D)

**Residual quantization (Eq. 5).** With r_0 = x, level n picks e_n* = argmin_{e ∈ B_n} ‖r_{n-1} − e‖²
(ties: lowest index) and passes on r_n = r_{n-1} − e_n*; the quantized value is Σ_{n ≤ M} e_n*.
Residuals are formed from the (non-differentiable) codes, so ∂r_n/∂x = I.

**Straight-through (Eq. 4).** ``quantized = q + (x − sg(x))`` where q = Σ e_n* is the hard value:
its forward value is exactly q (the added term is exactly zero) and its gradient w.r.t. ``x`` is
the identity. Codebooks are buffers, not parameters: no gradient reaches them.

**Commitment loss** (Eq. 3's form, Sec. 3.3; per level or on the total is [DEFAULT], our choice: the
paper does not specify), mean-reduced over the batch and the dimensions:

* ``per_level`` (SoundStream/EnCodec style): Σ_i Σ_{n ≤ M_i} ‖r_{i,n-1} − sg(e_{i,n}*)‖² / (B·D)
  = Σ_i Σ_{n ≤ M_i} ‖r_{i,n}‖² / (B·D); its gradient w.r.t. x_i is 2/(B·D) · Σ_{n ≤ M_i} r_{i,n};
* ``total``: Σ_i ‖x_i − sg(q_i)‖² / (B·D).

With EMA codebooks the codebook term ‖sg(x) − e*‖² of Eq. 3 carries no gradient, so it is left
out (it would only add a constant to the logged value).

**EMA codebook update** ([P] "EMA update", formulas [DEFAULT] VQ-VAE-EMA), per level from the
assignments of the samples that used the level, with decay λ and Laplace ε::

    N_k ← λ N_k + (1 − λ) n_k                     (n_k: batch count of code k)
    m_k ← λ m_k + (1 − λ) Σ_{i: k_i = k} r_i
    Ñ_k = (N_k + ε) / (Σ_j N_j + K ε) · Σ_j N_j
    e_k = m_k / Ñ_k                                (codes never assigned, N_k = 0, keep their value)

λ = 1 freezes the codebook. **Dead-code reset** ([P] "code reset", threshold [DEFAULT] 2.0): after
each EMA step, every code with N_k < threshold is replaced by a random residual of the current
batch at that level (sampled without replacement when the batch is large enough), and its
statistics restart at N_k = threshold, m_k = threshold · e_k, so no code is dead right after a
reset; a code that stays unused decays below the threshold and is replaced again. Threshold 0
disables the reset.

**Initialization** (switch ``init``): on the first training forward pass, each level's codebook is
fit to the residuals of that batch at that level: ``kmeans`` ([DEFAULT], as SoundStream: Lloyd
iterations from randomly chosen batch vectors; empty clusters keep their centre) or ``random``
(randomly chosen batch vectors). The statistics start at N_k = the batch count of code k and
m_k = N_k e_k (the scale of a batch, which makes the dead-code threshold meaningful from the start).
Until then the codebook holds N(0, 1) placeholders. The ``initialized`` flag is a buffer, so a
loaded checkpoint is never re-initialized.

**Quantizer dropout** ([P], SoundStream): in training, the depth M is drawn uniformly from
{1, …, N}, per sample (``per_sample=True``, [DEFAULT], SoundStream) or once per batch, for a
fraction ``prob`` of the samples/batches (the others use M = N). Levels n > M contribute nothing,
get no commitment loss and no EMA/reset update, and report index -1. In eval the depth is N, or
``n_active`` when given (0 ≤ n_active ≤ N).

Training vs eval: ``forward(x, n_active=None, train=None)`` updates codebooks and applies dropout
only when ``train`` (default: ``self.training``) is true. The EMA buffers are updated in place;
in data-parallel training each process updates its own copy.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Literal, NamedTuple

import torch
from torch import Tensor, nn

CodebookInit = Literal["kmeans", "random"]
DeadThresholdMode = Literal["absolute", "relative"]
Commitment = Literal["per_level", "total"]


class QuantizerOutput(NamedTuple):
    """What a quantizer returns (unpacks as ``quantized, indices, losses``).

    Attributes:
        quantized: (B, D) straight-through quantized value (forward value: the sum of the codes).
        indices: (B, N) long code index per level, -1 where the level was not used.
        losses: ``{"commit": scalar}``, the unweighted commitment loss.
    """

    quantized: Tensor
    indices: Tensor
    losses: dict[str, Tensor]


class Quantizer(nn.Module, ABC):
    """A (multi-level) vector quantizer of ``dim``-vectors with ``num_levels`` codebooks of
    ``codebook_size`` codes each."""

    dim: int
    num_levels: int
    codebook_size: int

    @abstractmethod
    def forward(self, x: Tensor, n_active: int | None = None, *, train: bool | None = None) -> QuantizerOutput:
        """Quantize ``x`` (B, D) with the first ``n_active`` levels (default: all, or dropout in training)."""

    @abstractmethod
    def decode(self, indices: Tensor) -> Tensor:
        """(B, D) sum of the codes ``indices`` (B, M) of the first M levels (-1: no contribution)."""

    @property
    @abstractmethod
    def codebooks(self) -> Tensor:
        """(N, K, D) the codebooks (a view of the buffers; do not modify in place)."""

    def perplexity(self) -> Tensor:
        """(N,) exp(entropy) of each level's EMA code-usage distribution (K = uniform use)."""
        sizes = torch.stack([lvl.cluster_size for lvl in self._levels()])
        p = sizes / sizes.sum(-1, keepdim=True).clamp_min(1e-12)
        return torch.exp(-(p * torch.log(p.clamp_min(1e-12))).sum(-1))

    def _levels(self) -> list[VectorQuantizer]:  # pragma: no cover - overridden
        raise NotImplementedError


def _nearest(x: Tensor, embed: Tensor) -> Tensor:
    """(B,) index of the nearest code (squared Euclidean; ties: lowest index, up to the rounding of
    the expanded distance ‖x‖² − 2x·e + ‖e‖²) of each row of x."""
    # ‖x − e‖² = ‖x‖² − 2 x·e + ‖e‖²; ‖x‖² is constant per row and does not change the argmin
    dist = torch.addmm(embed.square().sum(-1).unsqueeze(0), x, embed.t(), beta=1.0, alpha=-2.0)
    return dist.argmin(dim=-1)


def _choose_rows(x: Tensor, count: int) -> Tensor:
    """``count`` rows of ``x`` chosen at random (without replacement when x has enough rows)."""
    n = x.shape[0]
    if n >= count:
        pick = torch.randperm(n, device=x.device)[:count]
    else:
        pick = torch.randint(0, n, (count,), device=x.device)
    return x[pick]


def kmeans(x: Tensor, k: int, iters: int = 10) -> tuple[Tensor, Tensor]:
    """Lloyd's k-means from ``k`` random rows of ``x`` (B, D): ``(centres (k, D), counts (k,))``.

    Clusters that become empty keep their previous centre. ``counts`` are the sizes of the final
    assignment to the returned centres.
    """
    centres = _choose_rows(x, k).clone()
    for _ in range(iters):
        assign = _nearest(x, centres)
        counts = torch.bincount(assign, minlength=k).to(x.dtype)
        sums = torch.zeros_like(centres).index_add_(0, assign, x)
        filled = counts > 0
        centres = torch.where(filled.unsqueeze(-1), sums / counts.clamp_min(1).unsqueeze(-1), centres)
    counts = torch.bincount(_nearest(x, centres), minlength=k).to(x.dtype)
    return centres, counts


class VectorQuantizer(Quantizer):
    """One EMA codebook of ``codebook_size`` codes in R^dim (NCP-style VQ, and one RVQ level).

    Args:
        dim: code dimension D.
        codebook_size: number of codes K.
        decay: EMA decay λ ([DEFAULT] 0.99); 1.0 freezes the codebook.
        eps: Laplace smoothing ε of the cluster sizes ([DEFAULT] 1e-5).
        dead_threshold: codes whose EMA cluster size falls below this are reset from the batch
            ([DEFAULT] 2.0; 0 disables).
        dead_threshold_mode: ``"absolute"`` (the threshold is an EMA count of samples per batch,
            vector-quantize-pytorch's ``threshold_ema_dead_code``) or ``"relative"`` (a fraction of
            the mean use per code, ``B / K`` for a batch of B rows at this level: the same setting
            means the same at every batch size; at B = 512, K = 1024 an absolute 2.0 is 4x the mean
            use, so most codes count as dead every step).
        init: ``kmeans`` ([DEFAULT]) or ``random`` initialization from the first training batch.
        kmeans_iters: Lloyd iterations of the k-means initialization.
    """

    embed: Tensor
    cluster_size: Tensor
    embed_sum: Tensor
    initialized: Tensor

    def __init__(
        self,
        dim: int,
        codebook_size: int,
        *,
        decay: float = 0.99,
        eps: float = 1e-5,
        dead_threshold: float = 2.0,
        dead_threshold_mode: DeadThresholdMode = "absolute",
        init: CodebookInit = "kmeans",
        kmeans_iters: int = 10,
    ):
        super().__init__()
        if dead_threshold_mode not in ("absolute", "relative"):
            raise ValueError(f"dead_threshold_mode must be 'absolute' or 'relative', got {dead_threshold_mode!r}")
        if dim < 1 or codebook_size < 1:
            raise ValueError(f"dim and codebook_size must be >= 1, got {dim}, {codebook_size}")
        if not 0.0 < decay <= 1.0:
            raise ValueError(f"decay must be in (0, 1], got {decay}")
        if init not in ("kmeans", "random"):
            raise ValueError(f"init must be 'kmeans' or 'random', got {init!r}")
        self.dim = int(dim)
        self.num_levels = 1
        self.codebook_size = int(codebook_size)
        self.decay = float(decay)
        self.eps = float(eps)
        self.dead_threshold = float(dead_threshold)
        self.dead_threshold_mode = dead_threshold_mode
        self.init = init
        self.kmeans_iters = int(kmeans_iters)
        embed = torch.randn(codebook_size, dim)
        self.register_buffer("embed", embed)
        self.register_buffer("cluster_size", torch.ones(codebook_size))
        self.register_buffer("embed_sum", embed.clone())
        self.register_buffer("initialized", torch.zeros((), dtype=torch.bool))

    def _levels(self) -> list[VectorQuantizer]:
        return [self]

    @property
    def codebooks(self) -> Tensor:
        return self.embed.unsqueeze(0)

    # ----------------------------------------------------------------------------- codebook ops
    def nearest(self, x: Tensor) -> Tensor:
        """(B,) index of the nearest code of each row of ``x`` (B, D) (no gradient)."""
        with torch.no_grad():
            return _nearest(x.detach().to(self.embed.dtype), self.embed)

    @torch.no_grad()
    def set_codebook(self, codes: Tensor) -> None:
        """Replace the codebook by ``codes`` (K, D) and mark it initialized (statistics: N_k = 1)."""
        codes = codes.to(self.embed)
        if codes.shape != self.embed.shape:
            raise ValueError(f"codebook must have shape {tuple(self.embed.shape)}, got {tuple(codes.shape)}")
        self.embed.copy_(codes)
        self.cluster_size.fill_(1.0)
        self.embed_sum.copy_(codes)
        self.initialized.fill_(True)

    @torch.no_grad()
    def initialize(self, x: Tensor) -> None:
        """Fit the codebook to the batch ``x`` (B, D) (k-means or random rows; see module doc)."""
        x = x.detach().to(self.embed.dtype)
        if x.shape[0] == 0:
            return
        if self.init == "kmeans":
            centres, counts = kmeans(x, self.codebook_size, self.kmeans_iters)
        else:
            centres = _choose_rows(x, self.codebook_size)
            counts = torch.bincount(_nearest(x, centres), minlength=self.codebook_size).to(x.dtype)
        self.embed.copy_(centres)
        self.cluster_size.copy_(counts)
        self.embed_sum.copy_(centres * counts.unsqueeze(-1))
        self.initialized.fill_(True)

    @torch.no_grad()
    def ema_update(self, x: Tensor, indices: Tensor) -> None:
        """One EMA step from the vectors ``x`` (B, D) assigned to codes ``indices`` (B,)."""
        if self.decay >= 1.0:
            return
        x = x.detach().to(self.embed.dtype)
        counts = torch.bincount(indices, minlength=self.codebook_size).to(x.dtype)
        sums = torch.zeros_like(self.embed).index_add_(0, indices, x)
        self.cluster_size.mul_(self.decay).add_(counts, alpha=1.0 - self.decay)
        self.embed_sum.mul_(self.decay).add_(sums, alpha=1.0 - self.decay)
        total = self.cluster_size.sum()
        smoothed = (self.cluster_size + self.eps) / (total + self.codebook_size * self.eps) * total
        new = self.embed_sum / smoothed.unsqueeze(-1)
        self.embed.copy_(torch.where((self.cluster_size > 0).unsqueeze(-1), new, self.embed))

    @torch.no_grad()
    def reset_dead(self, x: Tensor) -> Tensor:
        """Replace codes with EMA size < threshold by distinct random rows of ``x``; return the (K,)
        mask of the codes replaced.

        With more dead codes than rows, a random subset of ``len(x)`` dead codes is replaced now and
        the rest in later steps: filling them all from one small batch would put several copies of
        one row in the codebook, and only one copy could ever be chosen.
        """
        threshold = self.effective_threshold(x.shape[0])
        dead = self.cluster_size < threshold
        n_dead = int(dead.sum())
        if n_dead == 0 or x.shape[0] == 0:
            return torch.zeros_like(dead)
        if n_dead > x.shape[0]:
            ids = dead.nonzero().squeeze(-1)
            keep = ids[torch.randperm(n_dead, device=ids.device)[: x.shape[0]]]
            dead = torch.zeros_like(dead)
            dead[keep] = True
            n_dead = x.shape[0]
        new = _choose_rows(x.detach().to(self.embed.dtype), n_dead)
        self.embed[dead] = new
        self.cluster_size[dead] = threshold
        self.embed_sum[dead] = new * threshold
        return dead

    def effective_threshold(self, batch_rows: int) -> float:
        """The EMA cluster size below which a code is dead, for a batch of ``batch_rows`` rows here."""
        if self.dead_threshold_mode == "relative":
            return self.dead_threshold * batch_rows / self.codebook_size
        return self.dead_threshold

    def train_step(self, x: Tensor, indices: Tensor) -> None:
        """EMA update then dead-code reset from the level's inputs ``x`` and their assignments."""
        self.ema_update(x, indices)
        self.reset_dead(x)

    # ---------------------------------------------------------------------------------- Quantizer
    def forward(self, x: Tensor, n_active: int | None = None, *, train: bool | None = None) -> QuantizerOutput:
        train = self.training if train is None else train
        if n_active is not None and n_active not in (0, 1):
            raise ValueError(f"a single VQ has one level; n_active must be 0 or 1, got {n_active}")
        batch = x.shape[0]
        if n_active == 0:
            indices = torch.full((batch, 1), -1, dtype=torch.long, device=x.device)
            return QuantizerOutput(torch.zeros_like(x) + (x - x.detach()), indices, {"commit": (x * 0).sum()})
        if train and not bool(self.initialized):
            self.initialize(x)
        idx = self.nearest(x)
        codes = self.embed[idx].to(x.dtype)
        commit = (x - codes).square().sum() / max(x.numel(), 1)
        if train:
            self.train_step(x, idx)
        quantized = codes + (x - x.detach())
        return QuantizerOutput(quantized, idx.unsqueeze(-1), {"commit": commit})

    def decode(self, indices: Tensor) -> Tensor:
        if indices.dim() == 1:
            indices = indices.unsqueeze(-1)
        if indices.shape[-1] > 1:
            raise ValueError(f"a single VQ decodes one index per sample, got shape {tuple(indices.shape)}")
        idx = indices[:, 0]
        valid = (idx >= 0).unsqueeze(-1)
        return torch.where(valid, self.embed[idx.clamp_min(0)], torch.zeros((), dtype=self.embed.dtype, device=idx.device))

    def extra_repr(self) -> str:
        return (
            f"dim={self.dim}, codebook_size={self.codebook_size}, decay={self.decay}, eps={self.eps}, "
            f"dead_threshold={self.dead_threshold} ({self.dead_threshold_mode}), init={self.init!r}"
        )


class ResidualVQ(Quantizer):
    """Residual vector quantizer (Eq. 5): ``num_quantizers`` EMA codebooks applied to successive
    residuals, with quantizer dropout.

    Args:
        dim: code dimension D (the latent dimension).
        num_quantizers: number of levels N ([P] 8).
        codebook_size: codes per level K ([P] 1024; separate codebooks per level).
        decay, eps, dead_threshold, dead_threshold_mode, init, kmeans_iters: per level, see :class:`VectorQuantizer`.
        dropout: quantizer dropout in training ([P] used).
        dropout_per_sample: draw the depth M per sample ([DEFAULT], SoundStream) or once per batch.
        dropout_prob: fraction of samples (or batches) that get a random depth; the others use N
            ([DEFAULT] 1.0; DAC uses 0.5).
        commitment: ``per_level`` ([DEFAULT]) or ``total`` (see the module doc).
    """

    def __init__(
        self,
        dim: int,
        num_quantizers: int = 8,
        codebook_size: int = 1024,
        *,
        decay: float = 0.99,
        eps: float = 1e-5,
        dead_threshold: float = 2.0,
        dead_threshold_mode: DeadThresholdMode = "absolute",
        init: CodebookInit = "kmeans",
        kmeans_iters: int = 10,
        dropout: bool = True,
        dropout_per_sample: bool = True,
        dropout_prob: float = 1.0,
        commitment: Commitment = "per_level",
    ):
        super().__init__()
        if num_quantizers < 1:
            raise ValueError(f"num_quantizers must be >= 1, got {num_quantizers}")
        if not 0.0 <= dropout_prob <= 1.0:
            raise ValueError(f"dropout_prob must be in [0, 1], got {dropout_prob}")
        if commitment not in ("per_level", "total"):
            raise ValueError(f"commitment must be 'per_level' or 'total', got {commitment!r}")
        self.dim = int(dim)
        self.num_levels = int(num_quantizers)
        self.codebook_size = int(codebook_size)
        self.dropout = bool(dropout)
        self.dropout_per_sample = bool(dropout_per_sample)
        self.dropout_prob = float(dropout_prob)
        self.commitment = commitment
        self.levels = nn.ModuleList(
            VectorQuantizer(
                dim,
                codebook_size,
                decay=decay,
                eps=eps,
                dead_threshold=dead_threshold,
                dead_threshold_mode=dead_threshold_mode,
                init=init,
                kmeans_iters=kmeans_iters,
            )
            for _ in range(num_quantizers)
        )

    def _levels(self) -> list[VectorQuantizer]:
        return list(self.levels)  # type: ignore[arg-type]

    @property
    def codebooks(self) -> Tensor:
        return torch.stack([lvl.embed for lvl in self._levels()])

    def sample_depth(self, batch: int, device: torch.device | str = "cpu") -> Tensor:
        """(B,) training depths M in {1..N} (quantizer dropout), N where dropout does not apply."""
        n = self.num_levels
        rows = batch if self.dropout_per_sample else 1
        depth = torch.randint(1, n + 1, (rows,), device=device)
        if self.dropout_prob < 1.0:
            keep_full = torch.rand(rows, device=device) >= self.dropout_prob
            depth = torch.where(keep_full, torch.full_like(depth, n), depth)
        return depth.expand(batch) if rows == 1 else depth

    def forward(self, x: Tensor, n_active: int | None = None, *, train: bool | None = None) -> QuantizerOutput:
        train = self.training if train is None else train
        batch, n = x.shape[0], self.num_levels
        if n_active is not None:
            if not 0 <= n_active <= n:
                raise ValueError(f"n_active must be in [0, {n}], got {n_active}")
            depth = torch.full((batch,), int(n_active), dtype=torch.long, device=x.device)
        elif train and self.dropout:
            depth = self.sample_depth(batch, x.device)
        else:
            depth = torch.full((batch,), n, dtype=torch.long, device=x.device)

        indices = torch.full((batch, n), -1, dtype=torch.long, device=x.device)
        hard = torch.zeros_like(x.detach())
        residual = x  # r_0 = x; r_n = r_{n-1} − e_n* keeps ∂r_n/∂x = I
        commit_sum = x.new_zeros(())
        for level_id, level in enumerate(self._levels()):
            active = depth > level_id
            if not bool(active.any()):
                break
            r_active = residual.detach()[active]
            if train and not bool(level.initialized):
                level.initialize(r_active)
            if bool(active.all()):
                idx = level.nearest(residual)
            else:  # assign only the samples that use this level
                idx = torch.zeros(batch, dtype=torch.long, device=x.device)
                idx[active] = level.nearest(r_active)
            codes = level.embed[idx].to(x.dtype) * active.unsqueeze(-1).to(x.dtype)
            indices[:, level_id] = torch.where(active, idx, indices[:, level_id])
            residual_next = residual - codes
            if self.commitment == "per_level":
                commit_sum = commit_sum + (residual_next.square().sum(-1) * active.to(x.dtype)).sum()
            hard = hard + codes
            if train:
                level.train_step(r_active, idx[active])
            residual = residual_next
        if self.commitment == "total":
            commit_sum = (x - hard).square().sum()
        commit = commit_sum / max(x.numel(), 1)
        quantized = hard + (x - x.detach())
        return QuantizerOutput(quantized, indices, {"commit": commit})

    def decode(self, indices: Tensor) -> Tensor:
        if indices.dim() == 1:
            indices = indices.unsqueeze(-1)
        m = indices.shape[-1]
        if m > self.num_levels:
            raise ValueError(f"indices have {m} levels, the quantizer has {self.num_levels}")
        levels = self._levels()
        out = torch.zeros(indices.shape[0], self.dim, dtype=levels[0].embed.dtype, device=indices.device)
        for level_id in range(m):
            out = out + levels[level_id].decode(indices[:, level_id])
        return out

    def extra_repr(self) -> str:
        return (
            f"dim={self.dim}, num_quantizers={self.num_levels}, codebook_size={self.codebook_size}, "
            f"dropout={self.dropout}, per_sample={self.dropout_per_sample}, prob={self.dropout_prob}, "
            f"commitment={self.commitment!r}"
        )


__all__ = [
    "CodebookInit",
    "Commitment",
    "Quantizer",
    "QuantizerOutput",
    "ResidualVQ",
    "VectorQuantizer",
    "kmeans",
]
