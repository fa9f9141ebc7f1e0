"""The network configuration a policy file carries, validated before any network is built.

A policy file's ``config`` decides what :class:`mocap.rl.networks.ActorCritic` allocates: a config
of ``obs_dim: 3e8`` or ``actor_hidden: [583, 1300000]`` would allocate gigabytes before the weights
were ever compared, and ``activation: "nosuch"`` or ``obs_dim: "abc"`` would end in a traceback. This
model checks types, ranges and the total size first (:func:`check_policy_config`), and
:func:`check_state_dict` checks the weights (a mapping of names to finite real tensors, no negative
normalizer variance).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from mocap.bounds import ACTIVATION_NAMES
from mocap.checkpoint import CheckpointError

#: the largest observation, action or hidden size a policy file may declare
MAX_POLICY_DIM = 100_000
#: the most parameters a policy file's network may have (the committed imitator has about 0.6M)
MAX_POLICY_PARAMETERS = 100_000_000

Dim = Annotated[int, Field(ge=1, le=MAX_POLICY_DIM)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Bound = Annotated[float, Field()]  # a Box bound: inf for unbounded


class BoxConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    type: Literal["box"]
    shape: list[Dim] = Field(min_length=1, max_length=4)
    low: Bound = float("-inf")
    high: Bound = float("inf")


class MultiDiscreteConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    type: Literal["multi_discrete"]
    nvec: list[Dim] = Field(min_length=1, max_length=1024)


class PolicyConfig(BaseModel):
    """What :meth:`mocap.rl.networks.ActorCritic.from_config` takes (``ActorCritic.config``)."""

    model_config = ConfigDict(extra="forbid")
    obs_dim: Dim
    action_space: BoxConfig | MultiDiscreteConfig = Field(discriminator="type")
    actor_hidden: list[Dim] = Field(default_factory=lambda: [512, 256], max_length=64)
    critic_hidden: list[Dim] = Field(default_factory=lambda: [512, 256], max_length=64)
    activation: Literal[ACTIVATION_NAMES] = "elu"  # type: ignore[valid-type]
    log_std_init: Finite = -1.2
    learn_std: bool = True
    normalize_obs: bool = True
    obs_clip: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = 5.0
    normalize_value: bool = False

    @model_validator(mode="after")
    def _size(self) -> "PolicyConfig":
        space = self.action_space
        out = (sum(space.nvec) if isinstance(space, MultiDiscreteConfig) else int(torch.Size(space.shape).numel())) or 1
        total = 0
        for hidden, last in ((self.actor_hidden, out), (self.critic_hidden, 1)):
            widths = [self.obs_dim, *hidden, last]
            total += sum(a * b + b for a, b in zip(widths, widths[1:]))
        if total > MAX_POLICY_PARAMETERS:
            raise ValueError(f"the network would have {total:,} parameters, more than {MAX_POLICY_PARAMETERS:,}")
        return self


def check_policy_config(path: Path, config: Any) -> dict[str, Any]:
    """``config`` validated (:class:`PolicyConfig`), as the dict ``ActorCritic.from_config`` takes;
    a :class:`CheckpointError` naming ``path`` and the first bad field otherwise."""
    if not isinstance(config, dict):
        raise CheckpointError(f"{path}: the policy's config is a {type(config).__name__}, not a mapping (corrupt file?)")
    try:
        checked = PolicyConfig.model_validate(config)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(part) for part in err["loc"]) or "config"
        got = repr(err.get("input"))[:80]
        more = f" (and {len(exc.errors()) - 1} more)" if len(exc.errors()) > 1 else ""
        raise CheckpointError(f"{path}: the policy's config.{where}: {err['msg']} (got {got}){more}; corrupt or hand-edited file?") from None
    return checked.model_dump()


def check_state_dict(path: Path, state: Any) -> dict[str, torch.Tensor]:
    """The weights of a policy file: a mapping of parameter names (str) to tensors, else a
    :class:`CheckpointError` naming ``path``."""
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: the policy's weights (state_dict) are a {type(state).__name__}, not a mapping of tensors (corrupt file?)")
    for key, value in state.items():  # a module's ``_extra_state`` (the normalizers' settings) may be plain data
        if not isinstance(key, str) or not (isinstance(value, torch.Tensor) or key.endswith("_extra_state")):
            raise CheckpointError(f"{path}: the policy's weights hold {str(key)[:60]!r}: {type(value).__name__}, not a named tensor (corrupt file?)")
        if isinstance(value, torch.Tensor):
            _check_values(path, key, value)
    return state


def _check_values(path: Path, key: str, value: torch.Tensor) -> None:
    """One weight tensor: real floating-point numbers (no bool, integer or complex), all finite, and a
    normalizer's variance (``*_norm.var``) not negative; a :class:`CheckpointError` naming ``path``
    and ``key`` otherwise."""
    if not value.dtype.is_floating_point:
        raise CheckpointError(f"{path}: the policy's weight {key[:60]!r} holds {value.dtype} values, not real numbers (corrupt or hand-edited file?)")
    if not bool(torch.isfinite(value).all()):
        raise CheckpointError(
            f"{path}: the policy's weight {key[:60]!r} holds NaN or infinite values (a diverged run, or a corrupt file); use an earlier checkpoint"
        )
    if key.endswith("_norm.var") and bool((value < 0).any()):
        raise CheckpointError(f"{path}: the policy's normalizer variance {key[:60]!r} is negative (corrupt or hand-edited file?)")


__all__ = ["MAX_POLICY_DIM", "MAX_POLICY_PARAMETERS", "PolicyConfig", "check_policy_config", "check_state_dict"]
