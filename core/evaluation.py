"""Imitation evaluation (trainer ``imitation_eval``) and the built-in evaluation plugin.

The evaluator rolls out the spec's imitator on every clip of the motion set, from the clip's
first frame (reference-state initialization), one episode per clip and start, all episodes in
parallel simulator envs. An episode stops being recorded after it first exceeds the failure
threshold (mean body error, :data:`mocap.metrics.PROTOCOL`), after numerical instability, or at
its horizon (the clip's length, or ``horizon`` seconds for looping clips). Metrics are
computed per episode over the recorded frames and averaged per clip and overall.

Outputs: stage metrics (overall means), ``<run dir>/imitation_eval.md`` and ``.json`` (per clip),
and optionally a video of one clip with the reference drawn as a ghost.

This module holds the params, the registrations and the ``eval`` / ``report`` commands; the evaluator
lives in :mod:`mocap.imitation_eval` and the evaluation targets in :mod:`mocap.eval_targets` (imported
when used, so that loading the plugin imports no torch; their names are reachable from here too, e.g.
``mocap.evaluation.evaluate_imitator``).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, Optional

import typer
from pydantic import BaseModel, ConfigDict, Field

from mocap.generation import GenerationParams
from mocap.hooks import hookimpl
from mocap.metric_display import MetricInfo
from mocap.metric_params import BUILTIN_DISPLAY, BUILTIN_INFO, SuccessParams
from mocap.plugins import lazy

if TYPE_CHECKING:  # pragma: no cover
    from mocap.interfaces import Imitator


class ImitationEvalParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    num_envs: int = Field(64, ge=1, description="episodes simulated in parallel")
    horizon: float | None = Field(None, gt=0, description="seconds per episode for looping clips (None: one period of the clip)")
    threshold: float = Field(0.5, gt=0, description="failure threshold on the mean body error, m")
    success_exclude: list[str] = Field(
        default_factory=list,
        description="bodies left out of the success check (the mean body error against threshold); position errors "
        "still use every body. [P] (UHC's definition): all body joints; [C] PHC's evaluation on smpl: its 20 'eval "
        "bodies', i.e. [L_Toe, R_Toe, L_Hand, R_Hand] left out. Default: all bodies",
    )
    video: bool = Field(True, description="record a video of one clip with the reference as a ghost")
    video_clip: str | None = Field(None, description="clip to record (default: the first clip)")
    video_seconds: float = Field(4.0, gt=0)
    video_format: str = Field("mp4", pattern="^(mp4|gif)$")
    target: Literal["auto", "imitator", "latent"] = Field(
        "auto", description="what to evaluate: 'auto' = the latent space when the spec trains one (as an imitator, z = encoder mean), else the imitator"
    )


class TaskEvalParams(BaseModel):  # the ``task`` part of ``eval_suite`` (:mod:`mocap.task_eval`)
    model_config = ConfigDict(extra="forbid")
    num_envs: int = Field(64, ge=1, description="envs rolled out in parallel with the deterministic task policy")
    seconds: float = Field(10.0, gt=0, description="simulated time per env, s (episodes restart as in training)")
    video_seconds: float = Field(10.0, ge=0, description="video of env 0 over the first seconds, goals as markers (0: none)")


class EvalSuiteParams(BaseModel):  # the trainer ``eval_suite`` (:mod:`mocap.suite`)
    model_config = ConfigDict(extra="forbid")
    task: TaskEvalParams | None = Field(
        default_factory=TaskEvalParams, description="the task policy's deterministic rollouts (None: skip; skipped anyway without a task stage)"
    )
    imitation: ImitationEvalParams | None = Field(default_factory=ImitationEvalParams, description="imitation protocol on every clip (None: skip)")
    generation: GenerationParams | None = Field(
        default_factory=GenerationParams, description="random generation from the prior (None: skip; skipped anyway without a prior)"
    )


#: the task-independent metrics of a task policy's deterministic evaluation (:mod:`mocap.task_eval`);
#: the task's own metrics keep the task's declarations
TASK_EVAL_METRICS: dict[str, MetricInfo] = {
    "episodes_ended": MetricInfo("episodes ended"),
    "terminated_share": MetricInfo("terminated episodes (share)"),
    "envs_never_terminated": MetricInfo("envs without a fall"),
    "episode_return": MetricInfo("episode return"),
    "episode_length": MetricInfo("episode length", "steps"),
}


# ---------------------------------------------------------------------------- plugin hooks
class NoParams(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _make_pd_replay(params: NoParams, **_: Any) -> Imitator:
    from mocap.baselines import PDReplay

    return PDReplay()


_make_metric = lazy("mocap.metrics:make_metric")
_success_metric = lazy("mocap.metrics:_success_metric")


#: the imitation protocol's aggregate metrics (each built-in metric also as ``<name>_succ``: its mean
#: over the tracked clips), declared with the trainers below
IMITATION_METRICS: dict[str, MetricInfo] = {
    "success_rate": MetricInfo("success rate"),
    "succeeded": MetricInfo("clips tracked"),
    "total": MetricInfo("clips"),
    "tracked_s": MetricInfo("tracked time", "s"),
    "unstable_episodes": MetricInfo("unstable episodes"),
    **{f"{k}_succ": MetricInfo(f"{v.display} (tracked)", v.unit) for k, v in BUILTIN_DISPLAY.items() if not k.startswith("success")},
}


@hookimpl
def register_trainers(register):  # type: ignore[no-untyped-def]
    register(
        "imitation_eval",
        lazy("mocap.imitation_eval:ImitationEval"),
        params=ImitationEvalParams,
        description="evaluate an imitator on every clip",
        metrics=IMITATION_METRICS,
    )
    register(
        "eval_suite",
        lazy("mocap.suite:EvalSuite"),
        params=EvalSuiteParams,
        description="imitation + random generation + the task stage's metrics of one cell, in one eval stage (comparisons)",
        metrics={**IMITATION_METRICS, **TASK_EVAL_METRICS},
    )


@hookimpl
def register_imitators(register):  # type: ignore[no-untyped-def]
    register("pd_replay", _make_pd_replay, params=NoParams, description="baseline: PD targets = the next reference pose")


@hookimpl
def register_commands(app):  # type: ignore[no-untyped-def]
    @app.command("report")
    def report_cmd(
        run_dir: Annotated[Path, typer.Argument(help="a run directory (runs/<name> or runs/<name>/<cell>) or a comparison directory")],
    ) -> None:
        """Rewrite report.md (learning curves, metrics, per-clip tables, videos) of a run, or comparison.md of a comparison."""
        from mocap.report import report_command

        report_command(run_dir)

    @app.command("eval")
    def eval_command(
        target: Annotated[
            Path, typer.Argument(help="a checkpoint (policy.pt, latent.pt), a checkpoint directory (checkpoints/<name>), a run directory or a spec")
        ],
        motions: Annotated[Optional[str], typer.Option("--motions", help="evaluate on this motion source instead of the training one (default params)")] = None,
        json_out: Annotated[Optional[Path], typer.Option("--json", help="write the result table as JSON")] = None,
        video: Annotated[Optional[Path], typer.Option("--video", help="write one video per clip (reference as a ghost) here")] = None,
        loop: Annotated[Optional[float], typer.Option("--loop", help="robustness protocol: looping clips keep cycling for this many seconds")] = None,
        num_envs: Annotated[int, typer.Option(help="clips simulated in parallel")] = 64,
        imitator_only: Annotated[bool, typer.Option("--imitator-only", help="for a latent space: evaluate the imitator it was distilled from instead")] = False,
    ) -> None:
        """Evaluate an imitator or a latent space with the imitation protocol (each clip from its first frame, deterministic)."""
        import json

        from rich.console import Console
        from rich.table import Table

        from mocap.eval_targets import build_evaluation_target, load_evaluation_target
        from mocap.imitation_eval import _cell, compare_tables, evaluate_imitator, record_video, render_comparison
        from mocap.metrics import PROTOCOL, default_metrics
        from mocap.paths import check_output_dir, check_output_file, safe_filename, write_output_text
        from mocap.plugins import get_plugins

        check_eval_options(num_envs, loop)
        if json_out is not None:  # output paths before any evaluation runs
            check_output_file(json_out, "--json")
        if video is not None:
            check_output_dir(video, "--video")
        console = Console(stderr=True)
        plugins = get_plugins()
        target_info = load_evaluation_target(target, plugins)
        loaded = build_evaluation_target(target_info, plugins, motions=motions, use_latent=not imitator_only)
        spec, lib, imitator, make_sim = target_info.spec, loaded.library, loaded.policy, loaded.make_sim
        if loaded.own_tracker:
            what = f"{spec.latent.name} (its own tracking policy)"
        else:
            what = f"{spec.latent.name} latent (z = encoder mean)" if loaded.latent is not None else spec.imitator.name
        checkpoint = target_info.latent_checkpoint if loaded.latent is not None else target_info.imitator_checkpoint

        params = ImitationEvalParams(num_envs=num_envs, horizon=loop, video=False)
        table = evaluate_imitator(imitator, lib, make_sim, params, default_metrics(), console)
        table["checkpoint"] = str(checkpoint) if checkpoint else None
        table["evaluated"] = what
        units = table["units"]
        cols = [c for c in units if c != "success"]
        out = Table(title=f"{what} on {len(lib.clip_names)} clips ({table['horizon']})")
        for col in ["clip", "success", "tracked s", *[f"{c} ({units[c]})" for c in cols]]:
            out.add_column(col, justify="left" if col == "clip" else "right")
        for name, row in table["clips"].items():
            out.add_row(name, "yes" if row["success"] else "[red]no[/]", _cell(row["tracked_s"]), *[_cell(row.get(c)) for c in cols])
        agg = table["aggregate"]
        out.add_row("[bold]all clips", f"{agg['succeeded']}/{agg['total']}", _cell(agg["tracked_s"]), *[_cell(agg.get(c)) for c in cols])
        out.add_row("[bold]successful", "", "", *[_cell(agg.get(f"{c}_succ")) for c in cols])
        stdout = Console(width=None if sys.stdout.isatty() else 160)
        stdout.print(out)
        stdout.print(f"success rate {100 * agg['success_rate']:.1f}% ({agg['succeeded']}/{agg['total']}); {PROTOCOL}")
        if target_info.code_note is not None:  # the checkpoint's recorded plugin code against the installed code
            console.print(f"note: {target}: {target_info.code_note}", style="yellow", markup=False, highlight=False, soft_wrap=True)
        if loaded.latent is not None and spec.imitator is not None and loaded.imitator is not loaded.policy:
            # PULSE Table 1 layout: the latent next to the imitator it was distilled from.
            teacher = evaluate_imitator(loaded.imitator, lib, make_sim, params, default_metrics(), console)
            table["imitator"] = teacher
            table["comparison"] = compare_tables(teacher, table)
            stdout.print(render_comparison({spec.imitator.name + " (teacher)": teacher, what: table}, table["comparison"], console_table=True))
        if json_out is not None:
            write_output_text(json_out, json.dumps(table, indent=2) + "\n", "--json")
            stdout.print(f"wrote {json_out}")
        if video is not None:
            for name in lib.clip_names:
                seconds = loop if (loop and bool(lib.loops[lib.clip_index(name)])) else float(lib.durations[lib.clip_index(name)])
                path = record_video(imitator, lib, make_sim, name, seconds, video / f"{safe_filename(name)}.mp4")
                if path is None:
                    console.print("[yellow]videos skipped[/]: the simulator cannot render")
                    break
                console.print(f"video: {path}")


def check_eval_options(num_envs: int, loop: float | None) -> None:
    """``mocap eval``'s counts, checked before anything loads: one :class:`~mocap.errors.UserError`
    line naming the option (not the protocol params' validation error)."""
    import math

    from mocap.errors import UserError

    if num_envs < 1:
        raise UserError(f"--num-envs {num_envs}: give the number of clips simulated in parallel, at least 1")
    if loop is not None and not (math.isfinite(loop) and loop > 0):
        raise UserError(f"--loop {loop}: give the seconds looping clips keep cycling, a positive finite number")


@hookimpl
def register_metrics(register):  # type: ignore[no-untyped-def]
    for name, (_, description) in BUILTIN_INFO.items():
        register(name, lambda name=name: _make_metric(name), description=description, metrics={name: BUILTIN_DISPLAY[name]})
    for name, reduce, what in (
        ("success", "mean", "no frame over the mean-error threshold"),
        ("success_linf", "max", "no frame with any body over the threshold"),
    ):
        register(
            name,
            lambda params, reduce=reduce: _success_metric(params, reduce),
            params=SuccessParams,
            description=what,
            metrics={name: BUILTIN_DISPLAY[name]},
        )


#: names defined in :mod:`mocap.imitation_eval` and :mod:`mocap.eval_targets`, reachable from here too (imported on first use)
_MOVED = {
    **dict.fromkeys(
        ("ImitationEval", "Rollout", "compare_tables", "episode_frames", "evaluate_imitator", "record_video", "render_comparison")
        + ("render_table", "rollout_imitation", "success_bodies"),
        "mocap.imitation_eval",
    ),
    **dict.fromkeys(("EvalTarget", "LoadedTarget", "build_evaluation_target", "check_trained_humanoid", "load_evaluation_target"), "mocap.eval_targets"),
}


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["IMITATION_METRICS", "EvalSuiteParams", "ImitationEvalParams", "NoParams"]
