"""The vectorized environment protocol that PPO trains on.

Any stage component trainable by RL (an imitator, a task driven through a latent space) provides
``make_env(ctx, num_envs) -> VecEnv``. The env owns its simulator and everything the problem
needs (motion library, goals, rewards, terminations) and resets finished envs itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from torch import Tensor

from mocap.interfaces import ActionSpace


@dataclass
class StepResult:
    """One batched transition.

    Attributes:
        obs: (N, O) observation after the step; for envs that finished this step it is already
            the first observation of their next episode (auto-reset).
        reward: (N,) reward of the transition.
        terminated: (N,) bool, the episode ended by failure/success (no bootstrapping).
        truncated: (N,) bool, the episode hit its time limit (bootstrap from ``final_obs``).
        final_obs: (N, O) observation reached by the step before any auto-reset (equal to
            ``obs`` for envs that did not finish); PPO bootstraps truncated episodes from it.
        info: scalars or (N,) tensors to log (reward terms, ...).
        episodes: finished-episode statistics: name -> (K,) tensor over the K envs that
            finished this step (``return``, ``length`` and e.g. ``success``).
    """

    obs: Tensor
    reward: Tensor
    terminated: Tensor
    truncated: Tensor
    final_obs: Tensor
    info: dict[str, Any] = field(default_factory=dict)
    episodes: dict[str, Tensor] = field(default_factory=dict)


@runtime_checkable
class VecEnv(Protocol):
    num_envs: int
    obs_dim: int
    action_space: ActionSpace

    def reset(self) -> Tensor:
        """Reset every env; return the (N, O) observations."""

    def step(self, actions: Tensor) -> StepResult:
        """Apply (N, A) actions (or (N, M) long indices for multi-discrete spaces)."""

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue exactly (RNG states, episode counters, sampling weights)."""

    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    def close(self) -> None: ...


@runtime_checkable
class AfterIteration(Protocol):
    """Optional VecEnv capability: PPO calls ``after_iteration`` after every iteration with the
    deterministic policy (obs -> action); the env uses it for periodic evaluation (hard-negative
    mining, task metrics) and returns scalars that PPO logs under ``eval/``."""

    def after_iteration(self, iteration: int, policy_fn: Any) -> dict[str, float]: ...


@runtime_checkable
class OnDevice(Protocol):
    """Optional VecEnv capability: the env takes its actions on ``device`` (default: the CPU)."""

    device: Any
