"""A trained task policy on video: ``mocap render RUN_DIR`` for a run with a ``task`` stage.

The run directory's ``spec.yaml`` and ``stages.json`` name everything: the task, the frozen latent
space (or ``scratch``) and imitator checkpoints, and the task policy (``policy.pt`` of the task
stage). :func:`render_task` builds the same :class:`~mocap.task_env.TaskEnv` the ``task`` stage
trained in (one env, the stage's seed unless ``seed`` is given), rolls the task policy out with its
deterministic action (Gaussian mean, or the argmax code of a discrete head) clipped to the action
bounds as PPO does, and records env 0 with the simulator's video recorder. Episodes restart as in
training (on termination or at the episode length), so a fall is visible and followed by a reset.

Goals are drawn as marker spheres when the task exposes ``markers(env_id) -> [(pos, rgba,
radius), ...]`` (reach: the hand target; speed: a point 1 m ahead of the root in the target
direction; strike: the target's centre and top, so a knocked-over target shows).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import torch
from mocap.errors import UserError
from mocap.runfiles import read_spec_file, read_stages


def task_stage(run_dir: Path) -> dict[str, Any] | None:
    """The ``task`` entry of ``run_dir/stages.json``, or None when ``run_dir`` is no task run."""
    stages_file = Path(run_dir) / "stages.json"
    if not (Path(run_dir).is_dir() and stages_file.is_file()):
        return None
    try:
        stages = read_stages(stages_file)
    except (OSError, ValueError, UserError):  # not a (readable) run record: not a task run
        return None
    return next((s for s in stages if isinstance(s, dict) and s.get("stage") == "task"), None)


def render_task(run_dir: Path, out: Path, *, seconds: float = 10.0, seed: int | None = None, width: int = 640, height: int = 480) -> tuple[Path, str]:
    """Record the task policy of ``run_dir`` for ``seconds`` into ``out`` (module docstring)."""
    from mocap.errors import UserError
    from mocap.task_env import make_task_env
    from mocap.interfaces import Box, StageResult
    from mocap.pipeline import StageContext
    from mocap.plugins import get_plugins
    from mocap.rl.networks import load_policy
    from mocap.runlog import MetricsLogger
    from mocap.spec import SpecError, validate_document

    run_dir = Path(run_dir)
    stage = task_stage(run_dir)
    if stage is None or not stage.get("checkpoint"):
        raise UserError(f"{run_dir}: no finished task stage in stages.json (run it first)")
    policy_path = Path(stage["checkpoint"])
    if not policy_path.is_file():
        raise UserError(f"{run_dir}: the task policy {policy_path} does not exist (moved?)")
    plugins = get_plugins()
    try:
        resolved = validate_document(read_spec_file(run_dir / "spec.yaml"), plugins, source=str(run_dir / "spec.yaml"))
    except SpecError as exc:
        raise UserError(str(exc)) from None
    upstream = {
        s["stage"]: StageResult(Path(s["checkpoint"]) if s.get("checkpoint") else None)
        for s in read_stages(run_dir / "stages.json")
        if s.get("stage") in ("imitator", "latent")
    }
    from rich.console import Console

    with tempfile.TemporaryDirectory() as tmp:
        ctx = StageContext(
            stage="task", resolved=resolved, plugins=plugins, workdir=Path(tmp), run_dir=Path(tmp), upstream=upstream,
            log=MetricsLogger(Path(tmp) / "metrics.jsonl", "task", enabled=False), seed=int(stage.get("seed", 0) if seed is None else seed),
            device=torch.device("cpu"), console=Console(stderr=True, quiet=True),
        )  # fmt: skip
        env = make_task_env(ctx, 1)
    try:
        policy = load_policy(policy_path)
        policy.eval()
        recorder = env.sim.make_recorder(width=width, height=height)
        if recorder is None:
            raise UserError(f"the {type(env.sim).__name__} simulator cannot render videos")
        space = env.action_space
        bounds = (space.low, space.high) if isinstance(space, Box) and (space.low != float("-inf") or space.high != float("inf")) else None
        obs = env.reset()
        steps = max(1, int(round(seconds / float(env.sim.dt))))
        episodes = falls = 0
        for _ in range(steps):
            with torch.no_grad():
                action = policy.mean_action(obs)
            if bounds is not None:
                action = action.clamp(*bounds)
            result = env.step(action)
            obs = result.obs
            recorder.add_frame(env.sim.state, markers=env.task.markers(0))
            if bool(result.terminated[0] | result.truncated[0]):
                episodes += 1
                falls += int(result.terminated[0])
        recorder.save(out)
    finally:
        env.close()
    spec = resolved.spec
    assert spec.task is not None and spec.latent is not None  # make_task_env built the env from both
    return Path(out), (
        f"task {spec.task.name} through {spec.latent.name}, {steps} frames, {steps * float(env.sim.dt):.2f} s, "
        f"{episodes} episode end(s) of which {falls} terminated"
    )


__all__ = ["render_task", "task_stage"]
