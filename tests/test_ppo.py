"""PPO: the loss math (property tests), normalizer, action heads, learning on toy envs, exact resume."""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console

from mocap.checkpoint import load_checkpoint
from mocap.hooks import hookimpl
from mocap.interfaces import Box, MultiDiscrete
from mocap.rl.env import StepResult, VecEnv
from mocap.rl.networks import ActorCritic, load_policy, save_policy
from mocap.rl.normalizer import RunningNormalizer
from mocap.rl.ppo import PPOParams, PPOTrainer, adapt_lr, bounds_loss, clipped_surrogate, compute_gae, value_loss
from mocap.runlog import MetricsLogger

torch.set_num_threads(1)


def assert_close(a: torch.Tensor, b: torch.Tensor, rtol: float = 1e-5, atol: float = 1e-6) -> None:
    """``torch.allclose`` with a message (torch.testing.assert_close costs seconds on first use)."""
    assert a.shape == b.shape and torch.allclose(a, b, rtol=rtol, atol=atol), (a, b)


# ------------------------------------------------------------------------------------ toy envs
class PointEnv:
    """A 1-D point that must move to a target. obs = (position, target); reward = −|error|.

    Continuous: action = velocity in [−1, 1] (scaled by 0.2). Multi-discrete: (direction ∈ {−1, 0, 1},
    speed ∈ {0.1, 0.2}). Episodes are truncated after ``max_steps``; leaving |position| ≤ 2 is a
    failure (termination, reward −10).
    """

    def __init__(self, num_envs: int, seed: int = 0, max_steps: int = 20, discrete: bool = False):
        self.num_envs = num_envs
        self.obs_dim = 2
        self.discrete = discrete
        self.action_space = MultiDiscrete((3, 2)) if discrete else Box((1,), -1.0, 1.0)
        self.max_steps = max_steps
        self.gen = torch.Generator().manual_seed(seed)
        self.pos = torch.zeros(num_envs)
        self.target = torch.zeros(num_envs)
        self.t = torch.zeros(num_envs, dtype=torch.long)
        self.ret = torch.zeros(num_envs)

    def _obs(self) -> torch.Tensor:
        return torch.stack([self.pos, self.target], -1)

    def _reset(self, mask: torch.Tensor) -> None:
        n = int(mask.sum())
        self.pos[mask] = torch.rand(n, generator=self.gen) * 2 - 1
        self.target[mask] = torch.rand(n, generator=self.gen) * 2 - 1
        self.t[mask] = 0
        self.ret[mask] = 0

    def reset(self) -> torch.Tensor:
        self._reset(torch.ones(self.num_envs, dtype=torch.bool))
        return self._obs()

    def step(self, actions: torch.Tensor) -> StepResult:
        if self.discrete:
            vel = (actions[:, 0].float() - 1) * (0.1 + 0.1 * actions[:, 1].float())
        else:
            vel = actions[:, 0].clamp(-1, 1) * 0.2
        self.pos = self.pos + vel
        self.t += 1
        err = (self.pos - self.target).abs()
        terminated = self.pos.abs() > 2
        reward = torch.where(terminated, torch.full_like(err, -10.0), -err)
        truncated = (self.t >= self.max_steps) & ~terminated
        self.ret += reward
        final_obs = self._obs()
        done = terminated | truncated
        episodes = {}
        if done.any():
            episodes = {"return": self.ret[done].clone(), "length": self.t[done].float(), "success": (err[done] < 0.1).float()}
            self._reset(done)
        return StepResult(self._obs(), reward, terminated, truncated, final_obs, {"error": err.mean()}, episodes)

    def state_dict(self) -> dict[str, Any]:
        return {"gen": self.gen.get_state(), **{k: getattr(self, k).clone() for k in ("pos", "target", "t", "ret")}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.gen.set_state(state["gen"])
        for k in ("pos", "target", "t", "ret"):
            setattr(self, k, state[k].clone())

    def close(self) -> None:
        pass


@dataclass
class FakeContext:
    """The part of :class:`mocap.pipeline.StageContext` a trainer uses."""

    workdir: Path
    make_env: Callable[[int], Any]
    seed: int = 0
    stop_after: int | None = None  # should_stop() turns True on this call (a simulated Ctrl-C)
    device: torch.device = torch.device("cpu")
    console: Console = field(default_factory=lambda: Console(file=io.StringIO()))
    calls: int = 0

    def __post_init__(self) -> None:
        self.log = MetricsLogger(self.workdir / "metrics.jsonl", "task")

    def make_rl_env(self, num_envs: int) -> Any:
        return self.make_env(num_envs)

    def should_stop(self) -> bool:
        self.calls += 1
        return self.stop_after is not None and self.calls >= self.stop_after

    def spec_yaml(self) -> str:
        return "name: toy\n"


def small_params(**kw: Any) -> PPOParams:
    base = dict(
        num_envs=32,
        horizon=32,
        total_env_steps=32 * 32 * 15,
        epochs=4,
        minibatch_size=256,
        lr=3e-3,
        gamma=0.9,
        actor_hidden=[32, 32],
        critic_hidden=[32, 32],
        activation="tanh",
        log_std_init=-0.5,
        checkpoint_every=5,
    )
    base.update(kw)
    return PPOParams(**base)


def episode_returns(workdir: Path) -> list[float]:
    lines = [json.loads(line) for line in (workdir / "metrics.jsonl").read_text().splitlines()]
    return [r["episode/return"] for r in lines]


# ------------------------------------------------------------------------------------------ GAE
def gae_closed_form(r, v, nv, term, done, gamma, lam):
    """A_t = Σ_{l=0}^{k} (γλ)^l δ_{t+l}, k = first episode end at or after t (or the rollout end)."""
    T, N = r.shape
    delta = r + gamma * (1 - term) * nv - v
    adv = np.zeros_like(r)
    for n in range(N):
        for t in range(T):
            total, l = 0.0, 0
            while t + l < T:
                total += (gamma * lam) ** l * delta[t + l, n]
                if done[t + l, n]:
                    break
                l += 1
            adv[t, n] = total
    return adv


@st.composite
def rollouts(draw, consistent: bool = False):
    """Random (T, N) rollouts. ``consistent``: next_values[t] = values[t+1] unless the episode ended."""
    T = draw(st.integers(1, 8))
    N = draw(st.integers(1, 3))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    r = rng.normal(size=(T, N))
    v = rng.normal(size=(T, N))
    nv = rng.normal(size=(T, N))
    term = rng.random((T, N)) < 0.2
    trunc = (rng.random((T, N)) < 0.2) & ~term
    done = term | trunc
    if consistent:
        nv[:-1] = np.where(done[:-1], nv[:-1], v[1:])
    return r, v, nv, term.astype(float), done.astype(float)


def _gae(r, v, nv, term, done, gamma, lam):
    t = [torch.as_tensor(a, dtype=torch.float64) for a in (r, v, nv)]
    adv, ret = compute_gae(*t, torch.as_tensor(term).bool(), torch.as_tensor(done).bool(), gamma, lam)
    return adv.numpy(), ret.numpy()


@settings(max_examples=60, deadline=None)
@given(rollouts(), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_gae_equals_closed_form_truncated_at_episode_ends(data, gamma, lam):
    r, v, nv, term, done = data
    adv, ret = _gae(r, v, nv, term, done, gamma, lam)
    np.testing.assert_allclose(adv, gae_closed_form(r, v, nv, term, done, gamma, lam), atol=1e-9)
    np.testing.assert_allclose(ret, adv + v, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(rollouts(consistent=True), st.floats(0.0, 1.0))
def test_gae_lambda_one_is_monte_carlo_return_minus_value(data, gamma):
    r, v, nv, term, done = data
    adv, _ = _gae(r, v, nv, term, done, gamma, 1.0)
    T, N = r.shape
    for n in range(N):
        for t in range(T):
            # G_t = Σ_l γ^l r_{t+l} + γ^{k+1} (1 − term) V(s'_{t+k}) up to the episode/rollout end t+k
            g, l = 0.0, 0
            while True:
                g += gamma**l * r[t + l, n]
                if done[t + l, n] or t + l == T - 1:
                    g += gamma ** (l + 1) * (1 - term[t + l, n]) * nv[t + l, n]
                    break
                l += 1
            assert adv[t, n] == pytest.approx(g - v[t, n], abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(rollouts(), st.floats(0.0, 1.0))
def test_gae_lambda_zero_is_td_residual(data, gamma):
    r, v, nv, term, done = data
    adv, _ = _gae(r, v, nv, term, done, gamma, 0.0)
    np.testing.assert_allclose(adv, r + gamma * (1 - term) * nv - v, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(rollouts(), st.floats(0.1, 1.0), st.floats(0.0, 1.0))
def test_gae_bootstraps_truncations_not_terminations(data, gamma, lam):
    r, v, nv, term, done = data
    adv, _ = _gae(r, v, nv, term, done, gamma, lam)
    trunc = (done > 0) & (term == 0)
    bumped = nv + 1.0 * (done > 0)  # change V(final_obs) of every finished episode
    adv2, _ = _gae(r, v, bumped, term, done, gamma, lam)
    # terminated steps ignore V(final_obs); a truncated step's advantage moves by exactly γ
    np.testing.assert_allclose(adv2[term > 0], adv[term > 0], atol=1e-12)
    np.testing.assert_allclose(adv2[trunc] - adv[trunc], gamma, atol=1e-9)


def test_gae_on_a_hand_computed_example():
    # one env, 3 steps; the episode is truncated at t=1 (bootstrap from V(final)=10), then terminates at t=2
    r = torch.tensor([[1.0], [2.0], [3.0]], dtype=torch.float64)
    v = torch.tensor([[0.5], [0.25], [4.0]], dtype=torch.float64)
    nv = torch.tensor([[0.25], [10.0], [99.0]], dtype=torch.float64)
    term = torch.tensor([[False], [False], [True]])
    done = torch.tensor([[False], [True], [True]])
    adv, _ = compute_gae(r, v, nv, term, done, gamma=0.5, lam=0.5)
    d0, d1, d2 = 1 + 0.5 * 0.25 - 0.5, 2 + 0.5 * 10 - 0.25, 3 - 4.0
    assert_close(adv.flatten(), torch.tensor([d0 + 0.25 * d1, d1, d2], dtype=torch.float64))


# ------------------------------------------------------------------------------- other losses
@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.0, 5.0), min_size=1, max_size=20), st.floats(1e-3, 10.0), st.floats(0.05, 0.5))
def test_clipped_surrogate_is_a_pessimistic_bound(ratios, adv, eps):
    ratio = torch.tensor(ratios, dtype=torch.float64)
    a = torch.full_like(ratio, adv)
    clipped = clipped_surrogate(ratio, a, eps)
    assert bool((clipped <= ratio * a + 1e-12).all())
    beyond = ratio > 1 + eps  # positive advantage beyond the clip range: gains are capped at (1+ε)A
    assert_close(clipped[beyond], torch.full_like(clipped[beyond], (1 + eps) * adv))
    assert bool((clipped[beyond] < (ratio * a)[beyond]).all())
    # with a negative advantage the bound is still pessimistic
    assert bool((clipped_surrogate(ratio, -a, eps) <= -ratio * a + 1e-12).all())


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-5.0, 5.0), min_size=1, max_size=8), st.floats(0.1, 3.0))
def test_bounds_loss_zero_inside_positive_outside(mu, bound):
    mean = torch.tensor([mu], dtype=torch.float64)
    loss = bounds_loss(mean, bound)
    outside = (mean.abs() > bound).any()
    assert float(loss) >= 0
    if outside:
        excess = (mean.abs() - bound).clamp(min=0).square().sum()
        assert float(loss) == pytest.approx(float(excess)) and float(loss) > 0
    else:
        assert float(loss) == 0.0


def test_value_loss_clipping():
    v, old, ret = torch.tensor([2.0]), torch.tensor([0.0]), torch.tensor([3.0])
    assert float(value_loss(v, old, ret)) == pytest.approx(0.5)
    # clipped prediction 0 + 0.5 is further from the target: the max picks it
    assert float(value_loss(v, old, ret, clip=0.5)) == pytest.approx(0.5 * 2.5**2)


# ----------------------------------------------------------------------------------- normalizer
@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.lists(st.integers(1, 40), min_size=1, max_size=5), st.integers(1, 4))
def test_normalizer_matches_numpy_and_merge_is_exact(seed, sizes, dim):
    rng = np.random.default_rng(seed)
    batches = [rng.normal(loc=rng.normal(size=dim) * 3, scale=rng.uniform(0.1, 4), size=(n, dim)) for n in sizes]
    norm = RunningNormalizer(dim, clip=None)
    for b in batches:
        norm.update(torch.as_tensor(b, dtype=torch.float32))
    data = np.concatenate([b.astype(np.float32) for b in batches]).astype(np.float64)
    np.testing.assert_allclose(norm.mean.numpy(), data.mean(0), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(norm.var.numpy(), data.var(0), rtol=1e-9, atol=1e-9)
    assert float(norm.count) == len(data)

    k = len(batches) // 2
    a, b = RunningNormalizer(dim, clip=None), RunningNormalizer(dim, clip=None)
    for x in batches[:k]:
        a.update(torch.as_tensor(x, dtype=torch.float32))
    for x in batches[k:]:
        b.update(torch.as_tensor(x, dtype=torch.float32))
    a.merge(b)
    assert_close(a.mean, norm.mean, rtol=1e-10, atol=1e-10)
    assert_close(a.var, norm.var, rtol=1e-10, atol=1e-10)
    assert float(a.count) == float(norm.count)


def test_normalizer_normalize_clip_freeze_and_state():
    norm = RunningNormalizer(3, clip=2.0)
    x = torch.randn(500, 3) * 4 + 1
    norm.update(x)
    y = norm.normalize(x)
    assert float(y.abs().max()) <= 2.0
    inner = RunningNormalizer(3, clip=None)
    inner.load_state_dict(norm.state_dict())
    assert_close(inner.denormalize(inner.normalize(x)), x, rtol=1e-5, atol=1e-5)
    norm.freeze()
    before = norm.mean.clone()
    norm.update(torch.randn(10, 3) + 100)
    assert torch.equal(norm.mean, before)
    other = RunningNormalizer(3)
    other.load_state_dict(norm.state_dict())
    assert other.frozen


# ------------------------------------------------------------------------------------- networks
def test_multi_discrete_log_prob_is_sum_of_heads():
    torch.manual_seed(0)
    nvec = (3, 4, 2)
    model = ActorCritic(5, MultiDiscrete(nvec), actor_hidden=[16], critic_hidden=[16], activation="relu")
    with torch.no_grad():
        model.action_head.weight.normal_()  # non-uniform logits
    obs = torch.randn(64, 5)
    action, logp_act, _ = model.act(obs)
    assert action.dtype == torch.long and action.shape == (64, 3)
    assert all(int(action[:, i].max()) < n for i, n in enumerate(nvec))
    logp, ent, value = model.evaluate(obs, action)
    logits = model.action_head(model.actor_body(model.obs_norm.normalize(obs)))
    dists = [torch.distributions.Categorical(logits=c) for c in torch.split(logits, list(nvec), -1)]
    ref_logp = sum(d.log_prob(action[:, i]) for i, d in enumerate(dists))
    ref_ent = sum(d.entropy() for d in dists)
    assert_close(logp, ref_logp)
    assert_close(logp_act, ref_logp)
    assert_close(ent, ref_ent)
    assert value.shape == (64,)
    det = model.mean_action(obs)
    assert torch.equal(det, torch.stack([d.probs.argmax(-1) for d in dists], -1))


def test_gaussian_head_log_prob_and_policy_file_roundtrip(tmp_path: Path):
    torch.manual_seed(0)
    model = ActorCritic(4, Box((3,)), actor_hidden=[8], critic_hidden=[8], log_std_init=-0.7, learn_std=False, normalize_value=True)
    model.obs_norm.update(torch.randn(100, 4) * 3)
    model.value_norm.update(torch.randn(100) * 5 + 2)
    obs, action = torch.randn(10, 4), torch.randn(10, 3)
    logp, ent, value = model.evaluate(obs, action)
    mean = model.mean_action(obs)
    ref = torch.distributions.Normal(mean, torch.full_like(mean, math.exp(-0.7)))
    assert_close(logp, ref.log_prob(action).sum(-1))
    assert_close(ent, ref.entropy().sum(-1))
    assert not model.log_std.requires_grad

    save_policy(tmp_path / "policy.pt", model, extra={"note": 1})
    loaded = load_policy(tmp_path / "policy.pt")
    assert loaded.config == model.config
    for a, b in zip(model.evaluate(obs, action), loaded.evaluate(obs, action)):
        assert torch.equal(a, b)
    assert load_checkpoint(tmp_path / "policy.pt")["extra"] == {"note": 1}


# -------------------------------------------------------------------------------------- training
def _train(tmp_path: Path, params: PPOParams, discrete: bool = False, stop_after: int | None = None, seed: int = 0):
    ctx = FakeContext(tmp_path, lambda n: PointEnv(n, seed=seed, discrete=discrete), seed=seed, stop_after=stop_after)
    result = PPOTrainer(params).run(ctx)
    ctx.log.close()
    return result


def test_ppo_learns_continuous_point_env(tmp_path: Path):
    result = _train(tmp_path, small_params())
    returns = episode_returns(tmp_path)
    assert returns[0] < -8, returns[0]  # random policy: the point wanders around its start
    assert returns[-1] > returns[0] + 5 and returns[-1] > -5, (returns[0], returns[-1])
    assert result.checkpoint == tmp_path / "policy.pt"
    assert result.metrics["iterations"] == 15 and result.metrics["episode/return"] == returns[-1]
    policy = load_policy(result.checkpoint)
    env = PointEnv(256, seed=123)
    obs, total = env.reset(), torch.zeros(256)
    with torch.no_grad():
        for _ in range(20):
            step = env.step(policy.mean_action(obs).clamp(-1, 1))
            total += step.reward
            obs = step.obs
    assert float(total.mean()) > -5  # the deterministic policy reaches the targets


def test_ppo_learns_multi_discrete_point_env(tmp_path: Path):
    # also exercises value normalization, value clipping, the entropy bonus and a linear lr schedule
    params = small_params(normalize_value=True, value_clip=0.2, entropy_coef=1e-3, lr_schedule="linear", lr=5e-3)
    _train(tmp_path, params, discrete=True)
    returns = episode_returns(tmp_path)
    assert returns[-1] > returns[0] + 5 and returns[-1] > -5, (returns[0], returns[-1])


def test_resume_with_a_constant_schedule_uses_the_specs_rate(tmp_path: Path):
    """A run trained with the adaptive rule, continued with ``lr_schedule: constant``: the optimizer
    runs at the spec's lr, not at the adapted rate saved in the checkpoint."""
    adaptive = small_params(total_env_steps=32 * 32 * 2, lr_schedule="adaptive", desired_kl=1e-4)
    _train(tmp_path, adaptive)
    saved = load_checkpoint(tmp_path / "ppo.pt")["optimizer"]["param_groups"][0]["lr"]
    assert saved != adaptive.lr  # the adaptive rule moved it
    constant = adaptive.model_copy(update={"lr_schedule": "constant", "lr": 7e-4, "total_env_steps": 32 * 32 * 3})
    _train(tmp_path, constant)
    ck = load_checkpoint(tmp_path / "ppo.pt")
    assert ck["iteration"] == 3 and ck["optimizer"]["param_groups"][0]["lr"] == pytest.approx(7e-4)


@pytest.mark.parametrize("schedule", ["constant", "adaptive"])
def test_resume_is_bit_exact(tmp_path: Path, schedule: str):
    params = small_params(total_env_steps=32 * 32 * 4, checkpoint_every=3, bounds_coef=1.0, soft_bound=0.5, lr_schedule=schedule, desired_kl=1e-4)
    _train(tmp_path / "straight", params)
    straight = load_checkpoint(tmp_path / "straight" / "ppo.pt")

    split = tmp_path / "split"
    stopped = _train(split, params, stop_after=2)  # Ctrl-C after iteration 2
    assert stopped.checkpoint == split / "ppo.pt" and not (split / "policy.pt").exists()
    assert load_checkpoint(split / "ppo.pt")["iteration"] == 2
    with (split / "metrics.jsonl").open("a") as fh:  # a line logged after the checkpoint, before a crash
        fh.write(json.dumps({"stage": "task", "step": 3, "episode/return": 0.0}) + "\n")
    _train(split, params)
    resumed = load_checkpoint(split / "ppo.pt")

    assert resumed["iteration"] == straight["iteration"] == 4
    assert resumed["env_steps"] == straight["env_steps"]
    assert straight["model"].keys() == resumed["model"].keys()
    for key, value in straight["model"].items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, resumed["model"][key]), key
    for sid, s in straight["optimizer"]["state"].items():
        for k, v in s.items():
            assert torch.equal(v, resumed["optimizer"]["state"][sid][k]), (sid, k)
    assert torch.equal(straight["obs"], resumed["obs"])
    lrs = [g["lr"] for g in straight["optimizer"]["param_groups"]]
    assert lrs == [g["lr"] for g in resumed["optimizer"]["param_groups"]]
    assert (lrs[0] != params.lr) == (schedule == "adaptive")  # the adaptive lr moved and was restored on resume
    steps = [json.loads(line)["step"] for line in (split / "metrics.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3, 4]
    a = load_policy(tmp_path / "straight" / "policy.pt")
    b = load_policy(split / "policy.pt")
    assert all(torch.equal(x, y) for x, y in zip(a.parameters(), b.parameters()))
    assert torch.equal(a.obs_norm.var, b.obs_norm.var)


@given(
    lr=st.floats(1e-6, 1e-2),
    kl=st.floats(0, 10) | st.just(float("nan")) | st.just(float("inf")),
    desired=st.floats(1e-4, 0.1),
)
def test_adaptive_lr_rule(lr: float, kl: float, desired: float):
    lo, hi = 1e-6, 1e-2
    new = adapt_lr(lr, kl, desired, lo, hi)
    assert lo <= new <= hi
    if not math.isfinite(kl) or kl > 2 * desired:
        assert new == max(lr / 1.5, lo)
    elif kl < desired / 2:
        assert new == min(lr * 1.5, hi)
    else:
        assert new == lr


def test_params_validation_and_registry():
    with pytest.raises(ValueError, match="minibatch_size"):
        PPOParams(num_envs=4, horizon=4, minibatch_size=32)
    with pytest.raises(ValueError):
        PPOParams(learning_rate=1e-3)  # extra='forbid'
    for name, f in PPOParams.model_fields.items():
        assert f.description, name

    import mocap.rl.plugin
    from mocap.testing import use_plugins

    with use_plugins(("rl", mocap.rl.plugin)) as pset:
        comp = pset.get("trainer", "ppo")
        trainer = comp.build({"num_envs": 8, "horizon": 8, "minibatch_size": 16})
    assert isinstance(trainer, PPOTrainer) and trainer.params.num_envs == 8
    assert isinstance(PointEnv(2), VecEnv)


class PointTask:
    """A task component whose RL problem is the point env (what a real task/imitator plugin provides)."""

    def __init__(self, params: Any = None, **kwargs: Any):
        self.kwargs = kwargs

    def make_env(self, ctx: Any, num_envs: int) -> PointEnv:
        return PointEnv(num_envs, seed=ctx.seed)


class point_plugin:
    @staticmethod
    @hookimpl
    def register_tasks(register):
        register("point", PointTask, description="toy 1-D point task")


def test_ppo_runs_as_a_pipeline_stage(tmp_path: Path):
    import mocap.rl.plugin
    from toy_plugins import toy

    from mocap.pipeline import run_pipeline
    from mocap.spec import load_spec_text
    from mocap.testing import use_plugins

    spec = """\
spec_version: 1
name: point
humanoid: {name: toy_body}
motions: {name: toy_motions}
simulator: {name: toy_sim}
task:
  name: point
  trainer:
    name: ppo
    params: {num_envs: 8, horizon: 8, total_env_steps: 192, minibatch_size: 32, actor_hidden: [8], critic_hidden: [8], max_grad_norm: null}
"""
    with use_plugins(("rl", mocap.rl.plugin), ("toy", toy), ("point", point_plugin)) as pset:
        resolved = load_spec_text(spec, pset)
        records = run_pipeline(resolved, pset, tmp_path / "run", console=Console(file=io.StringIO()))
    (record,) = records
    assert record.result.checkpoint == record.workdir / "policy.pt"
    assert (record.workdir / "DONE.json").is_file()
    assert load_checkpoint(record.workdir / "ppo.pt")["spec"] == resolved.to_yaml()
    assert isinstance(load_policy(record.result.checkpoint), ActorCritic)
    steps = [json.loads(line)["step"] for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3]


def test_export_policy_from_a_training_checkpoint(tmp_path):
    """``export_policy`` turns a resumable trainer checkpoint into a policy file with the same weights."""
    from mocap.checkpoint import load_checkpoint, save_checkpoint
    from mocap.rl.networks import ActorCritic, export_policy, load_policy

    model = ActorCritic(5, Box((2,)), [8], [8])
    save_checkpoint(
        tmp_path / "ppo.pt",
        {"model": model.state_dict(), "policy_config": model.config, "optimizer": {}, "iteration": 7, "env_steps": 700},
        spec_yaml="name: x\n",
    )
    export_policy(tmp_path / "ppo.pt", tmp_path / "policy.pt")
    again = load_policy(tmp_path / "policy.pt")
    pairs = [(a, b) for a, b in zip(model.state_dict().values(), again.state_dict().values()) if isinstance(a, torch.Tensor)]
    assert pairs and all(torch.equal(a, b) for a, b in pairs)
    data = load_checkpoint(tmp_path / "policy.pt")
    assert data["extra"] == {"iteration": 7, "env_steps": 700} and data["spec"] == "name: x\n" and "optimizer" not in data
