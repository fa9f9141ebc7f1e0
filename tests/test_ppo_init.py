"""PPO continued from a committed policy: init_policy (weights, normalizers, sigma) and init_lr."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from test_ppo import _train, episode_returns, small_params

from mocap.checkpoint import CheckpointError, load_checkpoint
from mocap.interfaces import Box
from mocap.rl.networks import load_policy
from mocap.rl.ppo import PPOTrainer


def test_init_policy_continues_a_trained_policy(tmp_path: Path):
    """``init_policy``: a fresh stage starts from a committed policy's weights and normalizers (its
    first iteration already scores like the trained policy), ``init_log_std`` resets σ, and a policy
    of another width is refused with the differing tensor named."""
    trained = _train(tmp_path / "a", small_params())
    learned = episode_returns(tmp_path / "a")[-1]
    src = load_policy(trained.checkpoint)
    cont = small_params(total_env_steps=32 * 32, init_policy=trained.checkpoint, init_log_std=-3.0)
    _train(tmp_path / "b", cont)
    first = episode_returns(tmp_path / "b")[0]
    assert first > -5 and first > episode_returns(tmp_path / "a")[0] + 5, (first, learned)
    ck = load_checkpoint(tmp_path / "b" / "ppo.pt")
    assert torch.equal(ck["model"]["obs_norm.count"], src.state_dict()["obs_norm.count"] + 32 * 32)  # continued stats
    fresh = PPOTrainer(cont).build_model(src.obs_dim, Box((src.action_dim,), -1.0, 1.0))
    from mocap.rl.networks import init_from_policy

    init_from_policy(fresh, trained.checkpoint, -3.0)
    assert torch.equal(fresh.log_std.detach(), torch.full_like(fresh.log_std, -3.0))
    assert torch.equal(fresh.actor_body[0].weight, src.actor_body[0].weight)
    wide = PPOTrainer(small_params(actor_hidden=[8])).build_model(src.obs_dim, Box((src.action_dim,), -1.0, 1.0))
    with pytest.raises(CheckpointError, match="actor_body"):
        init_from_policy(wide, trained.checkpoint)
    with pytest.raises(ValueError, match="init_log_std needs init_policy"):
        small_params(init_log_std=-3.0)


def test_init_lr_keeps_the_first_update_of_a_continued_policy_small(tmp_path: Path):
    """A trained policy continued under a fresh Adam at a large lr is thrown far off in its first
    update (the KL shock that cost the 15-clip imitator its skill); ``init_lr`` starts the adaptive
    schedule low, so the first update stays near the rollout policy. Constant/linear schedules and
    resumed stages keep ``lr``."""
    trained = _train(tmp_path / "a", small_params())

    def first_kl(name: str, init_lr: float | None) -> float:
        cont = small_params(total_env_steps=32 * 32, init_policy=trained.checkpoint, lr=0.05, lr_schedule="adaptive", init_lr=init_lr)
        _train(tmp_path / name, cont)
        row = json.loads((tmp_path / name / "metrics.jsonl").read_text().splitlines()[0])
        return float(row["approx_kl"])

    shocked, gentle = first_kl("shock", None), first_kl("gentle", 1e-5)
    assert gentle < 0.01 < shocked, (gentle, shocked)
    p = small_params(init_policy=trained.checkpoint, lr_schedule="adaptive", init_lr=1e-5)
    assert p.start_lr(fresh=True) == 1e-5 and p.start_lr(fresh=False) == p.lr
    assert small_params(init_policy=trained.checkpoint, lr_schedule="constant", init_lr=1e-5).start_lr(True) == 3e-3
    assert small_params(lr_schedule="adaptive").start_lr(True) == 3e-3  # no init_policy: a fresh network


def test_init_model_seeds_a_fresh_phase_and_a_resume_keeps_its_own_weights(tmp_path: Path):
    """``PPOTrainer(params, init_model=...)`` (how PMCP starts a phase from another policy): the hook
    runs on the fresh model before training; a resumed stage loads ``ppo.pt`` and does not call it."""
    from test_ppo import FakeContext, PointEnv

    trained = _train(tmp_path / "a", small_params())
    src = load_policy(trained.checkpoint)
    calls: list[int] = []

    def init(model) -> None:
        calls.append(1)
        model.load_state_dict(src.state_dict())

    def run(stop_after: int | None) -> None:
        ctx = FakeContext(tmp_path / "b", lambda n: PointEnv(n, seed=0), seed=0, stop_after=stop_after)
        PPOTrainer(small_params(total_env_steps=4 * 32 * 32), init_model=init).run(ctx)
        ctx.log.close()

    run(stop_after=1)
    first = json.loads((tmp_path / "b" / "metrics.jsonl").read_text().splitlines()[0])
    assert first["episode/return"] > episode_returns(tmp_path / "a")[0] + 5  # started from the trained weights
    assert calls == [1]
    run(stop_after=None)  # resumes from ppo.pt
    assert calls == [1]


def test_a_pmcp_state_file_that_is_not_one_is_a_clear_error(tmp_path: Path):
    from mocap import trainer_scaffold as scaffold

    path = tmp_path / "pmcp_state.json"
    assert scaffold.resume_state_file(path, 1, "PMCP") is None
    path.write_text("{not json")
    with pytest.raises(CheckpointError, match="pmcp_state.json: not a PMCP state file"):
        scaffold.resume_state_file(path, 1, "PMCP")
    path.write_text('{"format": 7}')
    with pytest.raises(CheckpointError, match="format 7"):
        scaffold.resume_state_file(path, 1, "PMCP")
    path.write_text('{"format": 1, "phase": "composer"}')
    assert scaffold.resume_state_file(path, 1, "PMCP") == {"format": 1, "phase": "composer"}
