"""Random generation from a latent space's prior, and its metrics (``mocap generate``, trainer ``generation_eval``).

Neither PULSE nor the hybrid-RVQ paper defines one protocol (PULSE Sec. 5.3 and Fig. 3f: qualitative
only; hybrid-RVQ Sec. 6.2, Eq. 8: motion-matching distance, filtered share and coverage). This module measures both
kinds on the same rollouts:

* **Rollouts.** ``num_rollouts`` envs start from reference states of the motion library (clip and
  time drawn with the library's weights), skipping starts where a non-foot body origin is below
  ``start_min_height`` (lying down is already a fall); ``start_clips`` (``mocap generate --start-clips
  walk,run``) draws the starts from those clips only (neither paper names its start states).
  ``falls_by_start_clip`` breaks the falls down by the clip each rollout started in. Each control step the latent space draws an
  action from its prior with no reference motion at all: the observation is the imitator's
  proprioception only (the goal is dropped), and the latent's ``random_action(obs, noise_scale,
  generator)`` (PULSE: ``z = μ_p + noise·σ_p·ε``; hybrid: uniformly random codes [+ prior]) is
  decoded into PD targets. That needs a decoder that outputs PD targets (distilled with
  ``label: pd_targets``) or a teacher whose actions need no reference (PHC ``action: absolute``);
  a residual teacher is refused.
* **Falls.** A rollout has fallen at the first step at which a body other than the feet touches
  the ground *and* is below ``fall_height`` (PULSE's code: contact and height < 0.15 m).
  Rollouts go on after a fall (getting up counts); ``fall_rate`` is the share that fell at least
  once, ``time_to_fall_s`` the mean time of the first fall over those that fell,
  ``survival_s`` the same with non-fallen rollouts counted at the horizon, ``down_at_end`` the
  share that is fallen at the last step.
* **Diversity** (APD-style): the mean over rollout pairs of the mean over steps and bodies of the
  distance between their body positions, each trajectory first expressed in its own start frame
  (start root position on the ground and heading removed), so that where and which way a rollout
  started does not count as diversity.
* **Motion matching** (hybrid_rvq Eq. 8): each generated transition ``(s_{t-1}, s_t)`` of
  proprioceptive states is matched to its nearest dataset transition (the library's frames at the
  control rate), features standardized by the dataset's mean and std; ``match_distance`` is the
  mean squared distance over the kept transitions; a transition is *filtered* when its distance per
  feature dimension exceeds ``filter_threshold`` (the paper gives no value: [DEFAULT] ours);
  ``coverage`` is the share of dataset transitions that are the nearest neighbour of at least one
  kept generated transition.

This module holds the params, the registration and the command; the rollouts and metrics live in
:mod:`mocap.generation_eval` (imported when used, so that loading the plugin imports no torch; its
names are reachable from here too, e.g. ``mocap.generation.evaluate_generation``).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from pydantic import BaseModel, ConfigDict, Field

from mocap.hooks import hookimpl
from mocap.metric_display import MetricInfo
from mocap.plugins import lazy


class GenerationParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    num_rollouts: int = Field(64, ge=2, description="rollouts (all simulated in parallel)")
    seconds: float = Field(10.0, gt=0, description="length of each rollout, s")
    noise_scale: float = Field(1.0, ge=0, description="scale of the prior noise (PULSE: σ_p multiplier; 0 = prior mean)")
    fall_height: float = Field(0.15, gt=0, description="a non-foot body touching the ground below this height is a fall, m ([CODE] PULSE 0.15)")
    start_min_height: float = Field(0.25, ge=0, description="skip start frames with a non-foot body origin below this, m")
    filter_threshold: float = Field(
        1.0, gt=0, description="motion matching: a transition is filtered when its squared distance per feature exceeds this ([DEFAULT]; not in the paper)"
    )
    start_clips: Optional[list[str]] = Field(
        None, min_length=1, description="draw the start frames from these clips only (default: every clip, with its sampling weight)"
    )
    seed: int = Field(0, description="seed of the start states and the prior noise")
    video_rollouts: int = Field(4, ge=0, description="rollouts recorded one after another in the video (0: none)")
    video_seconds: float = Field(5.0, gt=0, description="seconds of each recorded rollout")


# ------------------------------------------------------------------------------ registration


#: the generation protocol's metrics: name -> how reports show it (declared with the trainer below)
GENERATION_METRICS: dict[str, MetricInfo] = {
    "fall_rate": MetricInfo("fall rate"),
    "time_to_fall_s": MetricInfo("time to fall", "s"),
    "survival_s": MetricInfo("survival time", "s"),
    "diversity_m": MetricInfo("diversity", "m"),
    "match_distance": MetricInfo("motion-matching distance"),
    "filtered": MetricInfo("filtered share"),
    "coverage": MetricInfo("clip coverage"),
}
GENERATION_COLUMNS = (
    ("fall_rate", "share"),
    ("time_to_fall_s", "s"),
    ("survival_s", "s"),
    ("diversity_m", "m"),
    ("match_distance", ""),
    ("filtered", "share"),
    ("coverage", "share"),
)


def render_falls_by_start_clip(result: dict[str, Any]) -> str:
    """A markdown table of one result's ``falls_by_start_clip`` (empty when it has none)."""
    rows = result.get("falls_by_start_clip") or {}
    if not rows:
        return ""
    lines = ["| start clip | rollouts | fell | time to fall (s) | down at the end |", "|---|---|---|---|---|"]
    for clip, r in rows.items():
        t = r.get("time_to_fall_s")
        lines.append(f"| {clip} | {r['rollouts']} | {r['falls']} | {'-' if t is None else f'{t:.2f}'} | {r['down_at_end']} |")
    return "\n".join(["Falls by start clip:", "", *lines, ""])


def render_generation(results: dict[str, dict[str, Any]]) -> str:
    """A markdown table, one row per latent space."""
    head = ["latent", *[f"{c} ({u})" if u else c for c, u in GENERATION_COLUMNS]]
    lines = [
        "# Random generation from the prior",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for name, r in results.items():
        lines.append("| " + " | ".join([name, *[f"{r[c]:.3g}" for c, _ in GENERATION_COLUMNS]]) + " |")
    any_r = next(iter(results.values()))
    lines += ["", f"{any_r['num_rollouts']} rollouts of {any_r['seconds']:.3g} s; {any_r['protocol']}", ""]
    return "\n".join(lines)


@hookimpl
def register_trainers(register):  # type: ignore[no-untyped-def]
    register(
        "generation_eval",
        lazy("mocap.generation_eval:GenerationEval"),
        params=GenerationParams,
        description="random generation from a trained latent space's prior: falls, diversity, motion matching, video",
        metrics=GENERATION_METRICS,
    )


@hookimpl
def register_commands(app):  # type: ignore[no-untyped-def]
    @app.command("generate")
    def generate_command(
        target: Annotated[Path, typer.Argument(help="a latent checkpoint (latent.pt), a checkpoint directory, a run directory or a spec")],
        rollouts: Annotated[int, typer.Option("--rollouts", help="rollouts simulated in parallel")] = 64,
        seconds: Annotated[float, typer.Option("--seconds", help="length of each rollout, s")] = 10.0,
        noise: Annotated[float, typer.Option("--noise", help="prior noise scale")] = 1.0,
        seed: Annotated[int, typer.Option("--seed")] = 0,
        start_clips: Annotated[Optional[str], typer.Option("--start-clips", help="comma-separated clips the rollouts start from (default: every clip)")] = None,
        json_out: Annotated[Optional[Path], typer.Option("--json", help="write the metrics as JSON")] = None,
        video: Annotated[Optional[Path], typer.Option("--video", help="write a video of the first rollouts (mp4 or gif)")] = None,
    ) -> None:
        """Roll out random motion from a latent space's prior and report falls, diversity and motion matching."""
        import json

        from rich.console import Console

        from mocap.errors import UserError
        from mocap.eval_targets import build_evaluation_target, load_evaluation_target
        from mocap.generation_eval import generate_from_target
        from mocap.paths import check_output_file, write_output_text
        from mocap.plugins import get_plugins
        from mocap.task_eval import split_clips

        if json_out is not None:  # output paths before the rollouts
            check_output_file(json_out, "--json")
        if video is not None:
            check_output_file(video, "--video", video=True)
        console = Console(stderr=True)
        plugins = get_plugins()
        target_info = load_evaluation_target(target, plugins)
        if target_info.latent_checkpoint is None:
            raise UserError(f"{target}: not a latent space (generation samples a latent space's prior)")
        loaded = build_evaluation_target(target_info, plugins)
        clips = None if start_clips is None else split_clips(start_clips)
        if clips is not None and not clips:
            raise UserError("--start-clips needs at least one clip name")
        params = GenerationParams(num_rollouts=rollouts, seconds=seconds, noise_scale=noise, seed=seed, start_clips=clips)
        try:
            result = generate_from_target(loaded, params, video=video, console=console)
        except ValueError as exc:
            raise UserError(str(exc)) from None
        result["checkpoint"] = str(target_info.latent_checkpoint)
        print(render_generation({target_info.spec.latent.name: result}))
        print(render_falls_by_start_clip(result))
        if json_out is not None:
            write_output_text(json_out, json.dumps(result, indent=2) + "\n", "--json")
            console.print(f"wrote {json_out}")
        if result.get("video"):
            console.print(f"video: {result['video']}")


#: names defined in :mod:`mocap.generation_eval`, reachable from here too (imported on first use)
_MOVED = (
    "GenerationEval",
    "dataset_transitions",
    "evaluate_generation",
    "generate_from_target",
    "fallen_down",
    "heading_frame",
    "in_start_frame",
    "motion_matching",
    "pairwise_diversity",
    "start_states",
)


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        return getattr(importlib.import_module("mocap.generation_eval"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["GENERATION_METRICS", "GenerationParams", "render_generation"]
