"""Entry point of the ``pulse`` latent-space plugin (group ``mocap``: ``latent_pulse = "mocap_pulse.plugin"``)."""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap.plugins import lazy
from mocap_pulse.pulse_params import PulseParams


@hookimpl
def register_latent_spaces(register: Any) -> None:
    register(
        "pulse",
        lazy("mocap_pulse.latent:make_pulse"),
        params=PulseParams,
        description="PULSE: encoder E(z|s^p,s^g), decoder D(a|s^p,z), learned prior R(z|s^p); distilled online from an "
        "imitator (trainer: distill); tasks act with a residual z = mu_prior + z_task",
    )
