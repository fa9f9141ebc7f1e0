"""PMCP's composite policy (:mod:`mocap_phc.pmcp`): the composer formulas (:func:`compose`), the frozen
primitives + composer as one policy (:class:`CompositePolicy`), the ``pmcp.pt`` payload helpers and
the imitator acting with a composite (:class:`CompositeImitator`, what ``make_phc`` builds from it)."""

from __future__ import annotations

from typing import Any, Sequence, cast

import torch
from torch import Tensor, nn

from mocap.rl.networks import ActorCritic
from mocap_phc.imitator import PHCImitator
from mocap_phc.pmcp_params import ComposerForm

PMCP_FORMAT = "mocap_phc.pmcp/1"


# ----------------------------------------------------------------------------- composer math
def compose(weights: Tensor, means: Tensor, form: ComposerForm, eps: float = 1e-6) -> Tensor:
    """Mix the primitives' means (N, K, A) with composer weights (N, K) into actions (N, A).

    * ``weighted_sum`` ([C]): ``a = sum_i relu(w_i) mu_i``;
    * ``multiplicative`` ([P], MCP with equal sigma): ``c_i = relu(w_i) + eps``,
      ``a = sum_i c_i mu_i / sum_i c_i`` (the mean of the means where ``sum_i c_i = 0``).
    """
    w = torch.relu(weights.to(means.dtype))
    if form == "weighted_sum":
        return (w.unsqueeze(-1) * means).sum(-2)
    if form == "multiplicative":
        c = w + eps
        total = c.sum(-1, keepdim=True)
        mixed = (c.unsqueeze(-1) * means).sum(-2) / total.clamp_min(torch.finfo(means.dtype).tiny)
        return torch.where(total > 0, mixed, means.mean(-2))
    raise ValueError(f"unknown composer form {form!r}; choose 'weighted_sum' or 'multiplicative'")


def composer_bias(init: float | Sequence[float] | None, k: int) -> Tensor:
    """The composer's initial output (its action head's bias) for ``k`` primitives: ``1/k`` each for
    None, ``init`` each for a number, or ``init`` itself for one value per primitive (a wrong count
    is a ValueError naming both)."""
    if init is None:
        return torch.full((k,), 1.0 / k)
    if isinstance(init, (int, float)):
        return torch.full((k,), float(init))
    values = [float(v) for v in init]
    if len(values) != k:
        raise ValueError(f"composer_init_weight has {len(values)} values for {k} primitives; give one per primitive (P(F) last) or one number")
    return torch.tensor(values)


class CompositePolicy(nn.Module):
    """Frozen primitives + composer as one policy on PHC's flat observation (``mean_action``/``act``).

    ``mean_action(obs)``: composer mean weights -> :func:`compose` of the primitives' means.
    ``act(obs)``: the same with weights sampled from the composer's Gaussian (the primitives stay
    deterministic, as in [C]). ``weights(obs)`` gives the composer's deterministic weights.
    """

    def __init__(self, primitives: Sequence[ActorCritic], composer: ActorCritic, form: ComposerForm, eps: float = 1e-6):
        super().__init__()
        if composer.action_dim != len(primitives):
            raise ValueError(f"the composer outputs {composer.action_dim} weights for {len(primitives)} primitives")
        self.primitives = nn.ModuleList(primitives)
        self.composer = composer
        self.form = form
        self.eps = float(eps)
        self.obs_dim = int(composer.obs_dim)
        for p in self.parameters():
            p.requires_grad_(False)
        self.eval()

    @property
    def obs_norm(self) -> Any:
        """The composer's observation normalizer (fit on every clip), for consumers of ``policy.obs_norm``
        such as PULSE's ``normalizer='teacher'``."""
        return self.composer.obs_norm

    def primitive_means(self, obs: Tensor) -> Tensor:
        """(N, K, A) the primitives' deterministic actions, each on its own normalized observation."""
        primitives = cast("Sequence[ActorCritic]", self.primitives)  # an nn.ModuleList iterates as plain Modules
        return torch.stack([p.mean_action(obs) for p in primitives], dim=-2)

    def weights(self, obs: Tensor) -> Tensor:
        return self.composer.mean_action(obs)

    @torch.no_grad()
    def mean_action(self, obs: Tensor) -> Tensor:
        return compose(self.weights(obs), self.primitive_means(obs), self.form, self.eps)

    @torch.no_grad()
    def act(self, obs: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        w, logp, value = self.composer.act(obs)
        return compose(w, self.primitive_means(obs), self.form, self.eps), logp, value

    def forward(self, obs: Tensor) -> Tensor:
        return self.mean_action(obs)


def _net(model: ActorCritic) -> dict[str, Any]:
    return {"config": model.config, "state_dict": {k: v.detach().cpu() if isinstance(v, Tensor) else v for k, v in model.state_dict().items()}}


def _unnet(data: dict[str, Any], device: Any) -> ActorCritic:
    model = ActorCritic.from_config(data["config"])
    model.load_state_dict(data["state_dict"])
    return model.to(device).eval()


# ------------------------------------------------------------------------------ the imitator
def is_pmcp_checkpoint(data: Any) -> bool:
    return isinstance(data, dict) and data.get("format") == PMCP_FORMAT


def composite_policy_from(data: dict[str, Any], device: Any = "cpu") -> CompositePolicy:
    """The :class:`CompositePolicy` stored in a ``pmcp.pt`` payload."""
    if not is_pmcp_checkpoint(data):
        raise ValueError(f"not a PMCP checkpoint (format {data.get('format')!r}, expected {PMCP_FORMAT!r})")
    prims = [_unnet(d, device) for d in data["primitives"]]
    return CompositePolicy(prims, _unnet(data["composer"], device), data["composer_form"], float(data["composer_eps"])).to(device)


class CompositeImitator(PHCImitator):
    """The PHC imitator acting with a PMCP composite (:class:`CompositePolicy`): ``observe``,
    ``policy_output`` (the mixed action, before the action map), ``to_pd_targets`` and ``act``
    exactly as for a single policy (:class:`~mocap_phc.env.PolicyImitator`)."""

    def __init__(self, params: Any, skeleton: Any, composite: CompositePolicy, device: Any = "cpu"):
        super().__init__(params, skeleton, composite, device)
        self.composite = composite

    @property
    def num_primitives(self) -> int:
        return len(self.composite.primitives)


def make_composite_imitator(params: Any, skeleton: Any, data: dict[str, Any], device: Any = "cpu") -> CompositeImitator:
    """``make_phc`` on a ``pmcp.pt`` payload."""
    composite = composite_policy_from(data, device)
    imitator = CompositeImitator(params, skeleton, composite, device)
    if composite.obs_dim != imitator.obs_dim:
        raise ValueError(
            f"the PMCP checkpoint takes {composite.obs_dim} observation dims, but phc with obs={params.obs!r} on "
            f"{skeleton.name!r} ({skeleton.num_bodies} bodies) produces {imitator.obs_dim}"
        )
    return imitator
