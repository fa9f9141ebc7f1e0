"""The torch-free part of :mod:`mocap.interfaces` (re-exported there): the action spaces and the
motion-source role. Modules that must import without torch (components' params, motion sources,
which ``mocap validate`` builds to fingerprint their files) take these from here.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mocap.skeleton import Skeleton


# --------------------------------------------------------------------------------------- spaces
@dataclass(frozen=True)
class Box:
    """A continuous action space of ``shape`` with elementwise bounds (``inf`` for unbounded).

    ``exploration_sigma``: the exploration σ the space's method prescribes for a Gaussian policy on
    it (PULSE Sec. 4.3: a fixed 0.22 on the prior residual), used by PPO when the spec leaves
    ``log_std_init`` unset; None: no prescription.
    """

    shape: tuple[int, ...]
    low: float = float("-inf")
    high: float = float("inf")
    exploration_sigma: float | None = None


@dataclass(frozen=True)
class MultiDiscrete:
    """One categorical choice per entry of ``nvec`` (e.g. a code index per RVQ codebook)."""

    nvec: tuple[int, ...]


ActionSpace = Box | MultiDiscrete


# --------------------------------------------------------------------------------- motion data
class MotionSource(ABC):
    """Loads clips from some format and converts them to :class:`mocap.motion.clip.Clip`."""

    @abstractmethod
    def load(self, skeleton: Skeleton) -> Any:
        """Return a ``MotionSet`` of clips on ``skeleton`` (bad files skipped and listed, or an error)."""

    def inputs(self) -> list[Path]:
        """The files :meth:`load` reads. The pipeline fingerprints their contents into every stage's
        artifact key (:func:`mocap.fingerprint.files_fingerprint`), so a clip edited in place is
        trained on again instead of being served from a stale stage. Default: none (the spec's
        params alone identify the data, e.g. clips generated from the params)."""
        return []


__all__ = ["ActionSpace", "Box", "MotionSource", "MultiDiscrete"]
