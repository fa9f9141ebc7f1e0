"""The implementation of :mod:`mocap.evaluation`'s imitation protocol (documented there): rollouts of an
imitator on every clip, the metrics table, videos, and the ``imitation_eval`` trainer. Imported when a spec
or a command uses them (it imports torch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import torch
from rich.progress import Progress

from mocap.paths import safe_filename
from mocap.checkpoint import atomic_write_json, atomic_write_text
from mocap.evaluation import ImitationEvalParams
from mocap.interfaces import Imitator, Metric, Simulator, StageResult, Trainer
from mocap.metrics import PROTOCOL, default_metrics
from mocap.motion.library import MotionLibrary
from mocap.pipeline import StageFailed
from mocap.state import Trajectories


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
    success_bodies: Sequence[int] | None = None,
) -> Rollout:
    """Roll ``imitator`` out in ``sim`` (N = len(clip_ids) envs) for ``frames`` (N,) control steps each.

    Frame 0 is the reset state; frame k the state after k steps, compared with the reference at
    time k * dt. ``observed``: a library of the same clips the policy sees instead of ``lib``
    (noisy references, :mod:`mocap.noisy`); errors are still measured against ``lib``. An episode ends
    once the mean error over ``success_bodies`` (all bodies when None) exceeds ``threshold``.
    """
    check = slice(None) if success_bodies is None else list(success_bodies)
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
    steps = imitator.reference_steps  # reference frames the imitator observes (t + 1 and later)
    for k in range(1, T):
        ref = lib.frames_ahead(clip_ids, zeros + k * dt, dt, steps)
        seen = ref if observed is None else observed.frames_ahead(clip_ids, zeros + k * dt, dt, steps)
        with torch.no_grad():
            actions = imitator.act(imitator.observe(state, seen))
        state = sim.step(actions)
        sp, rp = state.body_pos.float().cpu(), ref.body_pos.float().cpu()
        sim_pos[k], ref_pos[k] = sp, rp
        sim_rot[k], ref_rot[k] = state.body_rot.float().cpu(), ref.body_rot.float().cpu()
        mask[k] = alive & (k <= frames)
        if state.unstable.numel():
            unstable |= state.unstable.cpu() & alive
        err = torch.linalg.vector_norm(sp - rp, dim=-1)[..., check].mean(-1)
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


def success_bodies(skeleton: Any, exclude: Sequence[str]) -> list[int] | None:
    """Indices of the bodies the success check uses: all but ``exclude`` (None: all bodies). An
    unknown name is a :class:`~mocap.errors.UserError` listing the skeleton's bodies."""
    if not exclude:
        return None
    from mocap.errors import UserError

    unknown = [n for n in exclude if n not in skeleton.body_names]
    if unknown:
        raise UserError(f"success_exclude: {', '.join(unknown)} not a body of {skeleton.name!r}; bodies: {', '.join(skeleton.body_names)}")
    keep = [i for i, n in enumerate(skeleton.body_names) if n not in set(exclude)]
    if not keep:
        raise UserError("success_exclude leaves no body to check")
    return keep


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
    p = params
    bodies = success_bodies(lib.skeleton, p.success_exclude)
    metrics = metrics if metrics is not None else default_metrics(bodies, p.threshold)
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
            out = rollout_imitation(sim, lib, imitator, ids, frames, threshold=p.threshold, observed=observed, success_bodies=bodies)
            sim.close()
            for m in metrics:
                per_episode[m.name].append(m(out.traj).double())
            assert out.traj.mask is not None  # rollout_imitation always records the mask
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
        "ci95": aggregate_intervals(aggregate, clips),
        "clips": clips,
    }


def aggregate_intervals(aggregate: dict[str, Any], clips: dict[str, dict[str, Any]]) -> dict[str, list[float]]:
    """95% intervals of the aggregate over the clips (:mod:`mocap.intervals`): the success rate's
    Wilson interval over the clips, each mean metric's bootstrap interval over the clips it averages
    (all clips; ``_succ``: the successful ones). A re-run elsewhere lands in these, not on the digits."""
    from mocap.intervals import bootstrap_mean, wilson

    out: dict[str, list[float]] = {}
    rate = wilson(float(aggregate["succeeded"]), int(aggregate["total"]))
    if rate is not None:
        out["success_rate"] = list(rate)
    rows = list(clips.values())
    for key in aggregate:
        base = key.removesuffix("_succ")
        if key in ("success_rate", "succeeded", "total", "fps", "unstable_episodes") or not rows or base not in rows[0]:
            continue
        chosen = [r for r in rows if r["success"]] if key.endswith("_succ") else rows
        interval = bootstrap_mean([float(r[base]) for r in chosen if isinstance(r.get(base), (int, float))])
        if interval is not None:
            out[key] = list(interval)
    return out


def record_video(imitator: Imitator, lib: MotionLibrary, make_sim: Callable[[int], Simulator], clip: str, seconds: float, path: Path) -> Path | None:
    """Roll the imitator out on ``clip`` and save a video with the reference drawn as a ghost.

    Returns None when the simulator cannot render (:meth:`Simulator.make_recorder` gives None).
    """
    sim = make_sim(1)
    recorder = sim.make_recorder(ghost=True)
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

    def preflight(self, resolved: Any, plugins: Any) -> None:
        """``video_clip`` names a clip of the spec's motion set and ``success_exclude`` bodies of the
        humanoid (checked before any stage trains)."""
        p = self.params
        spec = resolved.spec
        skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params.get("humanoid"))
        success_bodies(skeleton, p.success_exclude)
        if not (p.video and p.video_clip):
            return
        names = plugins.get("motion_source", spec.motions.name).build(resolved.params.get("motions")).load(skeleton).names
        if p.video_clip not in names:
            from mocap.errors import UserError

            shown = ", ".join(names[:20]) + (f", ... ({len(names)} clips)" if len(names) > 20 else "")
            raise UserError(f"eval.trainer.params.video_clip: no clip {p.video_clip!r} in the motion set (clips: {shown or 'none'})")

    def run(self, ctx) -> StageResult:  # type: ignore[no-untyped-def]
        p = self.params
        skeleton = ctx.skeleton
        motion_set = ctx.build("motions").load(skeleton)
        for path, reason in motion_set.skipped:
            ctx.console.print(f"[yellow]skipped[/] {path}: {reason}")
        lib = MotionLibrary(motion_set, skeleton)
        upstream = ctx.upstream.get("imitator")
        imitator = ctx.stage_component("imitator", checkpoint=upstream.checkpoint if upstream else None) if ctx.spec.imitator is not None else None
        latent_stage = ctx.upstream.get("latent")

        def make_sim(n: int) -> Simulator:
            return ctx.build("simulator", skeleton=skeleton, num_envs=n, seed=ctx.seed)

        if p.target != "imitator" and latent_stage is not None and latent_stage.checkpoint is not None:
            from mocap.distill_files import load_latent_state
            from mocap.latent_imitator import PDTargetTeacher, latent_imitator

            latent = ctx.stage_component("latent", checkpoint=latent_stage.checkpoint)
            if latent.decodes_pd_targets:
                # a latent space with its own tracking policy (VMP): it imitates the reference itself
                probe = make_sim(1)
                dt = float(probe.dt)
                probe.close()
                imitator = latent.as_imitator(lib, dt=dt, device="cpu")
                ctx.console.print(f"imitation_eval: evaluating the {ctx.spec.latent.name} latent's own tracking policy")
            else:
                label = load_latent_state(latent_stage.checkpoint)["extra"].get("label", "policy_output")
                assert imitator is not None  # a latent that does not drive PD targets itself was distilled from the spec's imitator
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


__all__ = [
    "ImitationEval",
    "Rollout",
    "compare_tables",
    "episode_frames",
    "evaluate_imitator",
    "record_video",
    "render_comparison",
    "render_table",
    "rollout_imitation",
    "success_bodies",
]
