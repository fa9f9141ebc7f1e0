"""The ``distill`` plugin: registers the trainer ``distill``, online DAgger-style distillation of an
imitator into a latent space (:mod:`mocap.distill_trainer` documents the method; it is imported when a
spec builds the trainer, so that loading the plugin imports no torch).

The trainer's params and β schedule live in :mod:`mocap.distill_params`, the file names, formats,
:func:`~mocap.distill_files.save_latent` and :func:`~mocap.distill_files.load_latent_state` in
:mod:`mocap.distill_files`; those names, and the trainer's, are reachable from here too
(``mocap.distill.save_latent``, imported on first use).
"""

from __future__ import annotations

import importlib
from typing import Any

from mocap.distill_params import DistillParams, mixture_beta
from mocap.hooks import hookimpl
from mocap.plugins import lazy


# ---------------------------------------------------------------------------------- plugin hook
@hookimpl
def register_trainers(register):  # type: ignore[no-untyped-def]
    register(
        "distill",
        lazy("mocap.distill_trainer:DistillTrainer"),
        params=DistillParams,
        description="DAgger-style online distillation of the imitator into a DistillableLatent (student acts, teacher "
        "labels); hard-negative clips, periodic evaluation, exact resume; writes latent.pt",
    )


#: names defined in other modules, reachable from here too (imported on first use)
_MOVED = {
    **dict.fromkeys(("DistillError", "DistillTrainer", "EPISODE_WINDOW"), "mocap.distill_trainer"),
    **dict.fromkeys(("CHECKPOINT_FORMAT", "CHECKPOINT_NAME", "LATENT_FORMAT", "LATENT_NAME", "load_latent_state", "save_latent"), "mocap.distill_files"),
    "DistillEpisodes": "mocap.distill_episodes",
    "failure_weights": "mocap.hard_negatives",
    "PDTargetTeacher": "mocap.latent_imitator",
}


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DistillParams", "mixture_beta"]
