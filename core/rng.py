"""The process-wide random number generators of a trainer, saved and restored for exact resume.

:func:`rng_state` holds only tensors, ints and floats (no NumPy objects), so a checkpoint that
stores it loads with ``torch.load(weights_only=True)`` (:func:`mocap.checkpoint.load_checkpoint`
never unpickles anything else). NumPy's legacy global generator state ``("MT19937", keys, pos,
has_gauss, cached_gaussian)`` is stored as a dict with the 624 keys as an int64 tensor.
"""

from __future__ import annotations

import random
from typing import Any

import numpy as np
import torch


def rng_state() -> dict[str, Any]:
    """torch, NumPy (global) and Python ``random`` states (and CUDA's when present)."""
    name, keys, pos, has_gauss, cached = np.random.get_state(legacy=True)  # type: ignore[misc]
    numpy_state = {
        "bit_generator": str(name),
        "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64).copy()),
        "pos": int(pos),
        "has_gauss": int(has_gauss),
        "cached_gaussian": float(cached),
    }
    state: dict[str, Any] = {"torch": torch.get_rng_state(), "numpy": numpy_state, "python": random.getstate()}
    if torch.cuda.is_available():  # pragma: no cover - no GPU in CI
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore what :func:`rng_state` returned (also NumPy's tuple form of older checkpoints)."""
    torch.set_rng_state(state["torch"])
    ns = state["numpy"]
    if isinstance(ns, dict):
        keys = np.asarray(torch.as_tensor(ns["keys"]).numpy(), dtype=np.uint32)
        np.random.set_state((ns["bit_generator"], keys, int(ns["pos"]), int(ns["has_gauss"]), float(ns["cached_gaussian"])))
    else:
        np.random.set_state(ns)
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():  # pragma: no cover
        torch.cuda.set_rng_state_all(state["cuda"])


__all__ = ["rng_state", "set_rng_state"]
