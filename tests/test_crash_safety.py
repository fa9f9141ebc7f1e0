"""Crash safety: a real `mocap run` killed with SIGKILL at random moments, restarted each time with
the same command, finishes with the same weights as an uninterrupted run, no half-written
checkpoint, and a metrics log without duplicate or missing iterations."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import torch

from mocap.checkpoint import load_checkpoint

TESTS = Path(__file__).parent

SPEC = """\
spec_version: 1
name: point
humanoid: {name: toy_body}
motions: {name: toy_motions}
simulator: {name: toy_sim}
task:
  name: point
  trainer:
    name: ppo
    params: {num_envs: 16, horizon: 16, total_env_steps: 15360, minibatch_size: 64, epochs: 2,
             actor_hidden: [16], critic_hidden: [16], checkpoint_every: 2, torch_threads: 1}
"""

RUNNER = """\
import sys
sys.path.insert(0, {tests!r})
import mocap.rl.plugin
from toy_plugins import toy
from test_ppo import point_plugin
from mocap.testing import use_plugins
from mocap.cli import main
with use_plugins(("rl", mocap.rl.plugin), ("toy", toy), ("point", point_plugin)):
    sys.exit(main(["run", {spec!r}, "--out", {out!r}]))
"""


def _command(spec: Path, out: Path) -> list[str]:
    return [sys.executable, "-c", RUNNER.format(tests=str(TESTS), spec=str(spec), out=str(out))]


def _run(spec: Path, out: Path, kill_after: float | None = None) -> int | None:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    proc = subprocess.Popen(_command(spec, out), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    if kill_after is None:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err.decode()[-2000:]
        return proc.returncode
    time.sleep(kill_after)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    return None


def _task_dir(out: Path) -> Path:
    (d,) = sorted((out.parent / "artifacts").glob("task-*"))
    return d


def test_sigkill_at_random_moments_then_resume(tmp_path: Path):
    spec = tmp_path / "point.yaml"
    spec.write_text(SPEC)
    straight = tmp_path / "a" / "runs" / "point"
    _run(spec, straight)

    killed = tmp_path / "b" / "runs" / "point"
    rng = random.Random(0)
    seen = []
    for _ in range(4):  # imports take ~2 s; the training ~8 s: kills land before, during and between checkpoints
        _run(spec, killed, kill_after=rng.uniform(2.0, 7.0))
        for leftover in (killed.parent / "artifacts").glob("**/*.tmp*"):
            assert False, f"half-written file left behind: {leftover}"
        ckpt = next((killed.parent / "artifacts").glob("task-*/ppo.pt"), None)
        if ckpt is not None:
            seen.append(load_checkpoint(ckpt)["iteration"])  # every checkpoint on disk is complete
    assert any(0 < it < 60 for it in seen), seen  # at least one kill landed mid-training
    _run(spec, killed)

    a, b = load_checkpoint(_task_dir(straight) / "ppo.pt"), load_checkpoint(_task_dir(killed) / "ppo.pt")
    assert a["iteration"] == b["iteration"] == 60
    for key, value in a["model"].items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, b["model"][key]), key
    steps = [json.loads(line)["step"] for line in (killed / "metrics.jsonl").read_text().splitlines() if line.strip()]
    assert steps == list(range(1, 61))
