"""One PMCP phase as a PPO run (:mod:`mocap_phc.pmcp`): the training envs of a primitive
(:class:`PrimitiveEnv`, with its plateau tracker) and of the composer (:class:`ComposerEnv`). The
phase itself is a plain :class:`~mocap.rl.ppo.PPOTrainer` (``init_model`` seeds its fresh weights) run
on a child context (:meth:`mocap.pipeline.StageContext.phase`) with the phase's own directory and log stage."""

from __future__ import annotations

from typing import Any, Callable, Sequence

import torch
from torch import Tensor

from mocap.interfaces import Box
from mocap.rl.env import StepResult
from mocap.rl.networks import ActorCritic
from mocap_phc.pmcp_composite import compose
from mocap_phc.pmcp_params import ComposerForm
from mocap_phc.pmcp_rules import PlateauTracker


# -------------------------------------------------------------------------------- the envs
class PrimitiveEnv:
    """A primitive's training env: an :class:`~mocap_phc.env.ImitationEnv` whose ``after_iteration``
    also feeds a :class:`PlateauTracker` every ``eval_every`` iterations; the tracker travels in
    ``state_dict``. ``done`` turns True once the primitive should be frozen."""

    def __init__(self, inner: Any, eval_every: int, patience: int, stop_on_success: bool):
        self.inner = inner
        self.num_envs = inner.num_envs
        self.obs_dim = inner.obs_dim
        self.action_space = inner.action_space
        self.device = getattr(inner, "device", torch.device("cpu"))
        self.eval_every = int(eval_every)
        self.stop_on_success = bool(stop_on_success)
        self.tracker = PlateauTracker(patience, inner.library.num_clips)

    @property
    def done(self) -> bool:
        return self.tracker.plateaued or (self.stop_on_success and self.tracker.all_success)

    def reset(self) -> Tensor:
        return self.inner.reset()

    def step(self, actions: Tensor) -> StepResult:
        return self.inner.step(actions)

    def after_iteration(self, iteration: int, policy_fn: Callable[[Tensor], Tensor]) -> dict[str, float]:
        before = self.inner.last_evaluation
        out = dict(self.inner.after_iteration(iteration, policy_fn) or {})
        if iteration > 0 and iteration % self.eval_every == 0:
            res = self.inner.last_evaluation
            if res is None or res is before:  # the env did not evaluate on this iteration
                res = self.inner.evaluate_clips(policy_fn)
            names = self.inner.library.clip_names
            improved = self.tracker.update(iteration, [res["clips"][n]["success"] for n in names])
            out.update(
                {
                    "pmcp/success_rate": res["success_rate"],
                    "pmcp/improved": float(improved),
                    "pmcp/stale_evals": float(self.tracker.stale),
                }
            )
        return out

    def state_dict(self) -> dict[str, Any]:
        return {"inner": self.inner.state_dict(), "plateau": self.tracker.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.inner.load_state_dict(state["inner"])
        self.tracker.load_state_dict(state["plateau"])

    def close(self) -> None:
        self.inner.close()


class ComposerEnv:
    """The composer's VecEnv: same observations as the wrapped ``ImitationEnv``; the action is the
    composer's weight vector (K,), mapped to the imitation action by :func:`compose` of the frozen
    primitives' deterministic means on the current observation."""

    def __init__(self, inner: Any, primitives: Sequence[ActorCritic], form: ComposerForm, eps: float = 1e-6):
        self.inner = inner
        self.num_envs = inner.num_envs
        self.obs_dim = inner.obs_dim
        self.device = getattr(inner, "device", torch.device("cpu"))
        self.primitives = [p.eval() for p in primitives]
        for p in self.primitives:
            for q in p.parameters():
                q.requires_grad_(False)
        self.form = form
        self.eps = float(eps)
        self.num_primitives = K = len(self.primitives)
        self.action_space = Box((K,))

    def means(self, obs: Tensor) -> Tensor:
        with torch.no_grad():
            return torch.stack([p.mean_action(obs.float()) for p in self.primitives], dim=-2)

    def to_action(self, obs: Tensor, weights: Tensor) -> Tensor:
        return compose(torch.as_tensor(weights).to(obs.device).float(), self.means(obs), self.form, self.eps)

    def reset(self) -> Tensor:
        return self.inner.reset()

    def step(self, weights: Tensor) -> StepResult:
        obs = self.inner.current_obs()
        res = self.inner.step(self.to_action(obs, weights))
        w = torch.relu(torch.as_tensor(weights).float())
        for i in range(self.num_primitives):
            res.info[f"composer/w{i}"] = w[:, i]
        return res

    def after_iteration(self, iteration: int, policy_fn: Callable[[Tensor], Tensor]) -> dict[str, float]:
        def composite(obs: Tensor) -> Tensor:
            return self.to_action(obs, policy_fn(obs))

        return self.inner.after_iteration(iteration, composite)

    def state_dict(self) -> dict[str, Any]:
        return self.inner.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.inner.load_state_dict(state)

    def close(self) -> None:
        self.inner.close()
