"""Hierarchical control: the ``hierarchy`` plugin registers the ``scratch`` latent space (the no-latent
baseline: the task action is the normalized PD target) and defines its params.

The task env (a task policy acting in the task action space of any latent space, the ``task``
stage's RL env) and ``scratch``'s module live in :mod:`mocap.task_env`, imported only when a spec
builds them: loading this plugin imports no torch. Their names are still reachable here
(``mocap.hierarchy.TaskEnv``). The plugin's command ``mocap task-eval RUN_DIR`` evaluates a trained
task policy deterministically (:mod:`mocap.task_eval`).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from pydantic import BaseModel, ConfigDict, Field

from mocap.hooks import hookimpl
from mocap.plugins import lazy


# ---------------------------------------------------------------------------------- scratch
class ScratchParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    range_scale: float = Field(1.0, gt=0, description="a = ±1 reaches this fraction of each joint's half range around its midpoint (PHC absolute map: 1.0)")


@hookimpl
def register_latent_spaces(register):  # type: ignore[no-untyped-def]
    register(
        "scratch",
        lazy("mocap.task_env:make_scratch"),
        params=ScratchParams,
        description="no latent space: task actions are normalized PD targets (baseline)",
    )


@hookimpl
def register_commands(app):  # type: ignore[no-untyped-def]
    @app.command("task-eval")
    def task_eval_command(
        run_dir: Annotated[Path, typer.Argument(help="a run directory with a finished task stage")],
        envs: Annotated[int, typer.Option("--envs", help="envs rolled out in parallel")] = 64,
        seconds: Annotated[float, typer.Option("--seconds", help="simulated time per env, s")] = 10.0,
        seed: Annotated[Optional[int], typer.Option("--seed", help="start states and goals (default: the stage's seed)")] = None,
        json_out: Annotated[Optional[Path], typer.Option("--json", help="write the metrics as JSON")] = None,
        start_clips: Annotated[
            Optional[str], typer.Option("--start-clips", help="comma-separated clips to start episodes from (default: the run's motion set)")
        ] = None,
    ) -> None:
        """Evaluate a trained task policy with its deterministic action: the task's metrics in units, falls, episodes."""
        import json

        from mocap.errors import UserError
        from mocap.paths import check_output_file, write_output_text
        from mocap.task_eval import evaluate_task, render_task_eval, split_clips

        if json_out is not None:  # before the rollouts
            check_output_file(json_out, "--json")
        try:
            clips = None if start_clips is None else split_clips(start_clips)
            result = evaluate_task(run_dir, num_envs=envs, seconds=seconds, seed=seed, start_clips=clips)
        except ValueError as exc:
            raise UserError(str(exc)) from None
        print(render_task_eval(result))
        policy = Path(result["policy"]).resolve()
        if policy.is_relative_to(Path.cwd().resolve()):  # a committed result names no path of this machine
            result["policy"] = str(policy.relative_to(Path.cwd().resolve()))
        if json_out is not None:
            write_output_text(json_out, json.dumps(result, indent=2) + "\n", "--json")
            print(f"wrote {json_out}")


#: names defined in :mod:`mocap.task_env`, reachable from here too (imported on first use)
_MOVED = ("STATE_FORMAT", "ScratchLatent", "TaskEnv", "make_scratch", "make_task_env")


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        return getattr(importlib.import_module("mocap.task_env"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ScratchParams"]
