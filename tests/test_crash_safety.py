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

import pytest
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
    params: {num_envs: 16, horizon: 16, total_env_steps: 8192, minibatch_size: 64, epochs: 2,
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


def _logged(out: Path) -> int:
    try:
        return sum(1 for line in (out / "metrics.jsonl").read_text().splitlines() if line.strip())
    except FileNotFoundError:
        return 0


def _run(spec: Path, out: Path, kill_at: int | None = None, delay: float = 0.0) -> int | None:
    """Run to the end, or SIGKILL the run ``delay`` s after its log reaches ``kill_at`` iterations."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    proc = subprocess.Popen(_command(spec, out), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    if kill_at is None:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err.decode()[-2000:]
        return proc.returncode
    deadline = time.monotonic() + 120
    while _logged(out) < kill_at and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(delay)
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
    for kill_at in (3, 10, 19, 27):  # after iterations (checkpoints every 2) plus a random delay: any moment
        _run(spec, killed, kill_at=kill_at, delay=rng.uniform(0.0, 0.3))
        ckpt = next((killed.parent / "artifacts").glob("task-*/ppo.pt"), None)
        if ckpt is not None:
            seen.append(load_checkpoint(ckpt)["iteration"])  # every checkpoint on disk is complete
    assert len(seen) == 4 and all(0 < it < 32 for it in seen) and seen == sorted(seen), seen  # kills landed mid-training
    _run(spec, killed)
    leftovers = sorted((killed.parent / "artifacts").glob("**/.*.tmp")) + sorted(killed.glob("**/.*.tmp"))
    assert not leftovers, f"temporary files of killed writes left behind: {leftovers}"

    a, b = load_checkpoint(_task_dir(straight) / "ppo.pt"), load_checkpoint(_task_dir(killed) / "ppo.pt")
    assert a["iteration"] == b["iteration"] == 32
    for key, value in a["model"].items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, b["model"][key]), key
    steps = [json.loads(line)["step"] for line in (killed / "metrics.jsonl").read_text().splitlines() if line.strip()]
    assert steps == list(range(1, 33))


@pytest.mark.slow
def test_a_campaign_of_twenty_sigkills_ends_bit_exact(tmp_path: Path):
    """The reliability campaign: 20 SIGKILLs, 17 at random iterations and random moments within them
    (mid-write included) and 3 after the last iteration (final checkpoint, policy file, report),
    each followed by the same command; the result equals the uninterrupted run."""
    spec = tmp_path / "point.yaml"
    spec.write_text(SPEC)
    straight = tmp_path / "a" / "runs" / "point"
    _run(spec, straight)
    killed = tmp_path / "b" / "runs" / "point"
    rng = random.Random(20)
    moments = [(k, rng.uniform(0.0, 0.2)) for k in sorted(rng.sample(range(1, 31), 17))] + [(32, d) for d in (0.0, 0.05, 0.15)]
    for kill_at, delay in moments:
        _run(spec, killed, kill_at=kill_at, delay=delay)
    _run(spec, killed)
    assert (killed / "report.md").is_file()
    assert not sorted((killed.parent / "artifacts").glob("**/.*.tmp"))
    a, b = load_checkpoint(_task_dir(straight) / "ppo.pt"), load_checkpoint(_task_dir(killed) / "ppo.pt")
    for key, value in a["model"].items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, b["model"][key]), key
    steps = [json.loads(line)["step"] for line in (killed / "metrics.jsonl").read_text().splitlines() if line.strip()]
    assert steps == list(range(1, 33))


def test_same_spec_and_seed_give_identical_metrics(tmp_path: Path):
    """Determinism on CPU: two runs of one spec log the same numbers (wall-clock fields aside), and
    the run records its seed and the stage seeds derived from it."""
    import io

    import yaml
    from rich.console import Console
    from test_ppo import point_plugin
    from toy_plugins import toy

    import mocap.rl.plugin
    from mocap.pipeline import derive_seed, run_pipeline
    from mocap.spec import load_spec_text
    from mocap.testing import use_plugins

    spec_text = SPEC.replace("15360", "2048").replace("8192", "2048") + "seed: 7\n"
    logs = []
    for run in ("a", "b"):
        with use_plugins(("rl", mocap.rl.plugin), ("toy", toy), ("point", point_plugin)) as pset:
            resolved = load_spec_text(spec_text, pset)
            run_pipeline(resolved, pset, tmp_path / run / "runs" / "point", console=Console(file=io.StringIO()))
        rows = [json.loads(line) for line in (tmp_path / run / "runs" / "point" / "metrics.jsonl").read_text().splitlines()]
        logs.append([{k: v for k, v in r.items() if k != "time" and not k.startswith(("time/", "steps_per_s", "rollout_steps"))} for r in rows])
    assert logs[0] == logs[1] and len(logs[0]) == 8
    recorded = yaml.safe_load((tmp_path / "a" / "runs" / "point" / "spec.yaml").read_text())
    assert recorded["seed"] == 7
    stages = json.loads((tmp_path / "a" / "runs" / "point" / "stages.json").read_text())
    assert stages[0].get("seed") == derive_seed(7, "task"), stages[0]


EVAL_SPEC = """\
spec_version: 1
name: evalkill
motions: {name: deepmimic, params: {clips: [walk, run, jump, kick]}}
imitator: {name: pd_replay}
eval: {trainer: {name: imitation_eval, params: {video: true, video_seconds: 1.0, num_envs: 2}}}
"""


def _eval_run(spec: Path, out: Path, kill: str | None = None, delay: float = 0.0) -> None:
    """``mocap run`` of the eval-only spec; ``kill``: SIGKILL ``delay`` s after the eval stage's
    artifact folder appears ("started") or after its row reached metrics.jsonl ("logged")."""
    cmd = [sys.executable, "-m", "mocap", "run", str(spec), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env={**os.environ, "OMP_NUM_THREADS": "1"})
    if kill is None:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err.decode()[-2000:]
        return
    deadline = time.monotonic() + 240
    while proc.poll() is None and time.monotonic() < deadline:
        started = bool(sorted((out.parent / "artifacts").glob("eval-*")))
        if (kill == "started" and started) or (kill == "logged" and _logged(out) > 0):
            break
        time.sleep(0.01)
    time.sleep(delay)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)


def test_sigkill_during_the_eval_stage_leaves_one_eval_row(tmp_path: Path):
    """Killed during the eval stage (mid-rollout, and right after its row was logged while its video
    was still being written), then rerun: the run ends with exactly one eval row and its files."""
    spec = tmp_path / "evalkill.yaml"
    spec.write_text(EVAL_SPEC)
    out = tmp_path / "runs" / "e"
    _eval_run(spec, out, kill="started", delay=random.Random(3).uniform(0.2, 1.5))
    _eval_run(spec, out, kill="logged", delay=0.0)
    _eval_run(spec, out)
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines() if line.strip()]
    assert [r["stage"] for r in rows] == ["eval"], rows
    assert (out / "imitation_eval.json").is_file() and (out / "stages.json").is_file()
    assert not sorted(out.parent.glob("**/.*.tmp"))
