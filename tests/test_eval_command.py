"""`mocap eval` on a checkpoint and on a run directory: table, JSON fields, clean errors."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from mocap.interfaces import Box
from mocap.plugins import get_plugins
from mocap.rl.networks import ActorCritic, save_policy
from mocap.testing import invoke

SPEC = """\
spec_version: 1
name: eval-cmd
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk, kick]}}
simulator: {name: mujoco}
imitator:
  name: phc
  params: {action: residual}
  trainer: {name: ppo}
"""


def test_eval_checkpoint_json_fields(tmp_path: Path):
    from mocap.spec import load_spec_text

    resolved = load_spec_text(SPEC, get_plugins())
    phc = get_plugins().get("imitator", "phc").build(resolved.params["imitator"], skeleton=get_plugins().get("humanoid", "amp").build({}))
    obs_dim = phc.observation.dim(15)
    torch.manual_seed(0)
    model = ActorCritic(obs_dim, Box((28,)), [32], [32], "elu", -5.0, False, True, 5.0, False)
    for p in model.action_head.parameters():  # a zero policy: residual 0 = PD replay of the reference
        torch.nn.init.zeros_(p)
    ckpt = tmp_path / "policy.pt"
    save_policy(ckpt, model, spec_yaml=resolved.to_yaml())
    out = tmp_path / "eval.json"
    result = invoke(["eval", ckpt, "--json", out])
    assert result.exit_code == 0, result.output
    assert "walk" in result.stdout and "success rate" in result.stdout
    table = json.loads(out.read_text())
    agg = table["aggregate"]
    for key in ("success_rate", "succeeded", "total", "mpjpe_g", "mpjpe_l", "pa_mpjpe", "acc_err", "vel_err", "fps"):
        assert key in agg, key
    assert agg["total"] == 2 and 0.0 <= agg["success_rate"] <= 1.0 and agg["fps"] == 30.0
    assert set(table["clips"]) == {"walk", "kick"}
    assert isinstance(table["clips"]["walk"]["success"], bool)
    # the zero residual policy is PD replay: it falls on the kick, like the pd_replay baseline
    assert table["clips"]["kick"]["success"] is False


def test_eval_errors_are_clean(tmp_path: Path):
    result = invoke(["eval", tmp_path / "missing.pt"])
    assert result.exit_code == 2 and "Traceback" not in result.output and "no such checkpoint" in result.stderr
    (tmp_path / "run").mkdir()
    result = invoke(["eval", tmp_path / "run"])
    assert result.exit_code == 2 and "not a run directory" in result.stderr
