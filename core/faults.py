"""Numerical faults never reach the weights: shared by the ``ppo`` and ``distill`` trainers.

:class:`FaultGuard` wraps an optimizer step. A batch whose inputs, loss or gradients are not finite
(NaN or ±inf) is skipped: no optimizer step (so Adam's moments stay clean too), no normalizer
update; the skip is counted and logged (``faults/skipped``, ``faults/total``). After
``max_consecutive`` faulty batches in a row the trainer stops with :class:`NumericalFault` (a clear
message, exit status 2); the last checkpoint it wrote holds weights that never saw a fault.
"""

from __future__ import annotations

import math
from typing import Any, Iterable

import torch
from torch import Tensor

from mocap.pipeline import StageFailed


class NumericalFault(StageFailed):
    """Too many consecutive non-finite batches: the run stops; its last checkpoint is good."""


def all_finite(*tensors: Tensor | None) -> bool:
    """True when every given tensor (None ignored) has only finite entries."""
    return all(t is None or bool(torch.isfinite(t).all()) for t in tensors)


class FaultGuard:
    """Counts and skips non-finite batches (module docstring).

    Args:
        max_consecutive: faulty batches in a row after which :class:`NumericalFault` is raised
            (0: never stop, only skip).
        where: the trainer's name, for messages.
    """

    def __init__(self, max_consecutive: int = 10, where: str = "training"):
        self.max_consecutive = int(max_consecutive)
        self.where = where
        self.total = 0
        self.consecutive = 0
        self.recent = 0  # since the last take_counts()
        self.last_reason = ""

    def fault(self, reason: str) -> None:
        """Record one skipped batch; raise :class:`NumericalFault` after too many in a row."""
        self.total += 1
        self.recent += 1
        self.consecutive += 1
        self.last_reason = reason
        if self.max_consecutive and self.consecutive >= self.max_consecutive:
            raise NumericalFault(
                f"{self.where}: {self.consecutive} consecutive batches with non-finite values (last: {reason}); "
                "stopping. The last checkpoint holds weights from before the faults; lower the learning rate "
                "or check the environment's observations and rewards"
            )

    def check_inputs(self, **tensors: Tensor | None) -> bool:
        """False (and a recorded fault) when a named input tensor has non-finite entries."""
        for name, t in tensors.items():
            if t is not None and not bool(torch.isfinite(t).all()):
                self.fault(f"non-finite {name}")
                return False
        return True

    def step(self, optimizer: torch.optim.Optimizer, loss: Tensor, params: Iterable[Tensor], max_grad_norm: float | None) -> tuple[bool, float]:
        """Backward already done: clip gradients and step unless the loss or a gradient is not
        finite. Returns ``(stepped, grad_norm)``; on a skip the gradients are cleared."""
        params = list(params)
        if not bool(torch.isfinite(loss.detach()).all()):
            optimizer.zero_grad(set_to_none=True)
            self.fault("non-finite loss")
            return False, float("nan")
        norm = torch.nn.utils.clip_grad_norm_(params, max_grad_norm or math.inf)
        if not bool(torch.isfinite(norm)):
            optimizer.zero_grad(set_to_none=True)
            self.fault("non-finite gradient")
            return False, float("nan")
        optimizer.step()
        self.consecutive = 0
        return True, float(norm)

    def take_counts(self) -> dict[str, float]:
        """``faults/skipped`` since the last call and ``faults/total``; resets the former."""
        out = {"faults/skipped": float(self.recent), "faults/total": float(self.total)}
        self.recent = 0
        return out

    def state_dict(self) -> dict[str, Any]:
        return {"total": self.total, "consecutive": self.consecutive}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.total = int(state.get("total", 0))
        self.consecutive = int(state.get("consecutive", 0))


__all__ = ["FaultGuard", "NumericalFault", "all_finite"]
