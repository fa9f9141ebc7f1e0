"""PPO properties pinned through the trainer itself, not only through the pure functions.

* Truncation bootstrapping (Pardo et al. 2018, "Time limits in reinforcement learning"; the
  :class:`~mocap.rl.env.StepResult` contract): at a step that hit the time limit the next value
  fed to GAE is V(final_obs), the state the step reached, never V(reset obs); at a terminated step
  the next value does not enter the advantages.
* Advantage standardization (the PPO implementations' ``(A − mean) / (std + ε)``): the update is
  invariant to adding a constant to every advantage, and a batch of exactly equal advantages
  (std 0) still gives a finite update thanks to ε.
* Value normalization (PHC's rl_games recipe, ``normalize_value: true``): the critic regresses the
  *normalized* return, a target of order 1 whatever the scale of the returns.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest
import torch
from test_ppo import FakeContext, small_params

import mocap.rl.ppo as ppo_module
from mocap.interfaces import Box
from mocap.rl.env import StepResult
from mocap.rl.networks import ActorCritic
from mocap.rl.ppo import PPOParams, PPOTrainer

torch.set_num_threads(1)


# ------------------------------------------------------------------- truncation bootstrapping
class ScheduledEnv:
    """Episodes of a fixed schedule: even envs are truncated after 5 steps, odd envs terminate
    after 3. obs = (t / 5, id marker): the state a step reached (``final_obs``, t = episode length)
    and the next episode's first observation (t = 0) differ, so do their values."""

    def __init__(self, num_envs: int) -> None:
        self.num_envs, self.obs_dim = num_envs, 2
        self.action_space = Box((1,), -1.0, 1.0)
        self.t = torch.zeros(num_envs)
        self.marker = torch.linspace(-1.0, 1.0, num_envs)
        self.length = torch.where(torch.arange(num_envs) % 2 == 0, 5.0, 3.0)
        self.records: list[dict[str, torch.Tensor]] = []

    def _obs(self) -> torch.Tensor:
        return torch.stack([self.t / 5.0, self.marker], -1)

    def reset(self) -> torch.Tensor:
        self.t.zero_()
        return self._obs()

    def step(self, actions: torch.Tensor) -> StepResult:
        self.t += 1
        ended = self.t >= self.length
        odd = torch.arange(self.num_envs) % 2 == 1
        terminated, truncated = ended & odd, ended & ~odd
        final_obs = self._obs()
        reward = actions[:, 0].clamp(-1, 1) + self.t
        self.t[ended] = 0.0
        obs = self._obs()
        self.records.append({"obs": obs.clone(), "final_obs": final_obs.clone(), "terminated": terminated, "truncated": truncated})
        return StepResult(obs, reward, terminated, truncated, final_obs)

    def state_dict(self) -> dict[str, Any]:
        return {"t": self.t.clone()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.t = state["t"].clone()

    def close(self) -> None:
        pass


def test_gae_gets_v_of_final_obs_at_truncations_and_ignores_terminations(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A spy on ``compute_gae``'s inputs over one rollout of 10 steps: truncations at t = 4 (inside
    the rollout) and t = 9 (its last step), terminations at t = 2, 5, 8."""
    T, N = 10, 4
    env = ScheduledEnv(N)
    models: list[ActorCritic] = []
    calls: list[dict[str, torch.Tensor]] = []
    build = PPOTrainer.build_model
    real_gae = ppo_module.compute_gae

    def build_spy(self: PPOTrainer, obs_dim: int, space: Any) -> ActorCritic:
        models.append(build(self, obs_dim, space))
        return models[-1]

    def gae_spy(rewards, values, next_values, terminated, dones, gamma, lam):  # type: ignore[no-untyped-def]
        with torch.no_grad():  # the rollout's weights: the update comes after GAE
            v_final = torch.stack([models[0].value(r["final_obs"]) for r in env.records])
            v_next = torch.stack([models[0].value(r["obs"]) for r in env.records])  # after auto-reset
        seen = {"values": values, "next_values": next_values, "terminated": terminated, "dones": dones}
        calls.append({**{k: v.clone() for k, v in seen.items()}, "v_final": v_final, "v_next": v_next})
        return real_gae(rewards, values, next_values, terminated, dones, gamma, lam)

    monkeypatch.setattr(PPOTrainer, "build_model", build_spy)
    monkeypatch.setattr(ppo_module, "compute_gae", gae_spy)
    params = small_params(num_envs=N, horizon=T, total_env_steps=T * N, minibatch_size=N * T, epochs=1, normalize_obs=False)
    PPOTrainer(params).run(FakeContext(tmp_path, lambda n: env))
    assert len(calls) == 1 and len(env.records) == T
    call = calls[0]
    v_final, v_next = call["v_final"], call["v_next"]
    trunc = torch.stack([r["truncated"] for r in env.records])
    term = torch.stack([r["terminated"] for r in env.records])
    assert bool(trunc[4].any()) and bool(trunc[T - 1].any()) and bool(term.any())
    assert bool((v_final[trunc] - v_next[trunc]).abs().min() > 1e-4), "the test needs V(final_obs) != V(reset obs)"
    # truncated: V(final_obs), not the reset observation's value
    torch.testing.assert_close(call["next_values"][trunc], v_final[trunc])
    # not finished: V(s_{t+1}), the observation the next step starts from
    live = ~(trunc | term)
    torch.testing.assert_close(call["next_values"][live], v_next[live])
    assert torch.equal(call["terminated"], term) and torch.equal(call["dones"], term | trunc)
    # terminated: whatever sits there does not change the advantages
    garbage = call["next_values"].clone()
    garbage[term] = 1e6
    rewards = torch.zeros(T, N)
    a, _ = real_gae(rewards, call["values"], call["next_values"], term, term | trunc, 0.9, 0.95)
    b, _ = real_gae(rewards, call["values"], garbage, term, term | trunc, 0.9, 0.95)
    torch.testing.assert_close(a, b, rtol=0, atol=0)


# -------------------------------------------------------------------- advantage standardization
def _batch(seed: int, T: int = 8, N: int = 8, obs_dim: int = 5, act_dim: int = 2) -> tuple[PPOTrainer, ActorCritic, dict[str, torch.Tensor]]:
    torch.manual_seed(seed)
    trainer = PPOTrainer(PPOParams(num_envs=N, horizon=T, minibatch_size=16, epochs=2, torch_threads=1, normalize_obs=False))
    model = trainer.build_model(obs_dim, Box((act_dim,)))
    obs = torch.randn(T, N, obs_dim)
    with torch.no_grad():
        act, logp, val = model.act(obs.reshape(T * N, obs_dim))
    data = {"obs": obs, "act": act.reshape(T, N, act_dim), "logp": logp.reshape(T, N), "val": val.reshape(T, N)}
    return trainer, model, data


Batch = dict[str, torch.Tensor]


def _update(trainer: PPOTrainer, model: ActorCritic, data: Batch, adv: torch.Tensor, ret: torch.Tensor, seed: int) -> tuple[ActorCritic, dict[str, float]]:
    model = copy.deepcopy(model)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    torch.manual_seed(seed)  # the same minibatch permutation
    stats = trainer._update(model, opt, data["obs"], data["act"], data["logp"], data["val"], adv, ret)
    return model, stats


@pytest.mark.parametrize("shift", [-5.0, 0.5, 20.0])
def test_update_is_invariant_to_a_constant_added_to_every_advantage(shift: float) -> None:
    trainer, model, data = _batch(0)
    adv = torch.randn(8, 8, generator=torch.Generator().manual_seed(1))
    ret = data["val"] + adv  # the same value targets in both updates
    a, _ = _update(trainer, model, data, adv, ret, seed=3)
    b, _ = _update(trainer, model, data, adv + shift, ret, seed=3)
    moved = max(float((p - q).detach().abs().max()) for p, q in zip(a.parameters(), model.parameters()))
    assert moved > 1e-4  # the update did something
    for p, q in zip(a.parameters(), b.parameters()):
        torch.testing.assert_close(p, q, rtol=0, atol=2e-6)


def test_equal_advantages_still_update_and_report_finite_stats() -> None:
    """All advantages exactly 1.0: their float32 std is exactly 0, so only ε keeps the standardized
    advantages finite (0 / ε = 0); without it every minibatch is NaN and skipped."""
    trainer, model, data = _batch(0)
    adv = torch.ones(8, 8)
    assert float(adv.reshape(-1).std()) == 0.0
    new, stats = _update(trainer, model, data, adv, data["val"] + 1.0, seed=3)
    for key in ("loss/policy", "loss/value", "loss/total", "approx_kl", "grad_norm"):
        assert key in stats and math.isfinite(stats[key]), (key, stats)
    assert all(bool(torch.isfinite(p).all()) for p in new.parameters())
    assert max(float((p - q).detach().abs().max()) for p, q in zip(new.parameters(), model.parameters())) > 1e-5


# -------------------------------------------------------------------------- value normalization
def test_critic_regresses_the_normalized_return(monkeypatch: pytest.MonkeyPatch) -> None:
    """Returns near 100 with ``normalize_value``: the value-loss target is the standardized return
    (mean about 0, std about 1) and the prediction it is compared with is the raw critic output."""
    torch.manual_seed(0)
    T, N = 8, 8
    trainer = PPOTrainer(PPOParams(num_envs=N, horizon=T, minibatch_size=64, epochs=1, torch_threads=1, normalize_value=True, normalize_obs=False))
    model = trainer.build_model(5, Box((2,)))
    obs = torch.randn(T, N, 5)
    with torch.no_grad():
        act, logp, val = model.act(obs.reshape(T * N, 5))
    ret = 100.0 + 5.0 * torch.randn(T, N, generator=torch.Generator().manual_seed(2))
    targets: list[torch.Tensor] = []
    real = ppo_module.value_loss

    def spy(values, old_values, returns, clip=None):  # type: ignore[no-untyped-def]
        targets.append(returns.detach().clone())
        return real(values, old_values, returns, clip)

    monkeypatch.setattr(ppo_module, "value_loss", spy)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    trainer._update(model, opt, obs, act.reshape(T, N, 2), logp.reshape(T, N), val.reshape(T, N), ret - val.reshape(T, N), ret)
    target = torch.cat(targets)
    assert abs(float(target.mean())) < 0.5 and 0.5 < float(target.std()) < 2.0, (float(target.mean()), float(target.std()))
    torch.testing.assert_close(target.sort().values, model.value_norm.normalize(ret.reshape(-1)).sort().values)
