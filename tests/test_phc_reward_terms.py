"""The imitation env's reward as named, weighted terms (``mocap.episodes.RewardTerms``) and the
spec's ``phc.reward_terms`` weight overrides."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from pydantic import ValidationError

torch.set_num_threads(1)

import mocap_phc.plugin  # noqa: F401
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap_phc.imitator import PHCParams

ROOT = Path(__file__).resolve().parents[1]
AMP_SMALL = dict(amp=True, amp_hidden=[16, 8], amp_batch=16, amp_updates_per_iteration=1, amp_replay_size=32, amp_demo_buffer_size=40)


@pytest.fixture(scope="module")
def walk(amp):
    return DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp)


def _env(skeleton, walk, **overrides):
    from mocap.motion.library import MotionLibrary
    from mocap_phc.env import ImitationEnv
    from mocap_sim_mujoco.simulator import MujocoSimulator

    params = PHCParams(**{"action": "residual", "hard_negative": False, "eval_every": 0, "energy_coef": 0.01, **overrides})
    sim = MujocoSimulator(skeleton=skeleton, num_envs=4, seed=0, dtype=torch.float32)
    return ImitationEnv(params, skeleton, MotionLibrary(walk, skeleton), sim, seed=0)


def _rollout(env, steps=6):
    """Steps past the energy warm-up (the code form is 0 for the first 3 steps) with fixed actions."""
    env.reset()
    g = torch.Generator().manual_seed(0)
    return [env.step(0.3 * torch.randn(env.num_envs, env.action_space.shape[0], generator=g)) for _ in range(steps)]


def _weighted(res, weights, unstable=None):
    """The reward as RewardTerms sums it: sum_k w_k r_k in the declared order, float64, 0 where unstable."""
    total = None
    for name, w in weights.items():
        v = res.info[f"reward/{name}"]
        part = v if w == 1.0 else w * v
        total = part if total is None else total + part
    total = total.double()
    bad = ~torch.isfinite(total) | (res.info["terminated/unstable"] > 0)
    return torch.where(bad, torch.zeros_like(total), total).float()


def test_default_terms_per_configuration():
    assert PHCParams().reward_term_weights() == {"imitation": 1.0, "energy": 1.0}
    point = PHCParams(recovery_goal={"reward": "point"}).reward_term_weights()
    assert list(point) == ["imitation", "point", "energy"] and set(point.values()) == {1.0}
    paper = PHCParams(amp=True, task_reward_weight=0.3, amp_reward_weight=0.7).reward_term_weights()
    assert paper == {"imitation": 0.3, "amp": 0.7, "energy": 1.0} and list(paper) == ["imitation", "amp", "energy"]
    code = PHCParams(amp=True, amp_energy_mix="code", task_reward_weight=0.3, amp_reward_weight=0.7).reward_term_weights()
    assert code == {"imitation": 0.3, "energy": 0.3, "amp": 0.7} and list(code) == ["imitation", "energy", "amp"]


def test_override_reweights_the_reward_exactly(amp, walk):
    base = _rollout(_env(amp, walk))
    weights = {"imitation": 0.5, "energy": 3.0}
    env = _env(amp, walk, reward_terms=weights)
    assert env.reward_terms.weights == weights
    heavy = _rollout(env)
    energy_seen = False
    for b, h in zip(base, heavy):
        # the terms (and everything else) are unchanged: the reward does not feed back into the dynamics
        for key in ("reward/imitation", "reward/energy", "reward/pos"):
            assert torch.equal(b.info[key], h.info[key]), key
        assert torch.equal(b.obs, h.obs)
        assert torch.equal(b.reward, _weighted(b, {"imitation": 1.0, "energy": 1.0}))
        assert torch.equal(h.reward, _weighted(h, weights))
        energy_seen |= bool((h.info["reward/energy"] < 0).any())
    assert energy_seen
    assert not torch.equal(torch.stack([r.reward for r in base]), torch.stack([r.reward for r in heavy]))


def test_override_of_the_amp_term(amp, walk):
    weights = PHCParams(**AMP_SMALL).reward_term_weights()  # imitation 0.5, amp 0.5, energy 1
    res = _rollout(_env(amp, walk, reward_terms={"amp": 2.0}, **AMP_SMALL), steps=5)
    for r in res:
        assert torch.equal(r.reward, _weighted(r, {**weights, "amp": 2.0}))
        assert torch.equal(r.info["reward/task"], r.info["reward/imitation"])  # paper mix: the task reward is r^g


def test_unknown_term_is_rejected_by_spec_validation():
    with pytest.raises(ValidationError, match="unknown reward term"):
        PHCParams(reward_terms={"imitaton": 1.0})
    from mocap.plugins import get_plugins
    from mocap.spec import SpecError, load_spec

    spec = ROOT / "specs" / "imitator" / "amp_bundled.yaml"
    with pytest.raises(SpecError, match="reward_terms"):
        load_spec(spec, get_plugins(), overrides=["imitator.params.reward_terms={bogus: 1.0}"])
    ok = load_spec(spec, get_plugins(), overrides=["imitator.params.reward_terms={energy: 2.0}"])
    assert ok.spec.imitator.params["reward_terms"] == {"energy": 2.0}


@pytest.mark.parametrize(("term", "needs"), [("amp", "amp: true"), ("point", "recovery_goal.reward: point")])
def test_a_term_absent_from_the_configuration_fails_at_env_build(amp, walk, term, needs):
    PHCParams(reward_terms={term: 1.0})  # a valid name: the spec validates ...
    with pytest.raises(ValueError, match=f"{term}.*not in this configuration.*{needs}"):
        _env(amp, walk, reward_terms={term: 1.0})  # ... but this env has no such term


def test_episode_counters_are_the_book_and_keep_their_state_keys(amp, walk):
    env = _env(amp, walk)
    _rollout(env, steps=3)
    assert env.progress is env.book.steps and env.ep_return is env.book.returns
    with pytest.raises(AttributeError):
        env.progress = torch.zeros(4, dtype=torch.long)
    sd = env.state_dict()
    assert torch.equal(sd["progress"], env.book.steps) and torch.equal(sd["ep_return"], env.book.returns)
    assert "steps" not in sd and "returns" not in sd  # the STATE_FORMAT 1 keys, loadable by older code
