"""The files of online distillation (:mod:`mocap.distill`, which re-exports these): their names and
formats, and the latent file's writer (:func:`save_latent`) and reader (:func:`load_latent_state`, which
also reads the student inside a resumable ``distill.pt``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mocap.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from mocap.interfaces import LatentSpace

CHECKPOINT_FORMAT = "mocap.distill/1"
CHECKPOINT_NAME = "distill.pt"
LATENT_FORMAT = "mocap.latent/1"
LATENT_NAME = "latent.pt"


def save_latent(path: Path, latent: torch.nn.Module, extra: dict[str, Any] | None = None, *, spec_yaml: str | None = None) -> None:
    """Write a trained latent space (``config`` if it has one, weights, buffers) atomically to ``path``."""
    state = {k: v.detach().cpu() if isinstance(v, Tensor) else v for k, v in latent.state_dict().items()}
    save_checkpoint(
        Path(path),
        {"format": LATENT_FORMAT, "config": latent.config if isinstance(latent, LatentSpace) else None, "state_dict": state, "extra": extra or {}},
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
        params = data.get("params")
        if not isinstance(params, dict):
            params = {}
        extra = {"label": params["label"]} if isinstance(params.get("label"), str) else {}
        return {"config": data.get("latent_config"), "state_dict": data["student"], "extra": extra, "spec": data.get("spec")}
    raise CheckpointError(f"{path}: not a distilled latent-space file (format {fmt!r}, expected {LATENT_FORMAT!r} or {CHECKPOINT_FORMAT!r})")


def init_from_latent(latent: torch.nn.Module, path: Path) -> None:
    """Copy the weights and buffers of the latent file ``path`` (:func:`load_latent_state`) into
    ``latent``, a fresh student of the same architecture (the distill trainer's ``init_latent``).
    A file of another architecture raises :class:`~mocap.checkpoint.CheckpointError` naming the tensors."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: init_latent does not exist")
    state = load_latent_state(path)["state_dict"]
    got = {k: tuple(v.shape) for k, v in state.items() if isinstance(v, Tensor)}
    want = {k: tuple(v.shape) for k, v in latent.state_dict().items() if isinstance(v, Tensor)}
    if got != want:
        bad = sorted(k for k in set(got) | set(want) if got.get(k) != want.get(k))
        raise CheckpointError(
            f"{path}: init_latent does not fit this latent space ({len(bad)} differing tensors: "
            f"{', '.join(bad[:3])}{', ...' if len(bad) > 3 else ''}); its sizes must match the spec's"
        )
    latent.load_state_dict(state)


def check_latent_loaded(latent: torch.nn.Module, path: Path, name: str) -> None:
    """The framework's check that a latent factory handed ``path`` returned the weights in it.

    A factory receives the checkpoint as a path and loads it itself; one that ignored it would
    evaluate random weights without a word. Called whenever a latent space is built from a
    checkpoint; a file this module does not read (a plugin's own format, e.g. VMP's) is not checked.
    Raises :class:`~mocap.plugins.PluginError` naming the tensors that differ.
    """
    try:
        saved = load_latent_state(Path(path))
    except (CheckpointError, KeyError):
        return
    mine = latent.state_dict()
    differ = []
    for key, value in saved["state_dict"].items():
        if not isinstance(value, Tensor):
            continue
        got = mine.get(key)
        if not isinstance(got, Tensor) or got.shape != value.shape or not torch.equal(got.detach().cpu().to(value.dtype), value.cpu()):
            differ.append(key)
    if differ:
        from mocap.plugins import PluginError

        raise PluginError(
            f"latent space {name!r}: its factory was given the checkpoint {path} but returned other weights "
            f"({', '.join(differ[:3])}{', ...' if len(differ) > 3 else ''}); a latent factory must load `checkpoint` (docs/plugins.md)"
        )


__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_NAME",
    "LATENT_FORMAT",
    "LATENT_NAME",
    "check_latent_loaded",
    "init_from_latent",
    "load_latent_state",
    "save_latent",
]
