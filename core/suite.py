"""Trainer ``eval_suite``: several evaluations of one cell in one ``eval`` stage.

A comparison (``matrix:``) tabulates each cell's *final* stage metrics. To put imitation, random
generation and a task side by side for every latent space (the quickstart), the ``eval`` stage runs:

* ``imitation`` (:class:`~mocap.imitation_eval.ImitationEval`): the latent space's decoder with
  ``z`` = encoder mean, or the imitator itself when the cell has no trained latent (``scratch``);
* ``generation`` (:class:`~mocap.generation_eval.GenerationEval`): rollouts of the latent space's prior;
  skipped, and said so, for a latent space without one (``scratch``);
The task stage's own metrics (normalized return, ...) sit next to these in a comparison already
(``comparison.md`` collects every stage's final metrics). Metrics are prefixed ``imitation/`` and
``generation/``; each part also publishes its own files (``imitation_eval.md``, ``generation.md``,
videos) in the run directory.
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
        return StageResult(checkpoint=None, metrics=metrics)


__all__ = ["EvalSuite", "EvalSuiteParams", "has_prior"]
