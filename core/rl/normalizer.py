"""Running mean/variance normalization of observations (and, optionally, of value targets).

The statistics are float64 buffers of an ``nn.Module``, so a normalizer placed inside a policy
is saved and loaded with the policy's ``state_dict``. Batches are folded in with the parallel
(pairwise) update of Chan, Golub & LeVeque (1979)::

    n   = n_a + n_b
    δ   = μ_b − μ_a
    μ   = μ_a + δ · n_b / n
    M2  = M2_a + M2_b + δ² · n_a · n_b / n          (M2 = n · var, population variance)

which is exact for any split of the data, so :meth:`RunningNormalizer.merge` of two normalizers
equals one normalizer fed both sets of batches (the basis for data-parallel training).

Data-parallel training (:mod:`mocap.distributed`) folds the batches of all processes in at once:
each process computes its batch's :class:`Moments` (:func:`batch_moments`, or the updates a model
makes, recorded with :meth:`RunningNormalizer.capture`), the processes exchange them,
:func:`combine_moments` merges them in rank order with the formula above, and every process
applies the same result (:meth:`RunningNormalizer.update_moments`), so the statistics stay
identical on all processes and equal those of the concatenated data.
"""

from __future__ import annotations

import contextlib
from typing import Any, Iterator, NamedTuple, Sequence

import torch
from torch import Tensor, nn


class Moments(NamedTuple):
    """Sample count, mean and population variance of a set of samples (float64 tensors)."""

    count: Tensor  # type: ignore[assignment]  # a field named like tuple.count (public name, kept)
    mean: Tensor
    var: Tensor


def empty_moments(shape: Sequence[int], device: torch.device | str | None = None) -> Moments:
    """The moments of no samples (count 0): the identity of :func:`combine_moments`."""
    z = torch.zeros(tuple(shape), dtype=torch.float64, device=device)
    return Moments(torch.zeros((), dtype=torch.float64, device=device), z, torch.ones_like(z))


def batch_moments(x: Tensor, shape: Sequence[int]) -> Moments:
    """Moments of ``x`` of shape ``(..., *shape)`` over its leading dimensions."""
    x = x.detach().to(torch.float64).reshape(-1, *tuple(shape))
    if x.shape[0] == 0:
        return empty_moments(shape, x.device)
    return Moments(torch.tensor(float(x.shape[0]), dtype=torch.float64, device=x.device), x.mean(0), x.var(0, unbiased=False))


def combine_moments(parts: Sequence[Moments]) -> Moments:
    """The moments of the union of the parts' samples (Chan et al.'s pairwise formula, applied in
    order; exact up to rounding). Parts with count 0 are ignored. ``parts`` must not be empty."""
    count, mean, var = parts[0]
    for n_b, mean_b, var_b in parts[1:]:
        n = count + n_b
        if float(n) == 0:
            continue
        delta = mean_b - mean
        m2 = var * count + var_b * n_b + delta.square() * count * n_b / n
        mean = mean + delta * n_b / n
        var = m2 / n
        count = n
    return Moments(count, mean, var)


class RunningNormalizer(nn.Module):
    """Normalizes ``x`` to ``clamp((x − μ) / sqrt(var + eps), −clip, clip)`` with running μ, var.

    Args:
        shape: shape of one sample (``(obs_dim,)``; ``()`` or ``(1,)`` for scalars).
        clip: symmetric clip of the normalized value (``None``: no clipping).
        eps: added to the variance before the square root.

    Before any update the statistics are μ = 0, var = 1 (identity up to ``eps``). A frozen
    normalizer ignores :meth:`update` (use it when evaluating or fine-tuning a trained policy).
    """

    mean: Tensor
    var: Tensor
    count: Tensor

    def __init__(self, shape: int | Sequence[int], clip: float | None = 5.0, eps: float = 1e-8):
        super().__init__()
        self.shape = (shape,) if isinstance(shape, int) else tuple(shape)
        self.clip = clip
        self.eps = eps
        self.frozen = False
        self._captured: list[Moments] | None = None
        self.register_buffer("mean", torch.zeros(self.shape, dtype=torch.float64))
        self.register_buffer("var", torch.ones(self.shape, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    # ------------------------------------------------------------------------------ statistics
    def _merge_stats(self, mean_b: Tensor, var_b: Tensor, n_b: float | Tensor) -> None:
        n_a = self.count
        n = n_a + n_b
        if float(n) == 0:
            return
        delta = mean_b - self.mean
        m2 = self.var * n_a + var_b * n_b + delta.square() * n_a * n_b / n
        self.mean.copy_(self.mean + delta * n_b / n)
        self.var.copy_(m2 / n)
        self.count.copy_(n)

    @torch.no_grad()
    def update(self, x: Tensor) -> None:
        """Fold the batch ``x`` of shape ``(..., *shape)`` into the statistics (no-op when frozen)."""
        if self.frozen:
            return
        x = x.detach().to(device=self.mean.device, dtype=torch.float64).reshape(-1, *self.shape)
        if x.shape[0] == 0:
            return
        captured = getattr(self, "_captured", None)
        if captured is not None:  # inside capture(): recorded, applied by the caller
            captured.append(batch_moments(x, self.shape))
            return
        self._merge_stats(x.mean(0), x.var(0, unbiased=False), float(x.shape[0]))

    @torch.no_grad()
    def update_moments(self, moments: Moments) -> None:
        """Fold in a batch given by its :class:`Moments` (no-op when frozen)."""
        if self.frozen:
            return
        dev = self.mean.device
        self._merge_stats(moments.mean.to(dev), moments.var.to(dev), moments.count.to(dev))

    @contextlib.contextmanager
    def capture(self) -> Iterator[list[Moments]]:
        """Within the block, :meth:`update` records each batch's :class:`Moments` in the yielded list
        instead of changing the statistics (data-parallel training merges them across processes)."""
        previous, self._captured = getattr(self, "_captured", None), []
        try:
            yield self._captured
        finally:
            self._captured = previous

    @torch.no_grad()
    def merge(self, other: "RunningNormalizer") -> None:
        """Fold another normalizer's statistics into this one (exact: same as feeding its batches)."""
        if other.shape != self.shape:
            raise ValueError(f"cannot merge normalizers of shapes {self.shape} and {other.shape}")
        if self.frozen:
            return
        self._merge_stats(other.mean.to(self.mean.device), other.var.to(self.mean.device), other.count.to(self.mean.device))

    # ----------------------------------------------------------------------------- transforms
    def normalize(self, x: Tensor) -> Tensor:
        """``clamp((x − μ) / sqrt(var + eps), −clip, clip)`` in the dtype of ``x``."""
        mean = self.mean.to(x.dtype)
        std = torch.sqrt(self.var + self.eps).to(x.dtype)
        y = (x - mean) / std
        if self.clip is not None:
            y = y.clamp(-self.clip, self.clip)
        return y

    def denormalize(self, y: Tensor) -> Tensor:
        """Inverse of :meth:`normalize` (without the clip): ``y · sqrt(var + eps) + μ``."""
        return y * torch.sqrt(self.var + self.eps).to(y.dtype) + self.mean.to(y.dtype)

    def forward(self, x: Tensor) -> Tensor:
        return self.normalize(x)

    @property
    def std(self) -> Tensor:
        return torch.sqrt(self.var + self.eps)

    # ----------------------------------------------------------------------------- freezing
    def freeze(self, frozen: bool = True) -> "RunningNormalizer":
        self.frozen = frozen
        return self

    def get_extra_state(self) -> Any:
        return {"frozen": self.frozen}

    def set_extra_state(self, state: Any) -> None:
        self.frozen = bool(state.get("frozen", False)) if isinstance(state, dict) else False

    def extra_repr(self) -> str:
        return f"shape={self.shape}, clip={self.clip}, eps={self.eps}, frozen={self.frozen}"


__all__ = ["Moments", "RunningNormalizer", "batch_moments", "combine_moments", "empty_moments"]
