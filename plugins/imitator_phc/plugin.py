"""Entry point of the ``phc`` imitator plugin (group ``mocap``: ``imitator_phc = "mocap_phc.plugin"``)."""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap_phc.imitator import PHCParams, make_phc
from mocap_phc.pmcp import PMCPParams, make_pmcp


@hookimpl
def register_imitators(register: Any) -> None:
    register(
        "phc",
        make_phc,
        params=PHCParams,
        description="PHC/PHC+ imitator: proprioception + next-frame imitation goal -> PD targets; "
        "RSI, relaxed early termination, hard-negative clip sampling (paper/code switches)",
    )


@hookimpl
def register_trainers(register: Any) -> None:
    register(
        "pmcp",
        make_pmcp,
        params=PMCPParams,
        description="PHC's PMCP in one stage: progressive primitives (each on the clips the previous one fails, until "
        "plateau), then a composer over the frozen primitives; writes pmcp.pt (a phc checkpoint) and pmcp.md",
    )
