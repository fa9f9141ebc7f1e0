"""Entry point of the ``hybrid_rvq`` latent-space plugin
(group ``mocap``: ``latent_hybrid_rvq = "mocap_hybrid_rvq.plugin"``)."""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap.plugins import lazy
from mocap_hybrid_rvq.hybrid_params import HybridParams


@hookimpl
def register_latent_spaces(register: Any) -> None:
    register(
        "hybrid_rvq",
        lazy("mocap_hybrid_rvq.model:make_hybrid"),
        params=HybridParams,
        description="Hybrid latent (Bae et al. 2025): deterministic prior z_p(s) + residual-VQ of the posterior margin "
        "(8 x 1024 codes, EMA, dead-code reset, quantizer dropout); task policies pick code indices of the first M "
        "codebooks. Baselines by `variant`: continuous, discrete, discrete_plus, hybrid_vq",
    )
