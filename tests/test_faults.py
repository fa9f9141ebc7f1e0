"""Numerical faults (``mocap.faults``): non-finite batches are skipped and counted, never reach the
weights, and too many in a row stop the run with a clear message and a good checkpoint."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from test_ppo import FakeContext, PointEnv, small_params

from mocap.checkpoint import load_checkpoint
from mocap.faults import FaultGuard, NumericalFault
from mocap.rl.ppo import PPOTrainer


def _model_and_opt():
    torch.manual_seed(0)
    model = torch.nn.Linear(3, 2)
    opt = torch.optim.Adam(model.parameters(), lr=0.1)
    return model, opt


def _snapshot(model, opt):
    return [p.detach().clone() for p in model.parameters()], json.dumps({k: str(v) for k, v in opt.state_dict()["state"].items()})


@pytest.mark.parametrize("poison", ["loss", "grad"])
def test_a_non_finite_batch_changes_nothing(poison):
    model, opt = _model_and_opt()
    guard = FaultGuard(max_consecutive=3)
    x = torch.randn(4, 3)
    loss = model(x).square().mean()
    loss.backward()
    assert guard.step(opt, loss, model.parameters(), 1.0)[0]  # a good step first: Adam has state
    before = _snapshot(model, opt)
    opt.zero_grad()
    bad = model(x).sum() * (float("nan") if poison == "loss" else 1.0)
    bad.backward()
    if poison == "grad":  # a finite loss whose gradient is not
        model.weight.grad[0, 0] = float("inf")
    stepped, norm = guard.step(opt, bad, model.parameters(), 1.0)
    after = _snapshot(model, opt)
    assert not stepped and norm != norm  # NaN norm reported
    assert all(torch.equal(a, b) for a, b in zip(before[0], after[0])) and before[1] == after[1]
    assert all(p.grad is None for p in model.parameters())
    assert guard.take_counts() == {"faults/skipped": 1.0, "faults/total": 1.0}
    assert guard.take_counts()["faults/skipped"] == 0.0


def test_consecutive_faults_stop_and_a_good_step_resets_the_count():
    model, opt = _model_and_opt()
    guard = FaultGuard(max_consecutive=3, where="ppo")
    nan = torch.tensor(float("nan"))
    guard.step(opt, nan, model.parameters(), None)
    guard.step(opt, nan, model.parameters(), None)
    good = model(torch.randn(2, 3)).sum()
    good.backward()
    assert guard.step(opt, good, model.parameters(), None)[0] and guard.consecutive == 0
    assert guard.check_inputs(obs=torch.zeros(3), none=None)
    assert not guard.check_inputs(obs=torch.tensor([0.0, float("inf")]))
    guard.step(opt, nan, model.parameters(), None)
    with pytest.raises(NumericalFault, match="3 consecutive batches"):
        guard.step(opt, nan, model.parameters(), None)
    assert guard.total == 5  # the non-finite input counts as a fault too


class FaultyPointEnv(PointEnv):
    """PointEnv whose rewards are NaN during the steps listed in ``bad_steps`` (counted globally)."""

    def __init__(self, *a, bad_steps=(), **kw):
        super().__init__(*a, **kw)
        self.bad_steps = set(bad_steps)
        self.count = 0

    def step(self, actions):
        out = super().step(actions)
        if self.count in self.bad_steps or "all" in self.bad_steps:
            out.reward = out.reward * float("nan")
        self.count += 1
        return out


def _run(tmp_path: Path, bad_steps, **kw):
    params = small_params(num_envs=8, horizon=8, total_env_steps=8 * 8 * 6, minibatch_size=32, checkpoint_every=1, **kw)
    ctx = FakeContext(tmp_path, lambda n: FaultyPointEnv(n, bad_steps=bad_steps))
    try:
        return PPOTrainer(params).run(ctx)
    finally:
        ctx.log.close()


def test_ppo_skips_an_iteration_with_nan_rewards_and_logs_it(tmp_path):
    _run(tmp_path, bad_steps={8 * 2 + 3})  # one step inside iteration 3
    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert [r["faults/skipped"] for r in rows] == [0, 0, 1, 0, 0, 0]
    assert rows[-1]["faults/total"] == 1 and "loss/policy" not in rows[2] and "loss/policy" in rows[3]
    ck = load_checkpoint(tmp_path / "ppo.pt")
    assert all(bool(torch.isfinite(v).all()) for v in ck["model"].values() if isinstance(v, torch.Tensor))


def test_ppo_stops_cleanly_after_repeated_faults(tmp_path):
    with pytest.raises(NumericalFault, match="consecutive"):
        _run(tmp_path / "a", bad_steps={"all"}, max_consecutive_faults=3)
    ck = load_checkpoint(tmp_path / "a" / "ppo.pt")  # written before the stop, with clean weights
    assert ck["iteration"] == 2
    assert all(bool(torch.isfinite(v).all()) for v in ck["model"].values() if isinstance(v, torch.Tensor))
