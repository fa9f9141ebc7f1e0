"""Entry point of the ``vmp`` latent-space plugin (group ``mocap``: ``latent_vmp = "mocap_vmp.plugin"``)."""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap.plugins import lazy
from mocap_vmp.tracking_params import VmpTrackerParams
from mocap_vmp.vmp_params import SupervisedParams, VmpParams, VmpTrackParams


@hookimpl
def register_latent_spaces(register: Any) -> None:
    register(
        "vmp",
        lazy("mocap_vmp.latent:make_vmp"),
        params=VmpParams,
        description="VMP stage I: 1-D conv beta-VAE over 2W+1-frame motion windows, prior N(0, I), per-frame latents "
        "(trainer: supervised), or with the trainer vmp_track also the latent-conditioned tracking policy (stage II)",
    )


@hookimpl
def register_imitators(register: Any) -> None:
    register(
        "vmp_tracker",
        lazy("mocap_vmp.tracking:make_vmp_tracker"),
        params=VmpTrackerParams,
        description="VMP stage II: tracking policy conditioned on the reference frame m_t and the VAE latent z_t "
        "(conditioning M, M5, M10, L, LM); trained by the latent stage's vmp_track trainer, loaded from its vmp.pt",
    )


@hookimpl
def register_trainers(register: Any) -> None:
    register(
        "supervised",
        lazy("mocap_vmp.trainer:SupervisedTrainer"),
        params=SupervisedParams,
        description="VMP stage I: train the motion VAE on windows of the spec's motions (RAdam, SGDR, cyclical KL)",
    )
    register(
        "vmp_track",
        lazy("mocap_vmp.track_trainer:VmpTrackTrainer"),
        params=VmpTrackParams,
        description="VMP stages I and II on the latent stage: the motion VAE (supervised), then the latent-conditioned "
        "tracking policy with PPO; writes vmp.pt (VAE + policy)",
    )
