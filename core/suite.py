"""Trainer ``eval_suite``: several evaluations of one cell in one ``eval`` stage.

A comparison (``matrix:``) tabulates each cell's *final* stage metrics. To put imitation, random
generation and a task side by side for every latent space (the quickstart), the ``eval`` stage runs:

* ``imitation`` (:class:`~mocap.imitation_eval.ImitationEval`): the latent space's decoder with
  ``z`` = encoder mean, or the imitator itself when the cell has no trained latent (``scratch``);
* ``generation`` (:class:`~mocap.generation_eval.GenerationEval`): rollouts of the latent space's prior;
  skipped, and said so, for a latent space without one (``scratch``);
* ``task`` (:func:`~mocap.task_eval.evaluate_task_run`): when the cell has a task stage, its policy
  with its deterministic action (what ``mocap task-eval`` reports: the task's metrics in units,
  terminations, episodes) and a video of env 0 with the goal as markers (``task.mp4``).
The task stage's own metrics (normalized return, ... from its exploring rollouts) sit next to these in
a comparison already (``comparison.md`` collects every stage's final metrics). Metrics are prefixed
``imitation/``, ``generation/`` and ``task_eval/``; each part also publishes its own files
(``imitation_eval.md``, ``generation.md``, ``task_eval.md``, videos) in the run directory.
"""

from __future__ import annotations

from typing import Any

from mocap.evaluation import EvalSuiteParams
from mocap.generation_eval import GenerationEval
from mocap.imitation_eval import ImitationEval
from mocap.interfaces import StageResult, Trainer


def has_prior(ctx: Any) -> bool:
    """The cell's latent space is trained and can sample its prior (``random_action``)."""
    stage = ctx.upstream.get("latent")
    if stage is None or stage.checkpoint is None:
        return False
    latent = ctx.stage_component("latent", checkpoint=stage.checkpoint)
    return bool(latent.samples_prior)


class EvalSuite(Trainer):
    """Trainer ``eval_suite`` (module docstring)."""

    def __init__(self, params: EvalSuiteParams | None = None):
        self.params = params or EvalSuiteParams()

    def run(self, ctx: Any) -> StageResult:
        p = self.params
        metrics: dict[str, float] = {}
        if p.imitation is not None:
            res = ImitationEval(p.imitation).run(ctx)
            metrics.update({f"imitation/{k}": v for k, v in res.metrics.items()})
        if p.generation is not None:
            if has_prior(ctx):
                res = GenerationEval(p.generation).run(ctx)
                metrics.update({f"generation/{k}": v for k, v in res.metrics.items()})
            else:
                name = ctx.spec.latent.name if ctx.spec.latent is not None else "none"
                ctx.console.print(f"eval_suite: no random generation for latent {name!r} (no trained prior)")
        task = ctx.upstream.get("task")
        if p.task is not None and task is not None and task.checkpoint is not None:
            metrics.update({f"task_eval/{k}": v for k, v in self._task(ctx, task.checkpoint).items()})
        return StageResult(checkpoint=None, metrics=metrics)

    def _task(self, ctx: Any, policy: Any) -> dict[str, float]:
        from pathlib import Path

        from mocap.task_eval import evaluate_task_run, render_task_eval
        from mocap.task_run import open_task_stage

        p = self.params.task
        assert p is not None
        run = open_task_stage(ctx.resolved, ctx.plugins, ctx.upstream, Path(policy), p.num_envs, ctx.seed)
        try:
            video = ctx.publish("task.mp4") if p.video_seconds > 0 else None
            result = evaluate_task_run(run, seconds=p.seconds, video=video, video_seconds=p.video_seconds)
        finally:
            run.close()
        if video is not None and "video" not in result:
            ctx.console.print(f"eval_suite: the {type(run.env.sim).__name__} simulator cannot render videos; no task.mp4")
        ctx.publish("task_eval.md").write_text(render_task_eval(result))
        return {k: float(v) for k, v in result.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


__all__ = ["EvalSuite", "EvalSuiteParams", "has_prior"]
