"""Entry point of the ``vmp`` latent-space plugin (group ``mocap``: ``latent_vmp = "mocap_vmp.plugin"``)."""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap_vmp.latent import VmpParams, make_vmp
from mocap_vmp.trainer import SupervisedParams, SupervisedTrainer


@hookimpl
def register_latent_spaces(register: Any) -> None:
    register(
        "vmp",
        make_vmp,
        params=VmpParams,
        description="VMP stage I: 1-D conv beta-VAE over 2W+1-frame motion windows, prior N(0, I), per-frame latents "
        "(trainer: supervised); the tracking policy (stage II) is not built yet",
    )


@hookimpl
def register_trainers(register: Any) -> None:
    register(
        "supervised",
        SupervisedTrainer,
        params=SupervisedParams,
        description="VMP stage I: train the motion VAE on windows of the spec's motions (RAdam, SGDR, cyclical KL)",
    )
