"""Imitation evaluation (trainer ``imitation_eval``) and the built-in evaluation plugin.

The evaluator rolls out the spec's imitator on every clip of the motion set, from the clip's
first frame (reference-state initialization), one episode per clip and start, all episodes in
parallel simulator envs. An episode stops being recorded after it first exceeds the failure
threshold (mean body error, :data:`mocap.metrics.PROTOCOL`), after numerical instability, or at
its horizon (the clip's length, or ``horizon`` seconds for looping clips). Metrics are
computed per episode over the recorded frames and averaged per clip and overall.

Outputs: stage metrics (overall means), ``<run dir>/imitation_eval.md`` and ``.json`` (per clip),
and optionally a video of one clip with the reference drawn as a ghost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from pydantic import BaseModel, ConfigDict, Field
from rich.progress import Progress

from mocap.baselines import PDReplay
from mocap.checkpoint import atomic_write_json, atomic_write_text
from mocap.hooks import hookimpl
from mocap.interfaces import Imitator, Metric, Simulator, StageResult, Trainer
from mocap.metrics import BUILTIN_METRICS, PROTOCOL, SuccessParams, _success_metric, default_metrics, make_metric
from mocap.motion.library import MotionLibrary
from mocap.state import Trajectories


class ImitationEvalParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    num_envs: int = Field(64, ge=1, description="episodes simulated in parallel")
    horizon: float | None = Field(
        None, gt=0, description="seconds per episode for looping clips (None: one period of the clip)"
    )
    threshold: float = Field(0.5, gt=0, description="failure threshold on the mean body error, m")
    video: bool = Field(True, description="record a video of one clip with the reference as a ghost")
    video_clip: str | None = Field(None, description="clip to record (default: the first clip)")
    video_seconds: float = Field(4.0, gt=0)
    video_format: str = Field("mp4", pattern="^(mp4|gif)$")


@dataclass
class Rollout:
    """Recorded episodes: trajectories, which clip each episode played, and instability counts."""

    traj: Trajectories
    clip_ids: torch.Tensor
    unstable: torch.Tensor


def rollout_imitation(
    sim: Simulator,
    lib: MotionLibrary,
    imitator: Imitator,
    clip_ids: torch.Tensor,
    frames: torch.Tensor,
    *,
    threshold: float,
    recorder: Any = None,
    progress: Any = None,
) -> Rollout:
    """Roll ``imitator`` out in ``sim`` (N = len(clip_ids) envs) for ``frames`` (N,) control steps each.

    Frame 0 is the reset state; frame k the state after k steps, compared with the reference at
    time k * dt.
    """
    n = len(clip_ids)
    dt = sim.dt
    zeros = torch.zeros(n, dtype=lib.dtype, device=lib.device)
    ref = lib.frames(clip_ids, zeros)
    sim.reset(torch.arange(n), ref)
    state = sim.state
    T = int(frames.max().item()) + 1
    sim_pos = torch.zeros(T, n, sim.skeleton.num_bodies, 3)
    ref_pos = torch.zeros_like(sim_pos)
    mask = torch.zeros(T, n, dtype=torch.bool)
    alive = torch.ones(n, dtype=torch.bool)
    unstable = torch.zeros(n, dtype=torch.bool)
    sim_pos[0], ref_pos[0], mask[0] = state.body_pos.float().cpu(), ref.body_pos.float().cpu(), True
    for k in range(1, T):
        ref = lib.frames(clip_ids, zeros + k * dt)
        with torch.no_grad():
            actions = imitator.act(imitator.observe(state, ref))
        state = sim.step(actions)
        sp, rp = state.body_pos.float().cpu(), ref.body_pos.float().cpu()
        sim_pos[k], ref_pos[k] = sp, rp
        mask[k] = alive & (k <= frames)
        if state.unstable.numel():
            unstable |= state.unstable.cpu() & alive
        err = torch.linalg.vector_norm(sp - rp, dim=-1).mean(-1)
        alive = alive & (err <= threshold) & ~unstable
        if recorder is not None:
            recorder.add_frame(state, 0, ghost=ref)
        if progress is not None:
            progress()
        if not bool((alive & (k < frames)).any()):
            sim_pos, ref_pos, mask = sim_pos[: k + 1], ref_pos[: k + 1], mask[: k + 1]
            break
    return Rollout(Trajectories(sim_pos, ref_pos, 1.0 / dt, mask), clip_ids, unstable)


def episode_frames(lib: MotionLibrary, clip_ids: torch.Tensor, dt: float, horizon: float | None) -> torch.Tensor:
    """Control steps per episode: the clip's length, or ``horizon`` seconds for looping clips."""
    dur = lib.durations.double()[clip_ids]
    if horizon is not None:
        dur = torch.where(lib.loops[clip_ids], torch.full_like(dur, horizon), dur)
    return torch.floor(dur / dt + 1e-6).long().clamp_min(1)


class ImitationEval(Trainer):
    """Evaluates the spec's imitator on every clip: success, MPJPE-G/L/PA, velocity and acceleration errors."""

    def __init__(self, params: ImitationEvalParams):
        self.params = params

    def run(self, ctx) -> StageResult:  # type: ignore[no-untyped-def]
        p = self.params
        skeleton = ctx.skeleton
        motion_set = ctx.build("motions").load(skeleton)
        for path, reason in motion_set.skipped:
            ctx.console.print(f"[yellow]skipped[/] {path}: {reason}")
        lib = MotionLibrary(motion_set, skeleton)
        upstream = ctx.upstream.get("imitator")
        imitator = ctx.build("imitator", skeleton=skeleton, checkpoint=upstream.checkpoint if upstream else None, device=ctx.device)
        metrics = self._metrics(ctx)
        all_ids = torch.arange(lib.num_clips)
        per_episode: dict[str, list[torch.Tensor]] = {m.name: [] for m in metrics}
        lengths: list[torch.Tensor] = []
        instab: list[torch.Tensor] = []
        dt = None
        with Progress(transient=True, console=ctx.console) as bar:
            task = bar.add_task("imitation eval", total=lib.num_clips)
            for start in range(0, lib.num_clips, p.num_envs):
                ids = all_ids[start : start + p.num_envs]
                sim = ctx.build("simulator", skeleton=skeleton, num_envs=len(ids), seed=ctx.seed)
                dt = sim.dt
                frames = episode_frames(lib, ids, dt, p.horizon)
                out = rollout_imitation(sim, lib, imitator, ids, frames, threshold=p.threshold)
                sim.close()
                for m in metrics:
                    per_episode[m.name].append(m(out.traj).double())
                lengths.append(out.traj.mask.sum(0).double() * dt)
                instab.append(out.unstable)
                bar.advance(task, len(ids))
        values = {k: torch.cat(v) for k, v in per_episode.items()}
        seconds = torch.cat(lengths)
        unstable = torch.cat(instab)
        rows = []
        for c in range(lib.num_clips):
            row: dict[str, Any] = {"clip": lib.clip_names[c], "tracked_s": round(float(seconds[c]), 3)}
            row.update({k: _num(v[c]) for k, v in values.items()})
            rows.append(row)
        overall = {k: _num(_nanmean(v)) for k, v in values.items()}
        overall["tracked_s"] = _num(seconds.mean())
        overall["unstable_episodes"] = float(unstable.sum())
        table = {"protocol": PROTOCOL, "fps": 1.0 / dt if dt else None, "units": _units(metrics), "clips": rows, "overall": overall}
        atomic_write_json(ctx.workdir / "imitation_eval.json", table)
        atomic_write_json(Path(ctx.run_dir) / "imitation_eval.json", table)
        atomic_write_text(Path(ctx.run_dir) / "imitation_eval.md", render_table(table))
        for k, v in overall.items():
            ctx.log.log(0, **{k: v})
        if p.video:
            self._video(ctx, lib, imitator)
        return StageResult(checkpoint=None, metrics=overall)

    def _metrics(self, ctx) -> list[Metric]:  # type: ignore[no-untyped-def]
        metrics = default_metrics()
        for i, ref in enumerate(ctx.spec.eval.metrics if ctx.spec.eval else []):
            metrics.append(ctx.build(f"eval.metrics.{i}"))
        seen: dict[str, Metric] = {}
        for m in metrics:
            seen[m.name] = m  # a spec's metric of the same name replaces the default
        return list(seen.values())

    def _video(self, ctx, lib: MotionLibrary, imitator: Imitator) -> None:  # type: ignore[no-untyped-def]
        p = self.params
        name = p.video_clip or lib.clip_names[0]
        clip = lib.clip_index(name)
        sim = ctx.build("simulator", skeleton=ctx.skeleton, num_envs=1, seed=ctx.seed)
        recorder = sim.make_recorder() if hasattr(sim, "make_recorder") else None
        if recorder is None:
            ctx.console.print("[yellow]video skipped[/]: the simulator cannot render")
            return
        frames = torch.tensor([max(1, int(p.video_seconds / sim.dt))])
        rollout_imitation(sim, lib, imitator, torch.tensor([clip]), frames, threshold=math.inf, recorder=recorder)
        path = Path(ctx.run_dir) / f"imitation_{name}.{p.video_format}"
        recorder.save(path)
        sim.close()
        ctx.console.print(f"video: {path}")


def _nanmean(v: torch.Tensor) -> torch.Tensor:
    ok = ~torch.isnan(v)
    return v[ok].mean() if ok.any() else torch.tensor(float("nan"))


def _num(v: torch.Tensor) -> float:
    x = float(v)
    return round(x, 4) if math.isfinite(x) else float("nan")


def _units(metrics: list[Metric]) -> dict[str, str]:
    return {m.name: m.unit for m in metrics}


def render_table(table: dict[str, Any]) -> str:
    units = table["units"]
    cols = ["tracked_s", *units]
    head = "| clip | " + " | ".join(f"{c} ({units[c]})" if c in units else f"{c}" for c in cols) + " |"
    lines = [
        "# Imitation evaluation",
        "",
        f"Protocol: {table['protocol']}; fps {table['fps']:.0f}." if table.get("fps") else f"Protocol: {table['protocol']}.",
        "",
        head,
        "|" + "---|" * (len(cols) + 1),
    ]
    for row in table["clips"]:
        lines.append(f"| {row['clip']} | " + " | ".join(_cell(row.get(c)) for c in cols) + " |")
    lines.append("| **all** | " + " | ".join(_cell(table["overall"].get(c)) for c in cols) + " |")
    return "\n".join(lines) + "\n"


def _cell(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


# ---------------------------------------------------------------------------- plugin hooks
class NoParams(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _make_pd_replay(params: NoParams, **_: Any) -> Imitator:
    return PDReplay()


@hookimpl
def register_trainers(register):  # type: ignore[no-untyped-def]
    register("imitation_eval", ImitationEval, params=ImitationEvalParams, description="evaluate an imitator on every clip")


@hookimpl
def register_imitators(register):  # type: ignore[no-untyped-def]
    register("pd_replay", _make_pd_replay, params=NoParams, description="baseline: PD targets = the next reference pose")


@hookimpl
def register_metrics(register):  # type: ignore[no-untyped-def]
    for name, (_, _, description) in BUILTIN_METRICS.items():
        register(name, lambda name=name: make_metric(name), description=description)
    register("success", lambda params: _success_metric(params, "mean"), params=SuccessParams, description="no frame over the mean-error threshold")
    register("success_linf", lambda params: _success_metric(params, "max"), params=SuccessParams, description="no frame with any body over the threshold")


