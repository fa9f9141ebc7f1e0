"""Hard-negative clip sampling shared by every trainer that samples clips (PHC+, distillation)."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor


def failure_weights(fail_counts: Tensor, base: Tensor, floor: float) -> Tensor:
    """Clip sampling probabilities ``(1 − floor) f / Σf + floor · b`` (``b`` normalized; ``b`` when Σf = 0).

    Sums to 1; with ``floor = 0`` the support is exactly the clips that failed (PHC+); with
    ``floor > 0`` every clip with ``b_c > 0`` keeps at least ``floor · b_c``.
    """
    f = fail_counts.to(torch.float64).clamp_min(0.0)
    b = base.to(torch.float64)
    b = b / b.sum()
    total = f.sum()
    if float(total) <= 0.0:
        return b.clone()
    w = (1.0 - floor) * f / total + floor * b
    return w / w.sum()


class FailureTracker:
    """Per-clip failure bookkeeping and the sampling weights it drives (PHC+ soft mining).

    ``params`` has ``hard_negative`` (on/off), ``hard_negative_floor``, ``hard_negative_decay`` and
    ``update_every``. Training episodes are counted per clip; every ``update_every`` finished
    episodes each clip played in that window adds its failure *rate* to ``fail_counts`` (a rate,
    not a count, so a clip's weight does not feed on how often it was sampled); evaluations add
    amounts directly (:meth:`add_failures`). Before each addition ``f`` is multiplied by the decay.
    The library's weights become :func:`failure_weights` of the counts when mining is on.
    """

    def __init__(self, library: Any, params: Any):
        self.library = library
        self.params = params
        C = library.num_clips
        self.base_weights = library.weights.detach().to("cpu", torch.float64).clone()
        self.fail_counts = torch.zeros(C, dtype=torch.float64)
        self.episodes_per_clip = torch.zeros(C, dtype=torch.long)
        self.failures_per_clip = torch.zeros(C, dtype=torch.long)
        self._win_episodes = torch.zeros(C, dtype=torch.float64)
        self._win_failures = torch.zeros(C, dtype=torch.float64)
        self._win_total = 0

    def record(self, clip_ids: Tensor, failed: Tensor) -> None:
        """Count finished training episodes; fold the window's failure rates in every ``update_every``."""
        ones = torch.ones_like(clip_ids, dtype=torch.float64)
        f = failed.to(torch.float64)
        self.episodes_per_clip.index_add_(0, clip_ids, ones.long())
        self.failures_per_clip.index_add_(0, clip_ids, f.long())
        self._win_episodes.index_add_(0, clip_ids, ones)
        self._win_failures.index_add_(0, clip_ids, f)
        self._win_total += int(clip_ids.numel())
        if self._win_total >= self.params.update_every:
            seen = self._win_episodes > 0
            rate = torch.where(seen, self._win_failures / self._win_episodes.clamp_min(1.0), torch.zeros_like(self._win_failures))
            self.add_failures(rate)
            self._win_episodes.zero_()
            self._win_failures.zero_()
            self._win_total = 0

    def add_failures(self, amount: Tensor) -> None:
        """``f <- decay * f + amount`` and refresh the sampling weights (when mining is on)."""
        self.fail_counts = self.fail_counts * self.params.hard_negative_decay + amount.to(torch.float64)
        if self.params.hard_negative:
            self.library.set_weights(failure_weights(self.fail_counts, self.base_weights, self.params.hard_negative_floor))

    def state_dict(self) -> dict[str, Any]:
        return {
            "fail_counts": self.fail_counts.clone(),
            "episodes_per_clip": self.episodes_per_clip.clone(),
            "failures_per_clip": self.failures_per_clip.clone(),
            "win_episodes": self._win_episodes.clone(),
            "win_failures": self._win_failures.clone(),
            "win_total": self._win_total,
            "weights": self.library.weights.detach().to("cpu", torch.float64).clone(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.fail_counts = state["fail_counts"].clone()
        self.episodes_per_clip = state["episodes_per_clip"].clone()
        self.failures_per_clip = state["failures_per_clip"].clone()
        self._win_episodes = state["win_episodes"].clone()
        self._win_failures = state["win_failures"].clone()
        self._win_total = int(state["win_total"])
        self.library.set_weights(state["weights"])
