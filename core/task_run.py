"""A trained task run reopened: the ``task`` stage's env and policy, from a run directory.

The run directory's ``spec.yaml`` and ``stages.json`` name everything: the task, the frozen latent
space (or ``scratch``) and imitator checkpoints, and the task policy (``policy.pt`` of the task
stage); a directory written by ``mocap export`` (``spec.yaml`` alone, every stage's ``checkpoint:``
in it, the task's ``task_policy.pt``) works the same. :func:`open_task_run` builds the same :class:`~mocap.task_env.TaskEnv` the ``task`` stage
trained in (``num_envs`` envs, the stage's seed unless ``seed`` is given) and loads the policy;
:meth:`TaskRun.act` is its deterministic action (Gaussian mean, or the argmax code of a discrete
head) clipped to the action bounds as PPO clips. Used by ``mocap render RUN_DIR``
(:mod:`mocap.task_video`) and ``mocap task-eval RUN_DIR`` (:mod:`mocap.task_eval`).
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mocap.errors import UserError
from mocap.runfiles import read_spec_file, read_stages


def is_task_target(path: Path) -> bool:
    """Whether ``path`` is a run directory with a finished task stage or an exported task directory
    (``spec.yaml`` naming a ``task:`` ``checkpoint:``, no ``stages.json``)."""
    path = Path(path)
    stage = task_stage(path)
    if stage is not None:
        return bool(stage.get("checkpoint"))
    spec_file = path / "spec.yaml"
    if not (path.is_dir() and spec_file.is_file()) or (path / "stages.json").exists():
        return False
    try:
        task = read_spec_file(spec_file).get("task")
    except UserError:
        return False
    return isinstance(task, dict) and isinstance(task.get("checkpoint"), str)


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


@dataclass
class TaskRun:
    """The reopened task stage: its env, policy, resolved spec and action bounds."""

    env: Any
    policy: Any
    resolved: Any
    bounds: tuple[float, float] | None
    policy_path: Path

    @torch.no_grad()
    def act(self, obs: Tensor) -> Tensor:
        action = self.policy.mean_action(obs)
        return action.clamp(*self.bounds) if self.bounds is not None else action

    @property
    def label(self) -> str:
        spec = self.resolved.spec
        return f"task {spec.task.name} through {spec.latent.name}"

    def close(self) -> None:
        self.env.close()


def open_task_run(run_dir: Path, num_envs: int = 1, seed: int | None = None, start_clips: list[str] | None = None) -> TaskRun:
    """Reopen the task stage of ``run_dir`` (module docstring); errors are one :class:`UserError`.
    ``start_clips``: episodes start from frames of these clips only (``motions.params.clips`` of the
    run's spec replaced; e.g. ``["walk", "run"]``, the locomotion starts of PULSE's speed task)."""
    from mocap.interfaces import StageResult
    from mocap.pipeline import derive_seed
    from mocap.plugins import get_plugins
    from mocap.spec import SpecError, load_spec

    run_dir = Path(run_dir)
    spec_file = run_dir / "spec.yaml"
    stage = task_stage(run_dir)
    exported = stage is None and spec_file.is_file() and not (run_dir / "stages.json").exists()
    if not exported and (stage is None or not stage.get("checkpoint")):
        raise UserError(f"{run_dir}: no finished task stage in stages.json (run it first)")
    plugins = get_plugins()
    try:
        overrides = None if start_clips is None else [f"motions.params.clips={json.dumps(list(start_clips))}"]
        resolved = load_spec(spec_file, plugins, overrides)  # relative checkpoint paths: to the spec file
    except SpecError as exc:
        raise UserError(str(exc)) from None
    spec = resolved.spec
    if exported:  # a `mocap export` directory: every stage's checkpoint named by spec.yaml
        if spec.task is None or spec.task.checkpoint is None:
            raise UserError(f"{spec_file}: no task checkpoint (an exported task run names task.checkpoint)")
        policy_path = Path(spec.task.checkpoint)
        sections = (("imitator", spec.imitator), ("latent", spec.latent))
        upstream = {name: StageResult(Path(sec.checkpoint)) for name, sec in sections if sec is not None and sec.checkpoint is not None}
        seed_default = derive_seed(int(spec.seed), "task")  # the seed the task stage ran with
    else:
        assert stage is not None
        policy_path = Path(stage["checkpoint"])
        upstream = {
            s["stage"]: StageResult(Path(s["checkpoint"]) if s.get("checkpoint") else None)
            for s in read_stages(run_dir / "stages.json")
            if s.get("stage") in ("imitator", "latent")
        }
        seed_default = int(stage.get("seed", 0))
    if not policy_path.is_file():
        raise UserError(f"{run_dir}: the task policy {policy_path} does not exist (moved?)")
    return open_task_stage(resolved, plugins, upstream, policy_path, num_envs, seed_default if seed is None else int(seed))


def open_task_stage(resolved: Any, plugins: Any, upstream: dict[str, Any], policy_path: Path, num_envs: int, seed: int) -> TaskRun:
    """The task env of a resolved spec (its frozen ``imitator``/``latent`` stages in ``upstream``)
    with ``num_envs`` envs, and the task policy at ``policy_path``: what :func:`open_task_run`
    builds from a run directory, and the ``eval_suite`` trainer from its pipeline stage."""
    from rich.console import Console

    from mocap.interfaces import Box
    from mocap.pipeline import StageContext
    from mocap.rl.networks import load_policy
    from mocap.runlog import MetricsLogger
    from mocap.task_env import make_task_env

    upstream = {k: v for k, v in upstream.items() if k in ("imitator", "latent")}
    with tempfile.TemporaryDirectory() as tmp:
        ctx = StageContext(
            stage="task", resolved=resolved, plugins=plugins, workdir=Path(tmp), run_dir=Path(tmp), upstream=upstream,
            log=MetricsLogger(Path(tmp) / "metrics.jsonl", "task", enabled=False), seed=int(seed),
            device=torch.device("cpu"), console=Console(stderr=True, quiet=True),
        )  # fmt: skip
        env = make_task_env(ctx, num_envs)
    try:
        policy = load_policy(policy_path)
    except BaseException:
        env.close()
        raise
    policy.eval()
    space = env.action_space
    bounds = (space.low, space.high) if isinstance(space, Box) and (space.low != float("-inf") or space.high != float("inf")) else None
    return TaskRun(env=env, policy=policy, resolved=resolved, bounds=bounds, policy_path=Path(policy_path))


__all__ = ["TaskRun", "is_task_target", "open_task_run", "open_task_stage", "task_stage"]
