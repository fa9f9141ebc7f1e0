"""The (T, N) observation chunks of online distillation (:mod:`mocap.distill`): T rollout steps
stacked into one chunk (:func:`_stack_obs`) and a minibatch's env columns of it (:func:`_columns`)."""

from __future__ import annotations

import torch
from torch import Tensor

from mocap.state import Observations


def _stack_obs(items: list[Observations]) -> Observations:
    """(T, N, ...) observations from T steps of (N, ...) ones (tensor extras with N rows are kept)."""
    first = items[0]
    goal = None if first.goal is None else torch.stack([o.goal for o in items])  # type: ignore[misc]
    extra = {}
    for k, v in first.extra.items():
        if isinstance(v, Tensor) and v.dim() > 0 and v.shape[0] == first.proprio.shape[0]:
            extra[k] = torch.stack([o.extra[k] for o in items])
    return Observations(proprio=torch.stack([o.proprio for o in items]), goal=goal, extra=extra)


def _columns(obs: Observations, idx: Tensor) -> Observations:
    return Observations(
        proprio=obs.proprio[:, idx],
        goal=None if obs.goal is None else obs.goal[:, idx],
        extra={k: v[:, idx] for k, v in obs.extra.items()},
    )
