"""The files of online distillation (:mod:`mocap.distill`, which re-exports these): their names and
formats, and the latent file's writer (:func:`save_latent`) and reader (:func:`load_latent_state`, which
also reads the student inside a resumable ``distill.pt``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mocap.checkpoint import CheckpointError, load_checkpoint, save_checkpoint

CHECKPOINT_FORMAT = "mocap.distill/1"
CHECKPOINT_NAME = "distill.pt"
LATENT_FORMAT = "mocap.latent/1"
LATENT_NAME = "latent.pt"


def save_latent(path: Path, latent: torch.nn.Module, extra: dict[str, Any] | None = None, *, spec_yaml: str | None = None) -> None:
    """Write a trained latent space (``config`` if it has one, weights, buffers) atomically to ``path``."""
    state = {k: v.detach().cpu() if isinstance(v, Tensor) else v for k, v in latent.state_dict().items()}
    save_checkpoint(
        Path(path),
        {"format": LATENT_FORMAT, "config": getattr(latent, "config", None), "state_dict": state, "extra": extra or {}},
        spec_yaml=spec_yaml,
    )


def load_latent_state(path: Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """``{"config", "state_dict", "extra", "spec"}`` of a latent file (:func:`save_latent`) or of the
    student inside a resumable ``distill.pt``; a latent factory rebuilds its module from these."""
    data = load_checkpoint(Path(path), map_location=map_location)
    fmt = data.get("format")
    if fmt == LATENT_FORMAT:
        return {"config": data.get("config"), "state_dict": data["state_dict"], "extra": data.get("extra", {}), "spec": data.get("spec")}
    if fmt == CHECKPOINT_FORMAT:  # a training checkpoint: the label it trains on is in its params (latent.pt keeps it in extra)
        params = data.get("params") if isinstance(data.get("params"), dict) else {}
        extra = {"label": params["label"]} if isinstance(params.get("label"), str) else {}
        return {"config": data.get("latent_config"), "state_dict": data["student"], "extra": extra, "spec": data.get("spec")}
    raise CheckpointError(f"{path}: not a distilled latent-space file (format {fmt!r}, expected {LATENT_FORMAT!r} or {CHECKPOINT_FORMAT!r})")


__all__ = ["CHECKPOINT_FORMAT", "CHECKPOINT_NAME", "LATENT_FORMAT", "LATENT_NAME", "load_latent_state", "save_latent"]
