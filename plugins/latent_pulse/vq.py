"""PULSE's vector-quantized latent variant (App. C.3), built on the Hybrid-RVQ plugin's quantizer.

App. C.3: "we follow Liu et al. (2021); Van Den Oord et al. (2017) and use a 64-dimensional latent
space divided into 8 partitions, using a dictionary size of 64. Dividing the latent space into
partitions increases the representation power combinatorially". The encoder output ``x`` (B, D) is
split into ``G`` partitions of ``D / G`` dims; each partition is replaced by its nearest code
(squared Euclidean) from a dictionary of ``K`` codes:

* ``shared=True`` (Liu et al. 2021, discrete-valued neural communication: one dictionary shared by
  all partitions, K^G combinations) or ``shared=False`` (one dictionary per partition);
* straight-through estimator (VQ-VAE): the forward value is the codes, ``∂z/∂x = I``;
* commitment loss ``mean (x − sg(e*))²`` (VQ-VAE's β term; mean over batch and dims): zero iff
  every partition of ``x`` equals its code;
* the dictionaries are :class:`mocap.quantizers.VectorQuantizer` (imported, not copied):
  EMA updates (VQ-VAE-EMA, so the codebook term of VQ-VAE's loss has no gradient and is left out),
  dead-code reset and k-means initialization from the first training batch. Codebooks change only
  in a forward pass with ``train=True``.

The paper's VQ numbers are 64-d, 8 partitions, 64 codes; it does not say whether the dictionary is
shared: [INF] shared, as in Liu et al. (2021), is the default.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence, cast

import torch
from torch import Tensor, nn

from mocap.quantizers import CodebookInit, VectorQuantizer


class PartitionedOutput(NamedTuple):
    """``quantized`` (B, D) straight-through value, ``indices`` (B, G) long, ``commit`` scalar."""

    quantized: Tensor
    indices: Tensor
    commit: Tensor


class PartitionedVQ(nn.Module):
    """``G`` partitions of a ``dim``-vector, each quantized with a ``K``-code dictionary (module doc)."""

    def __init__(
        self,
        dim: int,
        partitions: int,
        codebook_size: int,
        *,
        shared: bool = True,
        decay: float = 0.99,
        dead_threshold: float = 2.0,
        init: CodebookInit = "kmeans",
    ):
        super().__init__()
        if partitions < 1 or dim % partitions:
            raise ValueError(f"dim {dim} must be a positive multiple of partitions {partitions}")
        self.dim, self.partitions, self.codebook_size = (
            int(dim),
            int(partitions),
            int(codebook_size),
        )
        self.part_dim = self.dim // self.partitions
        self.shared = bool(shared)
        n_books = 1 if self.shared else self.partitions
        self.books = nn.ModuleList(
            VectorQuantizer(
                self.part_dim,
                self.codebook_size,
                decay=decay,
                dead_threshold=dead_threshold,
                init=init,
            )
            for _ in range(n_books)
        )

    def forward(self, x: Tensor, *, train: bool = False) -> PartitionedOutput:
        """Quantize ``x`` (B, D); ``train`` runs the codebooks' initialization/EMA/reset."""
        B = x.shape[0]
        parts = x.reshape(B, self.partitions, self.part_dim)
        if self.shared:
            out = self.books[0](parts.reshape(B * self.partitions, self.part_dim), train=train)
            return PartitionedOutput(
                out.quantized.reshape(B, self.dim),
                out.indices.reshape(B, self.partitions),
                out.losses["commit"],
            )
        qs, ids, commits = [], [], []
        for g, book in enumerate(self.books):
            out = book(parts[:, g], train=train)
            qs.append(out.quantized)
            ids.append(out.indices[:, 0])
            commits.append(out.losses["commit"])
        return PartitionedOutput(torch.cat(qs, -1), torch.stack(ids, -1), torch.stack(commits).mean())

    def decode(self, indices: Tensor) -> Tensor:
        """(B, D) the codes of ``indices`` (B, G) (the forward value of :meth:`forward` for its indices)."""
        indices = indices.long()
        if indices.shape[-1] != self.partitions:
            raise ValueError(f"expected {self.partitions} code indices per sample, got shape {tuple(indices.shape)}")
        books = cast("Sequence[VectorQuantizer]", self.books)  # an nn.ModuleList indexes / iterates as plain Modules
        if self.shared:
            book = books[0].embed
            return book[indices.clamp(0, self.codebook_size - 1)].reshape(indices.shape[0], self.dim)
        return torch.cat(
            [b.embed[indices[:, g].clamp(0, self.codebook_size - 1)] for g, b in enumerate(books)],
            -1,
        )


__all__ = ["PartitionedOutput", "PartitionedVQ"]
