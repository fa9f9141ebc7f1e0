"""Actor-critic networks for PPO, and the policy file format other plugins load.

:class:`ActorCritic` holds two separate MLPs (actor and critic) on a shared observation
normalizer, plus the action head of the env's action space:

* :class:`~mocap.interfaces.Box`: a diagonal Gaussian ``N(μ(s), σ²)`` with a state-independent
  ``log σ`` (learned or fixed). Deterministic action = ``μ(s)``.
* :class:`~mocap.interfaces.MultiDiscrete`: one categorical per entry of ``nvec`` (one logits
  head each); the log-probability and entropy of a joint action are the sums over the heads.
  Deterministic action = the per-head argmax.

The critic may predict values in a normalized space (``normalize_value``); :meth:`ActorCritic.value`
and the values returned by :meth:`~ActorCritic.act` / :meth:`~ActorCritic.evaluate` are always in
reward units.

A trained policy is saved with :func:`save_policy` and rebuilt anywhere with :func:`load_policy`
from the configuration stored in the file (no params object needed)::

    policy = load_policy(path)            # ActorCritic, eval mode, on CPU
    action = policy.mean_action(obs)      # (N, A) or (N, M) long
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import torch
from torch import Tensor, nn

from mocap.checkpoint import CheckpointError, check_format, load_checkpoint, save_checkpoint
from mocap.interfaces import ActionSpace, Box, MultiDiscrete
from mocap.rl.normalizer import RunningNormalizer

POLICY_FORMAT = "mocap.rl.policy/1"

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "elu": nn.ELU,
    "relu": nn.ReLU,
    "tanh": nn.Tanh,
    "silu": nn.SiLU,
    "gelu": nn.GELU,
}

_LOG_SQRT_2PI = 0.5 * math.log(2 * math.pi)


def mlp(sizes: Sequence[int], activation: str = "elu", activate_last: bool = False) -> nn.Sequential:
    """``Linear(sizes[0], sizes[1]) → act → … → Linear(sizes[-2], sizes[-1])`` (+ act if ``activate_last``)."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {activation!r}; choose one of {sorted(ACTIVATIONS)}")
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2 or activate_last:
            layers.append(ACTIVATIONS[activation]())
    return nn.Sequential(*layers)


def _init_linear(layer: nn.Linear, gain: float) -> None:
    nn.init.orthogonal_(layer.weight, gain)
    nn.init.zeros_(layer.bias)


def space_to_dict(space: ActionSpace) -> dict[str, Any]:
    if isinstance(space, Box):
        return {"type": "box", "shape": list(space.shape), "low": space.low, "high": space.high}
    if isinstance(space, MultiDiscrete):
        return {"type": "multi_discrete", "nvec": list(space.nvec)}
    raise TypeError(f"unsupported action space {space!r}")


def space_from_dict(data: dict[str, Any]) -> ActionSpace:
    if data["type"] == "box":
        return Box(shape=tuple(data["shape"]), low=data["low"], high=data["high"])
    if data["type"] == "multi_discrete":
        return MultiDiscrete(nvec=tuple(data["nvec"]))
    raise ValueError(f"unknown action space type {data['type']!r}")


class TrainOutput(NamedTuple):
    """What the PPO loss needs from one forward pass over a minibatch."""

    log_prob: Tensor  # (B,) log π(a|s)
    entropy: Tensor  # (B,) entropy of π(·|s)
    value_raw: Tensor  # (B,) critic output (normalized space when normalize_value)
    mean: Tensor | None  # (B, A) Gaussian mean (None for multi-discrete heads)


class ActorCritic(nn.Module):
    """Separate actor and critic MLPs on a shared running observation normalizer.

    Args:
        obs_dim: observation size O.
        action_space: :class:`Box` (Gaussian head) or :class:`MultiDiscrete` (categorical heads).
        actor_hidden / critic_hidden: hidden layer sizes.
        activation: ``elu``, ``relu``, ``tanh``, ``silu`` or ``gelu``.
        log_std_init: initial (or fixed) ``log σ`` of the Gaussian head.
        learn_std: whether ``log σ`` is trained.
        normalize_obs: normalize observations with the running statistics of :attr:`obs_norm`.
        obs_clip: clip of the normalized observations.
        normalize_value: the critic predicts ``(V − μ_R) / σ_R`` with running return statistics
            :attr:`value_norm`; values returned to callers are de-normalized.
    """

    def __init__(
        self,
        obs_dim: int,
        action_space: ActionSpace,
        actor_hidden: Sequence[int] = (512, 256),
        critic_hidden: Sequence[int] = (512, 256),
        activation: str = "elu",
        log_std_init: float = -1.2,
        learn_std: bool = True,
        normalize_obs: bool = True,
        obs_clip: float | None = 5.0,
        normalize_value: bool = False,
    ):
        super().__init__()
        self.config: dict[str, Any] = {
            "obs_dim": int(obs_dim),
            "action_space": space_to_dict(action_space),
            "actor_hidden": [int(h) for h in actor_hidden],
            "critic_hidden": [int(h) for h in critic_hidden],
            "activation": activation,
            "log_std_init": float(log_std_init),
            "learn_std": bool(learn_std),
            "normalize_obs": bool(normalize_obs),
            "obs_clip": obs_clip,
            "normalize_value": bool(normalize_value),
        }
        self.obs_dim = int(obs_dim)
        self.action_space = action_space
        self.normalize_obs = normalize_obs
        self.normalize_value = normalize_value
        self.obs_norm = RunningNormalizer((obs_dim,), clip=obs_clip)
        self.value_norm = RunningNormalizer((), clip=None)

        gain = math.sqrt(2.0)
        self.actor_body = mlp([obs_dim, *actor_hidden], activation, activate_last=True)
        self.critic_body = mlp([obs_dim, *critic_hidden], activation, activate_last=True)
        for m in [*self.actor_body, *self.critic_body]:
            if isinstance(m, nn.Linear):
                _init_linear(m, gain)
        feat_a = actor_hidden[-1] if actor_hidden else obs_dim
        feat_c = critic_hidden[-1] if critic_hidden else obs_dim
        self.value_head = nn.Linear(feat_c, 1)
        _init_linear(self.value_head, 1.0)

        if isinstance(action_space, Box):
            if len(action_space.shape) != 1:
                raise ValueError(f"Box action spaces must be 1-D, got shape {action_space.shape}")
            self.action_dim = action_space.shape[0]
            self.action_head = nn.Linear(feat_a, self.action_dim)
            self.log_std: nn.Parameter | None = nn.Parameter(torch.full((self.action_dim,), float(log_std_init)), requires_grad=learn_std)
            self.nvec: tuple[int, ...] = ()
        elif isinstance(action_space, MultiDiscrete):
            self.nvec = tuple(int(n) for n in action_space.nvec)
            if not self.nvec or min(self.nvec) < 1:
                raise ValueError(f"MultiDiscrete needs at least one entry, each >= 1; got {self.nvec}")
            self.action_dim = len(self.nvec)
            self.action_head = nn.Linear(feat_a, sum(self.nvec))
            self.log_std = None
        else:
            raise TypeError(f"unsupported action space {action_space!r}")
        # small policy-head init: initial actions near 0 / near-uniform logits (CleanRL, Andrychowicz et al. 2021)
        _init_linear(self.action_head, 0.01)

    # ----------------------------------------------------------------------------- helpers
    @property
    def is_gaussian(self) -> bool:
        return isinstance(self.action_space, Box)

    def _norm_obs(self, obs: Tensor) -> Tensor:
        return self.obs_norm.normalize(obs) if self.normalize_obs else obs

    def _heads(self, x: Tensor) -> Tensor:
        """Gaussian mean (B, A) or concatenated logits (B, Σ nvec) from normalized obs."""
        return self.action_head(self.actor_body(x))

    def _value_raw(self, x: Tensor) -> Tensor:
        return self.value_head(self.critic_body(x)).squeeze(-1)

    def denormalize_value(self, value_raw: Tensor) -> Tensor:
        return self.value_norm.denormalize(value_raw) if self.normalize_value else value_raw

    def _split_logits(self, logits: Tensor) -> list[Tensor]:
        return [torch.log_softmax(chunk, dim=-1) for chunk in torch.split(logits, list(self.nvec), dim=-1)]

    def _log_prob_entropy(self, head: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        if self.is_gaussian:
            assert self.log_std is not None
            log_std = self.log_std.expand_as(head)
            # log N(a; μ, σ) = −(a−μ)²/(2σ²) − log σ − ½ log 2π, summed over dimensions
            logp = (-0.5 * ((action - head) / log_std.exp()).square() - log_std - _LOG_SQRT_2PI).sum(-1)
            # H = ½ + ½ log 2π + log σ per dimension
            ent = (0.5 + _LOG_SQRT_2PI + log_std).sum(-1)
            return logp, ent
        logps, ents = [], []
        for i, log_pi in enumerate(self._split_logits(head)):
            logps.append(log_pi.gather(-1, action[..., i : i + 1].long()).squeeze(-1))
            ents.append(-(log_pi.exp() * log_pi).sum(-1))
        return torch.stack(logps, -1).sum(-1), torch.stack(ents, -1).sum(-1)

    def _sample(self, head: Tensor, deterministic: bool) -> Tensor:
        if self.is_gaussian:
            assert self.log_std is not None
            if deterministic:
                return head
            return head + self.log_std.exp() * torch.randn_like(head)
        chunks = self._split_logits(head)
        if deterministic:
            return torch.stack([c.argmax(-1) for c in chunks], -1)
        return torch.stack([torch.multinomial(c.exp(), 1).squeeze(-1) for c in chunks], -1)

    # ------------------------------------------------------------------------------ public
    def act(self, obs: Tensor, deterministic: bool = False) -> tuple[Tensor, Tensor, Tensor]:
        """Sample (or take the mode of) π(·|s): ``(action, log_prob, value)``.

        ``action`` is (N, A) float for Box (unclipped; clip to the bounds before stepping) or
        (N, M) long for MultiDiscrete; ``log_prob`` (N,) is of that action; ``value`` (N,) in
        reward units.
        """
        x = self._norm_obs(obs)
        head = self._heads(x)
        action = self._sample(head, deterministic)
        logp, _ = self._log_prob_entropy(head, action)
        return action, logp, self.denormalize_value(self._value_raw(x))

    def evaluate(self, obs: Tensor, action: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(log π(a|s), entropy of π(·|s), V(s))`` for given actions, each (N,)."""
        out = self.train_forward(obs, action)
        return out.log_prob, out.entropy, self.denormalize_value(out.value_raw)

    def train_forward(self, obs: Tensor, action: Tensor) -> TrainOutput:
        """One pass for the PPO loss: log-prob, entropy, raw critic output and the Gaussian mean."""
        x = self._norm_obs(obs)
        head = self._heads(x)
        logp, ent = self._log_prob_entropy(head, action)
        return TrainOutput(logp, ent, self._value_raw(x), head if self.is_gaussian else None)

    def mean_action(self, obs: Tensor) -> Tensor:
        """The deterministic action: Gaussian mean (N, A), or per-head argmax (N, M) long."""
        return self._sample(self._heads(self._norm_obs(obs)), deterministic=True)

    def value(self, obs: Tensor) -> Tensor:
        """V(s) (N,) in reward units."""
        return self.denormalize_value(self._value_raw(self._norm_obs(obs)))

    def forward(self, obs: Tensor) -> Tensor:
        return self.mean_action(obs)

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> "ActorCritic":
        cfg = dict(config)
        cfg["action_space"] = space_from_dict(cfg["action_space"])
        return cls(**cfg)


def save_policy(path: Path, model: ActorCritic, extra: dict[str, Any] | None = None, *, spec_yaml: str | None = None) -> None:
    """Write ``model`` (config + weights + normalizers) atomically to ``path``.

    ``extra`` is any user data stored alongside (e.g. training stats); read it back from
    ``load_checkpoint(path)["extra"]``.
    """
    state = {k: v.detach().cpu() if isinstance(v, Tensor) else v for k, v in model.state_dict().items()}
    save_checkpoint(
        Path(path),
        {"format": POLICY_FORMAT, "config": model.config, "state_dict": state, "extra": extra or {}},
        spec_yaml=spec_yaml,
    )


def load_policy(path: Path, map_location: str | torch.device = "cpu") -> ActorCritic:
    """Rebuild the :class:`ActorCritic` saved by :func:`save_policy`, or the current policy inside a
    trainer's resumable checkpoint (PPO's ``ppo.pt``), in eval mode on ``map_location``."""
    from mocap.rl.policy_config import check_policy_config, check_state_dict

    data = load_checkpoint(Path(path), map_location=map_location)
    if data.get("format") == POLICY_FORMAT:
        config, state = data.get("config"), data.get("state_dict")
    elif "policy_config" in data and "model" in data:  # a trainer's resumable checkpoint (e.g. ppo.pt mid-training)
        config, state = data["policy_config"], data["model"]
    else:  # a CheckpointError: another file, or another version of the policy format (both versions named)
        check_format(Path(path), data, POLICY_FORMAT, what="policy")
        raise CheckpointError(f"{path}: not a policy file")  # pragma: no cover - check_format raised
    config = check_policy_config(Path(path), config)  # types, ranges and size before any allocation
    state = check_state_dict(Path(path), state)
    try:
        model = ActorCritic.from_config(config)
        model.load_state_dict(state)
    except (KeyError, TypeError, RuntimeError) as exc:
        raise CheckpointError(f"{path}: the policy's configuration and weights do not fit together (corrupt file? {type(exc).__name__}: {exc})") from None
    return model.to(map_location).eval()


def init_from_policy(model: ActorCritic, source: Path, log_std: float | None = None, repeat_tail: int | None = None) -> None:
    """Copy the weights and normalizers of the policy file ``source`` into ``model`` (a fresh network
    of the same architecture): PPO's ``init_policy`` (continue training a committed policy).

    ``log_std``: set the Gaussian head's ``log σ`` to this value instead of the source's (e.g. a
    fixed exploration σ). A policy of another architecture (observation or action size, hidden
    widths, normalizers) raises :class:`~mocap.checkpoint.CheckpointError` naming the tensors.

    ``repeat_tail``: ``model`` may take more observation dims than the source, appended at the end as
    repeats of the source's last ``repeat_tail`` dims (e.g. PHC's goal block with ``goal_frames`` > 1).
    The appended inputs get the source's normalizer statistics of the block they repeat and zero
    weights in the first layers, so the starting policy and value are exactly the source's.
    """
    source = Path(source)
    if not source.is_file():
        raise CheckpointError(f"{source}: init_policy does not exist")
    src = load_policy(source)
    state = src.state_dict()
    if repeat_tail is not None and src.obs_dim != model.obs_dim:
        state = _append_repeated_inputs(state, src.obs_dim, model.obs_dim, repeat_tail, source)
    got = {k: tuple(v.shape) for k, v in state.items() if isinstance(v, Tensor)}
    want = {k: tuple(v.shape) for k, v in model.state_dict().items() if isinstance(v, Tensor)}
    if got != want:
        bad = sorted(k for k in set(got) | set(want) if got.get(k) != want.get(k))[:3]
        raise CheckpointError(
            f"{source}: init_policy does not fit this network (observation {model.obs_dim}, actions {model.action_dim}); differing tensors: {', '.join(bad)}"
        )
    model.load_state_dict(state)
    if log_std is not None:
        if model.log_std is None:
            raise CheckpointError(f"{source}: init log σ given, but the network has no Gaussian head")
        with torch.no_grad():
            model.log_std.fill_(float(log_std))


def _append_repeated_inputs(state: dict[str, Any], old: int, new: int, tail: int, source: Path) -> dict[str, Any]:
    """``state`` widened from ``old`` to ``new`` observation dims (:func:`init_from_policy`'s ``repeat_tail``)."""
    extra = new - old
    if not (0 < tail <= old and extra > 0 and extra % tail == 0):
        raise CheckpointError(
            f"{source}: init_policy_repeat_tail {tail} cannot widen the policy's {old} observation dims to {new} "
            "(the new dims must be whole repeats of the last repeat_tail dims)"
        )
    reps = extra // tail
    out: dict[str, Any] = {}
    for key, value in state.items():
        if key in ("obs_norm.mean", "obs_norm.var"):
            out[key] = torch.cat([value, value[-tail:].repeat(reps)])
        elif isinstance(value, Tensor) and value.dim() == 2 and value.shape[1] == old:  # a first layer
            out[key] = torch.cat([value, value.new_zeros(value.shape[0], extra)], dim=1)
        else:
            out[key] = value
    return out


def export_policy(source: Path, destination: Path, extra: dict[str, Any] | None = None) -> None:
    """Write the policy inside ``source`` (a policy file or a trainer's resumable checkpoint such as
    ``ppo.pt``) as a self-contained policy file: network config, weights, normalizers and the spec
    that trained it — without the optimizer and rollout state (a few MB instead of ~3x that)."""
    data = load_checkpoint(Path(source))
    model = load_policy(Path(source))
    info: dict[str, Any] = {k: data[k] for k in ("iteration", "env_steps") if k in data}
    save_policy(Path(destination), model, extra={**info, **(extra or {})}, spec_yaml=data.get("spec"))


__all__ = ["ACTIVATIONS", "ActorCritic", "TrainOutput", "export_policy", "init_from_policy", "load_policy", "mlp", "save_policy"]
