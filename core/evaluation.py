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
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Callable, Literal, Optional

import torch
import typer
from pydantic import BaseModel, ConfigDict, Field
from rich.progress import Progress

from mocap.baselines import PDReplay
from mocap.paths import safe_filename
from mocap.checkpoint import atomic_write_json, atomic_write_text
from mocap.hooks import hookimpl
from mocap.interfaces import Imitator, Metric, Simulator, StageResult, Trainer
from mocap.metrics import BUILTIN_METRICS, PROTOCOL, SuccessParams, _success_metric, default_metrics, make_metric
from mocap.motion.library import MotionLibrary
from mocap.pipeline import StageFailed
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
    target: Literal["auto", "imitator", "latent"] = Field(
        "auto", description="what to evaluate: 'auto' = the latent space when the spec trains one (as an imitator, z = encoder mean), else the imitator"
    )


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
    observed: MotionLibrary | None = None,
) -> Rollout:
    """Roll ``imitator`` out in ``sim`` (N = len(clip_ids) envs) for ``frames`` (N,) control steps each.

    Frame 0 is the reset state; frame k the state after k steps, compared with the reference at
    time k * dt. ``observed``: a library of the same clips the policy sees instead of ``lib``
    (noisy references, :mod:`mocap.noisy`); errors are still measured against ``lib``.
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
    sim_rot = torch.zeros(T, n, sim.skeleton.num_bodies, 4)
    ref_rot = torch.zeros_like(sim_rot)
    sim_rot[0], ref_rot[0] = state.body_rot.float().cpu(), ref.body_rot.float().cpu()
    mask = torch.zeros(T, n, dtype=torch.bool)
    alive = torch.ones(n, dtype=torch.bool)
    unstable = torch.zeros(n, dtype=torch.bool)
    sim_pos[0], ref_pos[0], mask[0] = state.body_pos.float().cpu(), ref.body_pos.float().cpu(), True
    for k in range(1, T):
        ref = lib.frames(clip_ids, zeros + k * dt)
        seen = ref if observed is None else observed.frames(clip_ids, zeros + k * dt)
        with torch.no_grad():
            actions = imitator.act(imitator.observe(state, seen))
        state = sim.step(actions)
        sp, rp = state.body_pos.float().cpu(), ref.body_pos.float().cpu()
        sim_pos[k], ref_pos[k] = sp, rp
        sim_rot[k], ref_rot[k] = state.body_rot.float().cpu(), ref.body_rot.float().cpu()
        mask[k] = alive & (k <= frames)
        if state.unstable.numel():
            unstable |= state.unstable.cpu() & alive
        err = torch.linalg.vector_norm(sp - rp, dim=-1).mean(-1)
        alive = alive & (err <= threshold) & ~unstable
        if recorder is not None:
            recorder.add_frame(state, ghost=ref)
        if progress is not None:
            progress()
        if not bool((alive & (k < frames)).any()):
            sim_pos, ref_pos, mask = sim_pos[: k + 1], ref_pos[: k + 1], mask[: k + 1]
            sim_rot, ref_rot = sim_rot[: k + 1], ref_rot[: k + 1]
            break
    return Rollout(Trajectories(sim_pos, ref_pos, 1.0 / dt, mask, sim_rot, ref_rot), clip_ids, unstable)


def episode_frames(lib: MotionLibrary, clip_ids: torch.Tensor, dt: float, horizon: float | None) -> torch.Tensor:
    """Control steps per episode: the clip's length, or ``horizon`` seconds for looping clips."""
    dur = lib.durations.double()[clip_ids]
    if horizon is not None:
        dur = torch.where(lib.loops[clip_ids], torch.full_like(dur, horizon), dur)
    return torch.floor(dur / dt + 1e-6).long().clamp_min(1)


def evaluate_imitator(
    imitator: Imitator,
    lib: MotionLibrary,
    make_sim: Callable[[int], Simulator],
    params: ImitationEvalParams,
    metrics: list[Metric] | None = None,
    console: Any = None,
    observed: MotionLibrary | None = None,
) -> dict[str, Any]:
    """Run the evaluation protocol (module docstring) and return the result table.

    ``observed``: what the policy sees instead of ``lib`` (the same clips, e.g. with estimator
    noise: :mod:`mocap.noisy`); every metric is still measured against ``lib``.

    The table: ``protocol``, ``fps``, ``units``, ``aggregate`` (``success_rate`` in [0, 1],
    ``succeeded``, ``total``, every metric's mean over all clips, and ``<metric>_succ`` its mean
    over the successful clips only — PHC reports MPJPE that way) and ``clips`` (clip name -> the
    metrics of that clip with ``success`` true/false and ``tracked_s``).
    """
    metrics = metrics if metrics is not None else default_metrics()
    p = params
    all_ids = torch.arange(lib.num_clips)
    per_episode: dict[str, list[torch.Tensor]] = {m.name: [] for m in metrics}
    lengths: list[torch.Tensor] = []
    instab: list[torch.Tensor] = []
    dt = 1.0 / 30.0
    with Progress(transient=True, console=console, disable=console is None) as bar:
        task = bar.add_task("imitation eval", total=lib.num_clips)
        for start in range(0, lib.num_clips, p.num_envs):
            ids = all_ids[start : start + p.num_envs]
            sim = make_sim(len(ids))
            dt = sim.dt
            frames = episode_frames(lib, ids, dt, p.horizon)
            out = rollout_imitation(sim, lib, imitator, ids, frames, threshold=p.threshold, observed=observed)
            sim.close()
            for m in metrics:
                per_episode[m.name].append(m(out.traj).double())
            lengths.append((out.traj.mask.sum(0).double() - 1).clamp_min(0) * dt)
            instab.append(out.unstable)
            bar.advance(task, len(ids))
            if console is not None and not console.is_terminal:  # logs and CI: a plain line instead of the bar
                console.print(f"imitation eval: {min(start + len(ids), lib.num_clips)}/{lib.num_clips} clips", highlight=False)
    values = {k: torch.cat(v) for k, v in per_episode.items()}
    seconds = torch.cat(lengths)
    unstable = torch.cat(instab)
    ok = values["success"] > 0.5 if "success" in values else torch.ones(lib.num_clips, dtype=torch.bool)
    clips: dict[str, dict[str, Any]] = {}
    for c in range(lib.num_clips):
        row: dict[str, Any] = {k: _num(v[c]) for k, v in values.items() if k != "success"}
        row["success"] = bool(ok[c])
        row["tracked_s"] = round(float(seconds[c]), 3)
        row["unstable"] = bool(unstable[c])
        clips[lib.clip_names[c]] = row
    aggregate: dict[str, Any] = {
        "success_rate": float(ok.double().mean()),
        "succeeded": int(ok.sum()),
        "total": lib.num_clips,
        "fps": 1.0 / dt,
        "tracked_s": _num(seconds.mean()),
        "unstable_episodes": int(unstable.sum()),
    }
    for k, v in values.items():
        if k == "success":
            continue
        aggregate[k] = _num(_nanmean(v))
        aggregate[f"{k}_succ"] = _num(_nanmean(v[ok])) if bool(ok.any()) else float("nan")
    return {
        "protocol": PROTOCOL,
        "fps": 1.0 / dt,
        "horizon": "clip length" if p.horizon is None else f"looping clips: {p.horizon:g} s",
        "units": _units(metrics),
        "aggregate": aggregate,
        "clips": clips,
    }


def record_video(
    imitator: Imitator, lib: MotionLibrary, make_sim: Callable[[int], Simulator], clip: str, seconds: float, path: Path
) -> Path | None:
    """Roll the imitator out on ``clip`` and save a video with the reference drawn as a ghost.

    Returns None when the simulator cannot render (it has no ``make_recorder``).
    """
    sim = make_sim(1)
    recorder = sim.make_recorder(ghost=True) if hasattr(sim, "make_recorder") else None
    if recorder is None:
        sim.close()
        return None
    frames = torch.tensor([max(1, int(seconds / sim.dt))])
    rollout_imitation(sim, lib, imitator, torch.tensor([lib.clip_index(clip)]), frames, threshold=math.inf, recorder=recorder)
    recorder.save(path)
    sim.close()
    return path


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
        imitator = (
            ctx.stage_component("imitator", checkpoint=upstream.checkpoint if upstream else None) if ctx.spec.imitator is not None else None
        )
        latent_stage = ctx.upstream.get("latent")

        def make_sim(n: int) -> Simulator:
            return ctx.build("simulator", skeleton=skeleton, num_envs=n, seed=ctx.seed)

        if p.target != "imitator" and latent_stage is not None and latent_stage.checkpoint is not None:
            from mocap.distill import load_latent_state
            from mocap.latent_imitator import PDTargetTeacher, latent_imitator

            latent = ctx.stage_component("latent", checkpoint=latent_stage.checkpoint)
            if getattr(latent, "decodes_pd_targets", False) and callable(getattr(latent, "as_imitator", None)):
                # a latent space with its own tracking policy (VMP): it imitates the reference itself
                probe = make_sim(1)
                dt = float(probe.dt)
                probe.close()
                imitator = latent.as_imitator(lib, dt=dt, device="cpu")
                ctx.console.print(f"imitation_eval: evaluating the {ctx.spec.latent.name} latent's own tracking policy")
            else:
                label = load_latent_state(latent_stage.checkpoint)["extra"].get("label", "policy_output")
                imitator = latent_imitator(PDTargetTeacher(imitator) if label == "pd_targets" else imitator, latent)
                ctx.console.print(f"imitation_eval: evaluating the {ctx.spec.latent.name} latent (z = encoder mean)")
        elif p.target == "latent":
            raise StageFailed("imitation_eval target 'latent': the spec has no trained latent stage")
        if imitator is None:
            raise StageFailed("imitation_eval: the spec has no imitator and its latent space cannot imitate on its own")

        table = evaluate_imitator(imitator, lib, make_sim, p, self._metrics(ctx), ctx.console)
        atomic_write_json(ctx.publish("imitation_eval.json"), table)
        atomic_write_text(ctx.publish("imitation_eval.md"), render_table(table))
        numeric = {k: float(v) for k, v in table["aggregate"].items() if isinstance(v, (int, float))}
        ctx.log.log(0, **numeric)
        if p.video:
            clip = p.video_clip or lib.clip_names[0]
            name = f"imitation_{safe_filename(clip)}.{p.video_format}"  # clip names come from motion files
            path = record_video(imitator, lib, make_sim, clip, p.video_seconds, ctx.publish(name))
            ctx.console.print(f"video: {Path(ctx.run_dir) / name}" if path else "[yellow]video skipped[/]: the simulator cannot render")
        return StageResult(checkpoint=None, metrics=numeric)

    def _metrics(self, ctx) -> list[Metric]:  # type: ignore[no-untyped-def]
        metrics = default_metrics()
        for i, _ in enumerate(ctx.spec.eval.metrics if ctx.spec.eval else []):
            metrics.append(ctx.build(f"eval.metrics.{i}"))
        seen: dict[str, Metric] = {}
        for m in metrics:
            seen[m.name] = m  # a spec's metric of the same name replaces the default
        return list(seen.values())


def _nanmean(v: torch.Tensor) -> torch.Tensor:
    ok = ~torch.isnan(v)
    return v[ok].mean() if ok.any() else torch.tensor(float("nan"))


def _num(v: torch.Tensor) -> float:
    x = float(v)
    return round(x, 4) if math.isfinite(x) else float("nan")


def _units(metrics: list[Metric]) -> dict[str, str]:
    return {m.name: m.unit for m in metrics}


def render_table(table: dict[str, Any]) -> str:
    """The result table as Markdown: one row per clip, then the aggregate (all clips / successful)."""
    units = table["units"]
    cols = [c for c in units if c != "success"]
    head = "| clip | success | tracked (s) | " + " | ".join(f"{c} ({units[c]})" for c in cols) + " |"
    agg = table["aggregate"]
    lines = [
        "# Imitation evaluation",
        "",
        f"Protocol: {table['protocol']}; fps {table['fps']:.0f}; horizon: {table['horizon']}.",
        "",
        f"**Success: {agg['succeeded']} / {agg['total']} clips ({100 * agg['success_rate']:.1f}%)**",
        "",
        head,
        "|" + "---|" * (len(cols) + 3),
    ]
    for name, row in table["clips"].items():
        mark = "yes" if row["success"] else "no"
        lines.append(f"| {name} | {mark} | {_cell(row['tracked_s'])} | " + " | ".join(_cell(row.get(c)) for c in cols) + " |")
    lines.append(f"| **all clips** | {agg['succeeded']}/{agg['total']} | {_cell(agg['tracked_s'])} | " + " | ".join(_cell(agg.get(c)) for c in cols) + " |")
    lines.append("| **successful clips** | | | " + " | ".join(_cell(agg.get(f"{c}_succ")) for c in cols) + " |")
    return "\n".join(lines) + "\n"


def compare_tables(teacher: dict[str, Any], student: dict[str, Any]) -> dict[str, Any]:
    """How much of the teacher's imitation a student keeps: clips both succeed on, the share of the
    teacher's successful clips the student also succeeds on, and MPJPE-g ratios (student / teacher)
    over all clips and over the clips both succeed on."""
    t_ok = {c for c, r in teacher["clips"].items() if r["success"]}
    s_ok = {c for c, r in student["clips"].items() if r["success"]}
    both = sorted(t_ok & s_ok)
    retained = len(both) / len(t_ok) if t_ok else float("nan")

    def mean_over(table: dict[str, Any], clips: list[str]) -> float:
        vals = [table["clips"][c]["mpjpe_g"] for c in clips if table["clips"][c].get("mpjpe_g") is not None]
        return sum(vals) / len(vals) if vals else float("nan")

    t_both, s_both = mean_over(teacher, both), mean_over(student, both)
    return {
        "teacher_succeeded": sorted(t_ok),
        "student_succeeded": sorted(s_ok),
        "both_succeeded": both,
        "retained_fraction": retained,
        "mpjpe_g_ratio_all": student["aggregate"]["mpjpe_g"] / teacher["aggregate"]["mpjpe_g"],
        "mpjpe_g_teacher_on_both": t_both,
        "mpjpe_g_student_on_both": s_both,
        "mpjpe_g_ratio_on_both": s_both / t_both if both else float("nan"),
    }


def render_comparison(tables: dict[str, dict[str, Any]], comparison: dict[str, Any] | None = None, console_table: bool = False) -> Any:
    """One row per evaluated policy (PULSE Table 1 layout): success, MPJPE-g/L, acceleration and
    velocity errors over all clips. Markdown text, or a rich Table with ``console_table``."""
    cols = [("success", None), ("mpjpe_g", "mm"), ("mpjpe_l", "mm"), ("acc_err", "mm/frame^2"), ("vel_err", "mm/frame")]
    header = ["policy", *[f"{c} ({u})" if u else c for c, u in cols]]
    rows = []
    for name, t in tables.items():
        agg = t["aggregate"]
        rows.append([name, f"{agg['succeeded']}/{agg['total']}", *[_cell(agg.get(c)) for c, _ in cols[1:]]])
    note = ""
    if comparison is not None:
        note = (
            f"student keeps {len(comparison['both_succeeded'])} of the teacher's {len(comparison['teacher_succeeded'])} successful clips "
            f"({100 * comparison['retained_fraction']:.0f}%); MPJPE-g on the clips both succeed on: "
            f"{_cell(comparison['mpjpe_g_student_on_both'])} vs {_cell(comparison['mpjpe_g_teacher_on_both'])} mm "
            f"(ratio {_cell(comparison['mpjpe_g_ratio_on_both'])})"
        )
    if console_table:
        from rich.table import Table

        out = Table(title="imitation on the same clips", caption=note or None)
        for col in header:
            out.add_column(col, justify="left" if col == "policy" else "right")
        for r in rows:
            out.add_row(*r)
        return out
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + ("\n\n" + note + "\n" if note else "\n")


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
    from mocap.suite import EvalSuite, EvalSuiteParams

    register(
        "eval_suite",
        EvalSuite,
        params=EvalSuiteParams,
        description="imitation + random generation + the task stage's metrics of one cell, in one eval stage (comparisons)",
    )


@hookimpl
def register_imitators(register):  # type: ignore[no-untyped-def]
    register("pd_replay", _make_pd_replay, params=NoParams, description="baseline: PD targets = the next reference pose")


@dataclass
class EvalTarget:
    """What ``mocap eval`` / ``mocap generate`` evaluate: a validated spec and the stage checkpoints.

    ``latent_checkpoint`` is set when the target is a latent space; it is then evaluated as an
    imitator (:class:`~mocap.latent_imitator.LatentImitator`, ``z`` = encoder mean) on top of the
    imitator it was distilled from (``imitator_checkpoint``).
    """

    resolved: Any
    imitator_checkpoint: Path | None
    latent_checkpoint: Path | None = None

    @property
    def spec(self) -> Any:
        return self.resolved.spec


@dataclass
class LoadedTarget:
    """An :class:`EvalTarget` built: skeleton, motion library, the policy to evaluate, and the parts."""

    target: EvalTarget
    skeleton: Any
    library: MotionLibrary
    imitator: Imitator  # the trained imitator (the teacher, for a latent)
    latent: Any  # the latent space, or None
    label: str  # what the latent's decoder outputs: "policy_output" (teacher's raw output) or "pd_targets"
    policy: Imitator  # what imitation evaluation rolls out
    make_sim: Callable[[int], Simulator]

    def to_pd_targets(self, obs: Any, output: torch.Tensor) -> torch.Tensor:
        """PD targets from a latent decoder's output (identity for ``label: pd_targets``)."""
        return output if self.label == "pd_targets" else self.imitator.to_pd_targets(obs, output)


_POLICY_NAMES = ("latent.pt", "policy.pt")


def _stage_checkpoint(spec: Any, stage: str) -> Path | None:
    section = getattr(spec, stage, None)
    ckpt = getattr(section, "checkpoint", None) if section is not None else None
    return Path(ckpt) if ckpt else None


def _from_file(target: Path, plugins: Any) -> EvalTarget:
    from mocap.checkpoint import load_checkpoint
    from mocap.errors import UserError
    from mocap.spec import SpecError, load_spec, validate_document

    if target.suffix in (".yaml", ".yml"):
        try:
            resolved = load_spec(target, plugins)
        except SpecError as exc:
            raise UserError(str(exc)) from None
        return _check(EvalTarget(resolved, _stage_checkpoint(resolved.spec, "imitator"), _stage_checkpoint(resolved.spec, "latent")), target)
    data = load_checkpoint(target)  # CheckpointError (missing, corrupt, truncated): one clear line
    _check_known_format(target, data)
    _warn_unfinished(target, data)
    spec_yaml = data.get("spec") if isinstance(data, dict) else None
    if not spec_yaml:
        raise UserError(f"{target}: the checkpoint carries no spec; evaluate its run directory instead")
    from mocap.export import resolve_embedded_paths

    from mocap.runfiles import yaml_mapping

    doc = resolve_embedded_paths(yaml_mapping(spec_yaml, f"{target} (embedded spec)"), target.parent)
    resolved = validate_document(doc, plugins, source=f"{target} (embedded spec)")
    from mocap.distill import CHECKPOINT_FORMAT as DISTILL_FORMAT, LATENT_FORMAT

    if data.get("format") in (LATENT_FORMAT, DISTILL_FORMAT) or (resolved.spec.imitator is None and resolved.spec.latent is not None):
        teacher = _stage_checkpoint(resolved.spec, "imitator")
        return _check(EvalTarget(resolved, teacher, target), target)
    return _check(EvalTarget(resolved, target), target)


def _warn_unfinished(path: Path, data: dict[str, Any]) -> None:
    """One ``warning:`` line when a trainer checkpoint was saved before the end of its budget (eval,
    generate, render and export all load targets through here)."""
    from rich.console import Console

    from mocap.checkpoint import training_status

    status = training_status(data)
    if status is not None:
        Console(stderr=True, soft_wrap=True).print(
            f"[yellow]warning:[/] {path} is a training checkpoint still {status}; the numbers describe an unfinished policy",
            highlight=False,
        )


def _check_known_format(path: Path, data: dict[str, Any]) -> None:
    """A policy / latent / trainer checkpoint of a format version this mocap does not read: a
    :class:`~mocap.checkpoint.CheckpointError` naming both versions (other formats pass: their
    plugin checks them)."""
    from mocap.checkpoint import check_format, split_format
    from mocap.distill import CHECKPOINT_FORMAT as DISTILL_FORMAT, LATENT_FORMAT
    from mocap.rl.networks import POLICY_FORMAT
    from mocap.rl.ppo import CHECKPOINT_FORMAT as PPO_FORMAT

    known = (POLICY_FORMAT, PPO_FORMAT, LATENT_FORMAT, DISTILL_FORMAT)
    got = split_format(data.get("format"))
    if got is not None and data.get("format") not in known and any(split_format(k)[0] == got[0] for k in known):  # type: ignore[index]
        check_format(path, data, known)


def _check(t: EvalTarget, source: Path) -> EvalTarget:
    from mocap.errors import UserError

    spec = t.spec
    if spec.imitator is None and t.latent_checkpoint is None:
        raise UserError(f"{source}: its spec has no imitator")
    if t.latent_checkpoint is not None and spec.latent is None:
        raise UserError(f"{source}: a latent checkpoint, but its spec has no latent stage")
    if t.latent_checkpoint is not None and t.imitator_checkpoint is None and spec.imitator is not None and spec.imitator.name not in ("pd_replay",):
        raise UserError(f"{source}: the latent's imitator has no checkpoint (the spec names none, and no run records one)")
    for path in (t.imitator_checkpoint, t.latent_checkpoint):
        if path is not None and not Path(path).is_file():
            raise UserError(f"{source}: checkpoint {path} does not exist (moved? evaluate a directory holding it)")
    return t


def _action_count(data: dict[str, Any]) -> int | None:
    """The number of actions of the policy in a checkpoint (policy file or PPO checkpoint), if it has one."""
    from mocap.rl.networks import POLICY_FORMAT

    config = data.get("config") if data.get("format") == POLICY_FORMAT else data.get("policy_config")
    space = config.get("action_space") if isinstance(config, dict) else None
    if isinstance(space, dict) and space.get("type") == "box" and space.get("shape"):
        return int(space["shape"][0])
    return None


def check_trained_humanoid(path: Path, skeleton: Any, plugins: Any, stage: str = "imitator") -> None:
    """Raise :class:`~mocap.checkpoint.CheckpointError` when the spec embedded in checkpoint ``path``
    names another humanoid than ``skeleton``: "trained for humanoid amp with 28 actions; the spec
    asks for smpl with 69"."""
    from mocap.checkpoint import CheckpointError, embedded_humanoid, load_checkpoint

    data = load_checkpoint(path)
    trained = embedded_humanoid(data)
    if trained is None or trained == skeleton.name:
        return
    actions = _action_count(data)
    if actions is None:
        try:
            actions = plugins.get("humanoid", trained).build(None).num_dofs
        except Exception:  # noqa: BLE001 - a humanoid this install lacks: say so without the count
            actions = None
    count = f" with {actions} actions" if actions is not None else ""
    raise CheckpointError(
        f"{path}: this {stage} checkpoint was trained for humanoid {trained}{count}; the spec asks for "
        f"{skeleton.name} with {skeleton.num_dofs}. Use a checkpoint trained on {skeleton.name}, or set humanoid: {trained}"
    )


def load_evaluation_target(target: Path, plugins: Any) -> EvalTarget:
    """The :class:`EvalTarget` of a checkpoint file, a run directory, a checkpoint directory or a spec.

    * a file ``policy.pt`` / ``ppo.pt`` (imitator) or ``latent.pt`` / ``distill.pt`` (latent space):
      its embedded spec; for a latent, the imitator checkpoint that spec names;
    * a run directory (``spec.yaml`` + ``stages.json``): the imitator and latent stages' checkpoints
      (the latent is evaluated when the run has one);
    * a checkpoint directory (``checkpoints/<name>/``): its ``spec.yaml`` whose stages name their
      ``checkpoint:`` files (relative to it), else its ``latent.pt`` or ``policy.pt``;
    * a spec file whose imitator (and latent) stages name ``checkpoint:`` files.
    """
    from mocap.errors import UserError
    from mocap.spec import SpecError, load_spec, validate_document

    target = Path(target)
    if target.is_dir():
        spec_file, stages_file = target / "spec.yaml", target / "stages.json"
        if stages_file.is_file() and spec_file.is_file():
            from mocap.runfiles import read_spec_file, read_stages

            resolved = validate_document(read_spec_file(spec_file), plugins, source=str(spec_file))
            found: dict[str, Path] = {}
            for stage in read_stages(stages_file):
                if stage["stage"] in ("imitator", "latent") and stage.get("checkpoint"):
                    found[stage["stage"]] = Path(stage["checkpoint"])
            if resolved.spec.imitator is None and "latent" not in found:
                raise UserError(f"{spec_file}: the run has no imitator or trained latent stage to evaluate")
            from mocap.pipeline import resolved_stage_keys

            keys = resolved_stage_keys(resolved, plugins)
            for stage in ("imitator", "latent"):
                section = getattr(resolved.spec, stage, None)
                if section is not None and section.trainer is not None and stage not in found:
                    partial = sorted((target.parent / "artifacts" / f"{stage}-{keys[stage]}").glob("*.pt"))
                    hint = f"; evaluate its latest training checkpoint instead: mocap eval {partial[0]}" if partial else "; run it first"
                    raise UserError(f"{target}: the {stage} stage has not finished (no checkpoint in stages.json){hint}")
            return _check(EvalTarget(resolved, found.get("imitator"), found.get("latent")), target)
        if spec_file.is_file():
            try:
                resolved = load_spec(spec_file, plugins)
            except SpecError as exc:
                raise UserError(str(exc)) from None
            t = EvalTarget(resolved, _stage_checkpoint(resolved.spec, "imitator"), _stage_checkpoint(resolved.spec, "latent"))
            return _check(t, target)
        for name in _POLICY_NAMES:
            if (target / name).is_file():
                return _from_file(target / name, plugins)
        raise UserError(f"{target}: not a run directory (spec.yaml + stages.json) nor a checkpoint directory ({' or '.join(_POLICY_NAMES)})")
    if not target.is_file():
        raise UserError(f"{target}: no such checkpoint file, spec or directory")
    return _from_file(target, plugins)


def _is_distilled(path: Path) -> bool:
    """Whether a latent checkpoint is a distilled latent space (``mocap.latent`` / ``mocap.distill``
    format, decoded through the imitator it was distilled from) rather than a latent space with a
    policy of its own (VMP's tracker)."""
    from mocap.checkpoint import load_checkpoint
    from mocap.distill import CHECKPOINT_FORMAT, LATENT_FORMAT

    return load_checkpoint(path).get("format") in (LATENT_FORMAT, CHECKPOINT_FORMAT)


def build_evaluation_target(
    target: EvalTarget, plugins: Any, *, motions: str | None = None, device: str = "cpu", use_latent: bool = True
) -> LoadedTarget:
    """Build the skeleton, motion library (``motions``: another source, default params), the
    imitator, the latent space (when ``target`` has one and ``use_latent``) and the simulator factory."""
    from mocap.distill import load_latent_state
    from mocap.latent_imitator import PDTargetTeacher, latent_imitator

    resolved, spec = target.resolved, target.spec
    skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params.get("humanoid"))
    for stage, path in (("imitator", target.imitator_checkpoint), ("latent", target.latent_checkpoint)):
        if path is not None:  # before loading motions: a checkpoint for another humanoid fails at once
            check_trained_humanoid(Path(path), skeleton, plugins, stage)
    if motions is None:
        source = plugins.get("motion_source", spec.motions.name).build(resolved.params.get("motions"))
    else:
        source = plugins.get("motion_source", motions).build({})
    lib = MotionLibrary(source.load(skeleton), skeleton)
    sim_component = plugins.get("simulator", spec.simulator.name)
    sim_params = resolved.params.get("simulator")

    def make_sim(n: int) -> Simulator:
        return sim_component.build(sim_params, skeleton=skeleton, num_envs=n, seed=spec.seed)

    own_tracker = spec.imitator is None or (
        use_latent and target.latent_checkpoint is not None and not _is_distilled(Path(target.latent_checkpoint))
    )
    if own_tracker:  # a latent space that imitates on its own (VMP's tracker), even where the spec names an imitator
        from mocap.errors import UserError

        latent = plugins.get("latent", spec.latent.name).build(
            resolved.params.get("latent"), skeleton=skeleton, checkpoint=target.latent_checkpoint, device=device
        )
        probe = make_sim(1)
        dt = float(probe.dt)
        probe.close()
        own = latent.as_imitator(lib, dt=dt, device=device) if callable(getattr(latent, "as_imitator", None)) else None
        if own is None:
            raise UserError(f"{target.latent_checkpoint}: the {spec.latent.name} latent has no imitator of its own and the spec names none")
        return LoadedTarget(target, skeleton, lib, own, latent, "pd_targets", own, make_sim)
    imitator = plugins.get("imitator", spec.imitator.name).build(
        resolved.params.get("imitator"), skeleton=skeleton, checkpoint=target.imitator_checkpoint, device=device
    )
    latent, label, policy = None, "policy_output", imitator
    if use_latent and target.latent_checkpoint is not None:
        latent = plugins.get("latent", spec.latent.name).build(
            resolved.params.get("latent"), skeleton=skeleton, checkpoint=target.latent_checkpoint, device=device
        )
        label = str(load_latent_state(target.latent_checkpoint)["extra"].get("label", "policy_output"))
        policy = latent_imitator(PDTargetTeacher(imitator) if label == "pd_targets" else imitator, latent)
    return LoadedTarget(target, skeleton, lib, imitator, latent, label, policy, make_sim)


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
        motions: Annotated[
            Optional[str], typer.Option("--motions", help="evaluate on this motion source instead of the training one (default params)")
        ] = None,
        json_out: Annotated[Optional[Path], typer.Option("--json", help="write the result table as JSON")] = None,
        video: Annotated[Optional[Path], typer.Option("--video", help="write one video per clip (reference as a ghost) here")] = None,
        loop: Annotated[
            Optional[float], typer.Option("--loop", help="robustness protocol: looping clips keep cycling for this many seconds")
        ] = None,
        num_envs: Annotated[int, typer.Option(help="clips simulated in parallel")] = 64,
        imitator_only: Annotated[
            bool, typer.Option("--imitator-only", help="for a latent space: evaluate the imitator it was distilled from instead")
        ] = False,
    ) -> None:
        """Evaluate an imitator or a latent space with the imitation protocol (each clip from its first frame, deterministic)."""
        import json

        from rich.console import Console
        from rich.table import Table

        from mocap.plugins import get_plugins

        console = Console(stderr=True)
        plugins = get_plugins()
        target_info = load_evaluation_target(target, plugins)
        loaded = build_evaluation_target(target_info, plugins, motions=motions, use_latent=not imitator_only)
        spec, lib, imitator, make_sim = target_info.spec, loaded.library, loaded.policy, loaded.make_sim
        if spec.imitator is None:
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
        if loaded.latent is not None and spec.imitator is not None:
            # PULSE Table 1 layout: the latent next to the imitator it was distilled from.
            teacher = evaluate_imitator(loaded.imitator, lib, make_sim, params, default_metrics(), console)
            table["imitator"] = teacher
            table["comparison"] = compare_tables(teacher, table)
            stdout.print(render_comparison({spec.imitator.name + " (teacher)": teacher, what: table}, table["comparison"], console_table=True))
        if json_out is not None:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            json_out.write_text(json.dumps(table, indent=2) + "\n")
            stdout.print(f"wrote {json_out}")
        if video is not None:
            video.mkdir(parents=True, exist_ok=True)
            for name in lib.clip_names:
                seconds = loop if (loop and bool(lib.loops[lib.clip_index(name)])) else float(lib.durations[lib.clip_index(name)])
                path = record_video(imitator, lib, make_sim, name, seconds, video / f"{safe_filename(name)}.mp4")
                if path is None:
                    console.print("[yellow]videos skipped[/]: the simulator cannot render")
                    break
                console.print(f"video: {path}")


@hookimpl
def register_metrics(register):  # type: ignore[no-untyped-def]
    for name, (_, _, description) in BUILTIN_METRICS.items():
        register(name, lambda name=name: make_metric(name), description=description)
    register("success", lambda params: _success_metric(params, "mean"), params=SuccessParams, description="no frame over the mean-error threshold")
    register("success_linf", lambda params: _success_metric(params, "max"), params=SuccessParams, description="no frame with any body over the threshold")


