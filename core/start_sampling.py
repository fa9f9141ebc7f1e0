"""Failure-driven sampling of episode start times *within* a clip (after BeyondMimic's adaptive
sampling): the hard segment of a clip (a backflip's take-off, a spin's turn) is practised, not only
the easy run-up that uniform start times mostly give.

Each clip's timeline is cut into bins of ``bin_s`` seconds. An episode that fails adds 1 to the bin
of the time at which it failed; an episode that does not fail adds nothing; before each addition
all counts of that clip are multiplied by ``decay`` (old failures fade once a segment is learned).
Starts are drawn per clip from::

    p_b = (1 - floor) * s_b / sum(s) + floor / n_bins        (p uniform while sum(s) = 0)
    s_b = sum_{j = 0 .. lookback} f_{b + j}

i.e. a failure at bin ``b`` also raises the ``lookback`` bins before it, so that the policy starts
a little before the hard moment and meets it with its own momentum (BeyondMimic convolves its
failure histogram with a kernel for the same reason). Within a bin the time is uniform. The clip
itself is still drawn by the clip weights (hard negatives, :mod:`mocap.hard_negatives`).

Choices the paper leaves open are switches with documented defaults: bin width 1 s, floor 0.2
(every segment keeps a share), decay 0.99 per failure of the clip, look-back 1 bin.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from mocap.start_sampling_params import StartSamplingParams


class AdaptiveStartSampler:
    """Per-clip failure counts over time bins and the start-time distribution they give."""

    def __init__(self, durations: Tensor, params: StartSamplingParams):
        self.params = p = params
        dur = torch.as_tensor(durations, dtype=torch.float64).cpu()
        self.num_bins = torch.clamp(torch.ceil(dur / p.bin_s - 1e-9), min=1).long()  # (C,)
        self.offsets = torch.cumsum(self.num_bins, 0) - self.num_bins
        self.durations = dur
        self.counts = torch.zeros(int(self.num_bins.sum()), dtype=torch.float64)

    # ------------------------------------------------------------------------------ counts
    def bin_of(self, clip_ids: Tensor, times: Tensor) -> Tensor:
        """(K,) global bin index of clip times (wrapped into the period for times past the end)."""
        c = clip_ids.cpu().long()
        t = torch.as_tensor(times, dtype=torch.float64).cpu()
        dur = self.durations[c].clamp_min(1e-9)
        t = torch.where(t >= dur, torch.remainder(t, dur), t).clamp_min(0.0)
        b = torch.minimum(torch.floor(t / self.params.bin_s).long(), self.num_bins[c] - 1)
        return self.offsets[c] + b

    def record_failures(self, clip_ids: Tensor, fail_times: Tensor) -> None:
        """Episodes of ``clip_ids`` failed at clip times ``fail_times``: decay their clips, count the bins."""
        if clip_ids.numel() == 0:
            return
        bins = self.bin_of(clip_ids, fail_times)
        for c in torch.unique(clip_ids.cpu().long()).tolist():
            lo, n = int(self.offsets[c]), int(self.num_bins[c])
            self.counts[lo : lo + n] *= self.params.decay ** int((clip_ids.cpu() == c).sum())
        self.counts.index_add_(0, bins, torch.ones(bins.numel(), dtype=torch.float64))

    def probabilities(self, clip: int) -> Tensor:
        """(n_bins,) start probabilities of one clip's bins (module docstring)."""
        p = self.params
        lo, n = int(self.offsets[clip]), int(self.num_bins[clip])
        f = self.counts[lo : lo + n]
        s = f.clone()
        for j in range(1, p.lookback + 1):
            s[:-j] += f[j:]
        uniform = torch.full((n,), 1.0 / n, dtype=torch.float64)
        total = float(s.sum())
        if total <= 0:
            return uniform
        return (1.0 - p.floor) * s / total + p.floor * uniform

    # ---------------------------------------------------------------------------- sampling
    def sample_times(self, clip_ids: Tensor, generator: torch.Generator) -> Tensor:
        """(K,) start times (s, float64) for episodes of ``clip_ids``: a bin by :meth:`probabilities`,
        then uniform within it (clamped to the clip's duration)."""
        c = clip_ids.cpu().long()
        out = torch.zeros(c.numel(), dtype=torch.float64)
        for clip in torch.unique(c).tolist():
            rows = (c == clip).nonzero().squeeze(-1)
            probs = self.probabilities(int(clip))
            b = torch.multinomial(probs, rows.numel(), replacement=True, generator=generator)
            u = torch.rand(rows.numel(), generator=generator, dtype=torch.float64)
            t = (b.double() + u) * self.params.bin_s
            out[rows] = torch.minimum(t, self.durations[clip].expand_as(t))
        return out

    # ------------------------------------------------------------------------------ resume
    def state_dict(self) -> dict[str, Any]:
        return {"start_counts": self.counts.clone()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        counts = state.get("start_counts")
        if counts is None:
            return
        if tuple(counts.shape) != tuple(self.counts.shape):
            raise ValueError("the saved start-time counts were made with another motion set or bin width")
        self.counts = counts.to(torch.float64).clone()


def expected_bins(duration: float, bin_s: float) -> int:
    """Number of bins of a clip of ``duration`` seconds."""
    return max(1, math.ceil(duration / bin_s - 1e-9))


__all__ = ["AdaptiveStartSampler", "StartSamplingParams", "expected_bins"]
