"""Deterministic evaluation of a trained task policy: ``mocap task-eval RUN_DIR``.

Training logs a task's metrics from its exploring rollouts; this measures the policy a user gets.
:func:`evaluate_task` reopens the task stage of a run directory with ``num_envs`` envs
(:func:`mocap.task_run.open_task_run`), rolls the task policy out with its deterministic action for
``seconds`` of simulated time, episodes restarting as in training (on termination, e.g. a fall, or
at the episode length), and reports:

* the task's own metrics over every env step of the window (:meth:`Task.metrics`, in the task's
  units: ``speed_error`` in m/s for ``speed``, ``success_rate`` and distances in m for ``reach``, ...);
* ``episodes_ended``: episodes that ended in the window; ``terminated_share``: the share of those that
  ended by termination (for every built-in task a fall, or an unstable step);
* ``envs_never_terminated``: the share of the envs that ran the whole window without a termination;
* ``episode_return`` / ``episode_length`` (control steps): means over the ended episodes (NaN if none);
* ``env_steps``, ``seconds``, ``num_envs``, ``seed``, ``start_clips`` (None: the spec's motions);
* how natural the motion is (:mod:`mocap.naturalness`): ``mm_distance`` and ``mm_within`` (motion
  matching against the run's motion set at the control rate; with ``start_clips``, those clips),
  ``foot_skating`` (m/s), ``root_jerk`` (m/s³), ``crouch_share``, and ``realism`` when the committed
  judge fits the humanoid (:func:`realism_judge`).

``start_clips`` (``mocap task-eval --start-clips walk,run``) starts every episode from frames of those
clips instead of the run's motion set: a policy trained from every clip's frames can be measured from
PULSE's locomotion starts (and one trained from those, from every clip's), so that two policies
trained from different starts are compared on the same ones.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import torch

from mocap.metric_display import MetricInfo

from mocap.generation_eval import dataset_transitions
from mocap.naturalness import NaturalnessRecorder
from mocap.task_run import TaskRun, open_task_run


def split_clips(text: str) -> list[str]:
    """The clip names of a comma-separated list (``"walk, run"`` -> ``["walk", "run"]``; blanks dropped)."""
    return [c.strip() for c in text.split(",") if c.strip()]


def evaluate_task(run_dir: Path, *, num_envs: int = 64, seconds: float = 10.0, seed: int | None = None, start_clips: list[str] | None = None) -> dict[str, Any]:
    """The metrics of the module docstring for the task policy of ``run_dir``."""
    if num_envs < 1 or not seconds > 0:
        raise ValueError(f"task-eval needs num_envs >= 1 and seconds > 0, got {num_envs} and {seconds}")
    if start_clips is not None and not start_clips:
        raise ValueError("task-eval --start-clips needs at least one clip name")
    run = open_task_run(Path(run_dir), num_envs, seed, start_clips)
    try:
        result = evaluate_task_run(run, seconds=seconds)
    finally:
        run.close()
    result["seed"] = seed
    result["start_clips"] = start_clips
    return result


def evaluate_task_run(run: TaskRun, *, seconds: float = 10.0, video: Path | None = None, video_seconds: float = 10.0) -> dict[str, Any]:
    """:func:`evaluate_task` on an opened task stage (its env's ``num_envs``), recording env 0 for the
    first ``video_seconds`` into ``video`` when given (goals as markers, as ``mocap render``)."""
    env = run.env
    num_envs = int(env.num_envs)
    steps = max(1, int(round(seconds / float(env.sim.dt))))
    recorder = env.sim.make_recorder() if video is not None else None
    rec_steps = min(steps, int(round(video_seconds / float(env.sim.dt)))) if recorder is not None else 0
    obs = env.reset()
    env.task.metrics()  # drop anything the reset accumulated
    dataset = dataset_transitions(env.library, float(env.sim.dt), env.sixd)
    natural = NaturalnessRecorder(env.skeleton, dataset, float(env.sim.dt), sixd=env.sixd, judge=realism_judge(env.skeleton.name, dataset.shape[1]))
    natural.add(env.sim.state)
    ever_terminated = torch.zeros(num_envs, dtype=torch.bool)
    returns: list[torch.Tensor] = []
    lengths: list[torch.Tensor] = []
    ended = terminated = 0
    for t in range(steps):
        result = env.step(run.act(obs))
        obs = result.obs
        if t < rec_steps:
            assert recorder is not None
            recorder.add_frame(env.sim.state, markers=env.task.markers(0))
        term = result.terminated.bool().cpu()
        done = term | result.truncated.bool().cpu()
        ever_terminated |= term
        natural.add(env.sim.state, fresh=done)  # a finished env's state is already its next episode's first
        ended += int(done.sum())
        terminated += int(term.sum())
        if "return" in result.episodes:
            returns.append(result.episodes["return"].double().reshape(-1))
            lengths.append(result.episodes["length"].double().reshape(-1))
    task_metrics = {k: float(v) for k, v in env.task.metrics().items()}
    dt = float(env.sim.dt)
    ret = torch.cat(returns) if returns else torch.zeros(0, dtype=torch.float64)
    length = torch.cat(lengths) if lengths else torch.zeros(0, dtype=torch.float64)
    spec = run.resolved.spec
    out: dict[str, Any] = {
        "task": spec.task.name,
        "latent": spec.latent.name,
        "policy": str(run.policy_path),
        **task_metrics,
        "episodes_ended": ended,
        "terminated_share": terminated / ended if ended else 0.0,
        "envs_never_terminated": float((~ever_terminated).float().mean()),
        "episode_return": float(ret.mean()) if ret.numel() else math.nan,
        "episode_length": float(length.mean()) if length.numel() else math.nan,
        "env_steps": steps * num_envs,
        "seconds": steps * dt,
        "num_envs": num_envs,
        **natural.result(),
        "protocol": "deterministic task policy (mean action), episodes restart on termination or at the episode length",
    }
    if recorder is not None and video is not None and rec_steps:
        recorder.save(video)
        out["video"] = str(video)
    return out


def realism_judge(humanoid: str, feature_dim: int) -> Any:
    """The committed realism judge (``checkpoints/realism_judge/judge.pt``, :mod:`mocap.realism`) when
    it is there and was trained on this humanoid's features (the ``amp`` humanoid); else None."""
    from mocap.realism import default_judge_path, load_judge

    path = default_judge_path()
    if humanoid != "amp" or not path.is_file():
        return None
    judge = load_judge(path)
    return judge if judge.feature_dim == feature_dim else None


def render_task_eval(result: dict[str, Any], declared: Mapping[str, MetricInfo] | None = None) -> str:
    """A Markdown table of one :func:`evaluate_task` result: each row's display name and unit (the
    task's declared metrics and task-eval's own rows, :func:`mocap.metric_display.metric_label`), its
    key and its value. ``declared``: the installed plugins' declarations when None."""
    from mocap.metric_display import metric_label

    skip = {"task", "latent", "policy", "protocol", "seed", "video", "start_clips"}
    rows = []
    for key, value in result.items():
        if key in skip:
            continue
        label = metric_label(key, declared)
        shown = f"{value:.4g}" if isinstance(value, float) else str(value)
        rows.append(f"| {label} | `{key}` | {shown} |")
    head = f"task {result['task']} through {result['latent']} ({result['protocol']})"
    return "\n".join([head, "", "| metric | key | value |", "|---|---|---|", *rows, ""])


__all__ = ["evaluate_task", "evaluate_task_run", "render_task_eval", "split_clips"]
