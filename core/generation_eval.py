"""The implementation of :mod:`mocap.generation`: rollouts from a latent space's prior, falls, diversity, motion
matching (the protocol is documented there), :func:`generate_from_target` (``mocap generate``) and the
``generation_eval`` trainer. Imported when a spec or a command uses them (it imports torch).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable

import torch
from torch import Tensor

from mocap.generation import GenerationParams, render_falls_by_start_clip, render_generation
from mocap.interfaces import Imitator, Simulator, Trainer
from mocap.motion.library import MotionLibrary
from mocap.naturalness import nearest_transitions
from mocap.observations import SixD, proprioception
from mocap.rotations import heading_quat, quat_apply, quat_conjugate
from mocap.state import Observations
from mocap.termination import allowed_contact_mask


def heading_frame(root_pos: Tensor, root_rot: Tensor) -> tuple[Tensor, Tensor]:
    """(origin (N, 3) on the ground below the root, yaw-only rotation (N, 4) wxyz) of each root."""
    q = heading_quat(root_rot)
    origin = torch.cat([root_pos[..., :2], torch.zeros_like(root_pos[..., 2:])], -1)
    return origin, q


def in_start_frame(body_pos: Tensor, origin: Tensor, heading: Tensor) -> Tensor:
    """(T, N, B, 3) body positions expressed in each rollout's start frame (origin, heading (N, ...))."""
    T, N, B, _ = body_pos.shape
    rel = body_pos - origin[None, :, None, :]
    q = quat_conjugate(heading)[None, :, None, :].expand(T, N, B, 4)
    return quat_apply(q, rel)


def fallen_down(body_pos: Tensor, body_contact: Tensor, allowed: Tensor, fall_height: float) -> Tensor:
    """(N,) bool: a body other than the ``allowed`` ones (the feet) touches the ground *and* its origin
    is below ``fall_height`` (the generation protocol's fall, PULSE's code: contact and height < 0.15 m)."""
    below = body_pos[..., 2] < fall_height
    return (body_contact & ~allowed.to(body_contact.device) & below).any(-1)


def pairwise_distances(traj: Tensor) -> Tensor:
    """(N, N) mean over t and b of ‖traj[t, i, b] − traj[t, j, b]‖ for (T, N, B, 3) trajectories."""
    T, N, B, _ = traj.shape
    x = traj.permute(1, 0, 2, 3).reshape(N, T * B, 3)
    out = torch.zeros(N, N, dtype=torch.float64)
    for i in range(N - 1):
        d = torch.linalg.vector_norm(x[i + 1 :] - x[i], dim=-1).mean(-1).double()
        out[i, i + 1 :] = d
        out[i + 1 :, i] = d
    return out


def generation_intervals(result: dict[str, Any], survival: list[float], distances: Tensor, resamples: int = 2000) -> dict[str, list[float]]:
    """95% intervals over the rollouts (:mod:`mocap.intervals`): Wilson for the fall and down-at-end
    shares and the filtered share (rollouts as the effective count: transitions within one are
    correlated); bootstrap for the time to fall, the survival time and the diversity (rollouts
    resampled, their pairwise distances averaged over distinct pairs); mean ± 1.96 std / √rollouts
    for the match distance."""
    import numpy as np

    from mocap.intervals import bootstrap_mean, normal_mean, wilson

    n = int(result["num_rollouts"])
    found = {
        "fall_rate": wilson(result["fall_rate"] * n, n),
        "down_at_end": wilson(result["down_at_end"] * n, n),
        "filtered": wilson(result["filtered"] * n, n),
        "time_to_fall_s": bootstrap_mean([t for t in result["fall_time_s_per_rollout"] if t is not None]),
        "survival_s": bootstrap_mean(survival),
        "match_distance": normal_mean(result["match_distance"], result["match_distance_std"], n),
    }
    if n >= 2:
        rng = np.random.default_rng(0)
        dist = distances.numpy()
        means = []
        for _ in range(resamples):
            idx = rng.integers(0, n, n)
            sub = dist[np.ix_(idx, idx)]
            distinct = idx[:, None] != idx[None, :]
            means.append(float(sub[distinct].mean()) if distinct.any() else math.nan)
        finite = [m for m in means if math.isfinite(m)]
        found["diversity_m"] = (float(np.percentile(finite, 2.5)), float(np.percentile(finite, 97.5))) if finite else None
    return {k: list(v) for k, v in found.items() if v is not None}


def pairwise_diversity(traj: Tensor) -> float:
    """Mean over pairs i < j of mean_{t,b} ‖traj[t, i, b] − traj[t, j, b]‖ for (T, N, B, 3) trajectories."""
    T, N, B, _ = traj.shape
    if N < 2:
        return float("nan")
    x = traj.permute(1, 0, 2, 3).reshape(N, T * B, 3)
    total, pairs = 0.0, 0
    for i in range(N - 1):
        d = torch.linalg.vector_norm(x[i + 1 :] - x[i], dim=-1).mean(-1)  # (N - i - 1,)
        total += float(d.sum())
        pairs += d.numel()
    return total / pairs


def motion_matching(generated: Tensor, dataset: Tensor, threshold: float, chunk: int = 4096) -> dict[str, float]:
    """hybrid_rvq Eq. 8 on transition features (module docstring).

    Args:
        generated: (M, F) generated transitions; dataset: (K, F) dataset transitions (unnormalized).
        threshold: filter threshold on the squared distance divided by F.
    """
    best, idx = nearest_transitions(generated, dataset, chunk)
    keep = best / generated.shape[1] <= threshold
    covered = torch.zeros(len(dataset), dtype=torch.bool)
    covered[idx[keep]] = True
    return {
        "match_distance": float(best[keep].mean()) if bool(keep.any()) else float("nan"),
        "match_distance_std": float(best[keep].std()) if int(keep.sum()) > 1 else float("nan"),
        "filtered": float(1.0 - keep.double().mean()),
        "coverage": float(covered.double().mean()),
        "dataset_transitions": int(len(dataset)),
        "generated_transitions": int(len(generated)),
    }


def dataset_transitions(lib: MotionLibrary, dt: float, sixd: SixD = "zhou") -> Tensor:
    """(K, 2P) proprioception pairs (s_{t-1}, s_t) of every clip sampled at the control rate."""
    rows = []
    for c in range(lib.num_clips):
        n = int(math.floor(float(lib.durations[c]) / dt + 1e-6)) + 1
        if n < 2:
            continue
        ids = torch.full((n,), c, dtype=torch.long, device=lib.device)
        times = torch.arange(n, dtype=torch.float64, device=lib.device) * dt
        feat = proprioception(lib.frames(ids, times), sixd).float().cpu()
        rows.append(torch.cat([feat[:-1], feat[1:]], -1))
    return torch.cat(rows)


def start_states(
    lib: MotionLibrary, n: int, skeleton: Any, min_height: float, generator: torch.Generator, clips: list[str] | None = None
) -> tuple[Tensor, Tensor]:
    """``n`` (clip id, time) pairs drawn with the library's weights whose frames have every non-foot body above
    ``min_height``; with ``clips``, only frames of those clips (their weights renormalized; the library, and so
    the motion-matching dataset, stays whole). ``ValueError`` for an empty list or an unknown clip name."""
    allowed = allowed_contact_mask(skeleton).cpu()
    weights = None
    if clips is not None:
        if not clips:
            raise ValueError("generation start clips: need at least one clip name")
        try:
            chosen = torch.tensor([lib.clip_index(c) for c in clips])
        except KeyError as exc:
            raise ValueError(str(exc.args[0])) from None
        weights = torch.zeros(lib.num_clips, dtype=torch.float64)
        weights[chosen] = lib.weights.double().cpu()[chosen]
        if not float(weights.sum()) > 0:  # clips named on purpose that the motion set weights 0: equally
            weights[chosen] = 1.0
    ids_out, t_out = [], []
    have = 0
    for _ in range(100):
        ids, times = lib.sample(4 * n, generator=generator, weights=weights)
        frames = lib.frames(ids, times)
        low = (frames.body_pos[..., 2].cpu() < min_height) & ~allowed
        ok = ~low.any(-1)
        ids_out.append(ids[ok.to(ids.device)])
        t_out.append(times[ok.to(times.device)])
        have += int(ok.sum())
        if have >= n:
            break
    if have < n:
        raise ValueError(f"fewer than {n} start frames with every non-foot body above {min_height} m in the motion library")
    return torch.cat(ids_out)[:n], torch.cat(t_out)[:n]


def falls_by_start_clip(clips: list[str], fall_times: list[float | None], down_at_end: list[bool]) -> dict[str, dict[str, Any]]:
    """Per start clip (sorted by name): its rollouts, how many fell (``fall_times``: the time of a rollout's
    first fall in s, None when it did not fall), the mean time to that fall over those that fell (None
    when none did) and how many were down at the end."""
    rows: dict[str, dict[str, Any]] = {}
    times: dict[str, list[float]] = {}
    for clip, t, d in zip(clips, fall_times, down_at_end, strict=True):
        row = rows.setdefault(clip, {"rollouts": 0, "falls": 0, "down_at_end": 0})
        row["rollouts"] += 1
        row["falls"] += int(t is not None)
        row["down_at_end"] += int(d)
        if t is not None:
            times.setdefault(clip, []).append(float(t))
    return {clip: {**row, "time_to_fall_s": sum(times[clip]) / len(times[clip]) if clip in times else None} for clip, row in sorted(rows.items())}


def _reference_free(obs: Observations) -> Observations:
    """The observation a generation rollout gives the latent: proprioception only."""
    return Observations(proprio=obs.proprio, goal=None, extra={})


def evaluate_generation(
    latent: Any,
    imitator: Imitator | None,
    to_pd_targets: Callable[[Observations, Tensor], Tensor],
    lib: MotionLibrary,
    make_sim: Callable[[int], Simulator],
    params: GenerationParams,
    *,
    video: Path | None = None,
    console: Any = None,
) -> dict[str, Any]:
    """Roll out ``latent.random_action`` from the prior and measure falls, diversity and motion matching.

    ``imitator.observe`` supplies the proprioception (its goal is dropped); ``to_pd_targets`` maps a
    decoder output to PD targets without a reference (see the module docstring).
    """
    if not latent.samples_prior:
        raise ValueError(
            f"{type(latent).__name__} cannot generate: it has no prior to sample (LatentSpace.samples_prior is False); a latent "
            "space that has one sets the class attribute samples_prior = True and implements random_action "
            "(docs/plugins.md, 'What the framework calls, and when')"
        )
    p = params
    gen = torch.Generator().manual_seed(p.seed)
    sim = make_sim(p.num_rollouts)
    skeleton = sim.skeleton
    ids, times = start_states(lib, p.num_rollouts, skeleton, p.start_min_height, gen, p.start_clips)
    ref = lib.frames(ids, times)
    sim.reset(torch.arange(p.num_rollouts), ref)
    state = sim.state
    steps = max(1, int(round(p.seconds / sim.dt)))
    allowed = allowed_contact_mask(skeleton).to(state.body_pos.device)
    origin, heading = heading_frame(state.root_pos.float().cpu(), state.root_rot.float().cpu())
    body = torch.zeros(steps + 1, p.num_rollouts, skeleton.num_bodies, 3)
    props = []
    body[0] = state.body_pos.float().cpu()
    first_fall = torch.full((p.num_rollouts,), -1, dtype=torch.long)
    down = torch.zeros(p.num_rollouts, dtype=torch.bool)
    unstable = torch.zeros(p.num_rollouts, dtype=torch.bool)
    recorder = None
    if video is not None and p.video_rollouts > 0:
        recorder = sim.make_recorder()
    rec_steps = min(steps, int(round(p.video_seconds / sim.dt)))
    frames_by_env: list[list[Any]] = [[] for _ in range(min(p.video_rollouts, p.num_rollouts))]
    from rich.progress import Progress

    sixd = imitator.proprio_sixd if imitator is not None else "zhou"

    def observe(state: Any, ref: Any) -> Observations:
        if imitator is None:  # a latent that decodes to PD targets on its own (VMP): plain proprioception
            return Observations(proprio=proprioception(state, sixd).float(), goal=None, extra={})
        return _reference_free(imitator.observe(state, ref))

    with Progress(transient=True, console=console, disable=console is None) as bar:
        task = bar.add_task("generation", total=steps)
        for k in range(1, steps + 1):
            obs = observe(state, ref)
            props.append(obs.proprio.float().cpu())
            with torch.no_grad():
                out = latent.random_action(obs, noise_scale=p.noise_scale, generator=gen)
                try:
                    targets = to_pd_targets(obs, out)
                except ValueError as exc:
                    raise ValueError(
                        f"generation needs PD targets without a reference motion ({exc}); distill the latent with "
                        "label: pd_targets or use an imitator with absolute actions"
                    ) from None
            state = sim.step(targets)
            body[k] = state.body_pos.float().cpu()
            down = fallen_down(state.body_pos, state.body_contact, allowed, p.fall_height).cpu()
            first_fall = torch.where((first_fall < 0) & down, torch.full_like(first_fall, k), first_fall)
            if state.unstable.numel():
                unstable |= state.unstable.cpu()
            if recorder is not None and k <= rec_steps:
                for e in range(len(frames_by_env)):
                    frames_by_env[e].append((state.root_pos[e].cpu(), state.root_rot[e].cpu(), state.dof_pos[e].cpu()))
            bar.advance(task)
    obs = observe(state, ref)
    props.append(obs.proprio.float().cpu())
    sim.close()
    dt = sim.dt
    fell = first_fall >= 0
    fall_times = first_fall[fell].double() * dt
    horizon = steps * dt
    survival = torch.where(fell, first_fall.double() * dt, torch.full_like(first_fall, 0, dtype=torch.float64) + horizon)
    traj = in_start_frame(body, origin, heading)
    prop = torch.stack(props)  # (T + 1, N, P)
    gen_trans = torch.cat([prop[:-1], prop[1:]], -1).reshape(-1, 2 * prop.shape[-1])
    matching = motion_matching(gen_trans, dataset_transitions(lib, dt, sixd), p.filter_threshold)
    starts = "library start states" if p.start_clips is None else f"start states of {', '.join(p.start_clips)}"
    start_names = [lib.clip_names[int(i)] for i in ids]
    per_rollout = [float(f) * dt if f >= 0 else None for f in first_fall.tolist()]
    result: dict[str, Any] = {
        "protocol": f"mocap-generation-v1 (prior rollouts from {starts}; see mocap.generation)",
        "params": p.model_dump(),
        "num_rollouts": p.num_rollouts,
        "seconds": horizon,
        "fall_rate": float(fell.double().mean()),
        "time_to_fall_s": float(fall_times.mean()) if bool(fell.any()) else float("nan"),
        "survival_s": float(survival.mean()),
        "down_at_end": float(down.double().mean()),
        "unstable": int(unstable.sum()),
        "diversity_m": pairwise_diversity(traj),
        **matching,
        "start_clips": start_names,
        "fall_time_s_per_rollout": per_rollout,
        "falls_by_start_clip": falls_by_start_clip(start_names, per_rollout, down.tolist()),
    }
    result["ci95"] = generation_intervals(result, survival.tolist(), pairwise_distances(traj))
    if recorder is not None:
        for frames in frames_by_env:
            for pose in frames:
                recorder.add_frame(pose)
        recorder.save(video)
        result["video"] = str(video)
    return result


def generate_from_target(loaded: Any, params: GenerationParams, *, video: Path | None = None, console: Any = None) -> dict[str, Any]:
    """:func:`evaluate_generation` of a built evaluation target (``mocap.eval_targets.build_evaluation_target``)."""
    own = bool(loaded.latent.decodes_pd_targets)  # VMP: random_action gives PD targets
    imitator = None if own else loaded.imitator
    mapping = (lambda obs, out: out) if own else loaded.to_pd_targets
    return evaluate_generation(loaded.latent, imitator, mapping, loaded.library, loaded.make_sim, params, video=video, console=console)


class GenerationEval(Trainer):
    """Trainer ``generation_eval``: :func:`evaluate_generation` of the spec's trained latent space;
    publishes ``generation.json`` / ``generation.md`` (and ``generation.mp4``) in the run directory."""

    def __init__(self, params: GenerationParams):
        self.params = params

    def run(self, ctx: Any) -> Any:
        from mocap.checkpoint import atomic_write_json, atomic_write_text
        from mocap.distill_files import load_latent_state
        from mocap.interfaces import StageResult
        from mocap.pipeline import StageFailed

        latent_stage = ctx.upstream.get("latent")
        if latent_stage is None or latent_stage.checkpoint is None:
            raise StageFailed("generation_eval needs a trained latent stage")
        upstream = ctx.upstream.get("imitator")
        imitator = ctx.stage_component("imitator", checkpoint=upstream.checkpoint if upstream else None) if ctx.spec.imitator is not None else None
        latent = ctx.stage_component("latent", checkpoint=latent_stage.checkpoint)
        latent.eval()
        if latent.decodes_pd_targets:  # VMP: random_action already gives PD targets
            label = "pd_targets"
        else:
            label = load_latent_state(latent_stage.checkpoint)["extra"].get("label", "policy_output")
        skeleton = ctx.skeleton
        lib = MotionLibrary(ctx.build("motions").load(skeleton), skeleton)

        def make_sim(n: int) -> Simulator:
            return ctx.build("simulator", skeleton=skeleton, num_envs=n, seed=ctx.seed)

        if label == "pd_targets":
            mapping = lambda obs, out: out
        else:  # a latent distilled from policy outputs: the spec has the imitator that maps them
            assert imitator is not None
            mapping = imitator.to_pd_targets
        try:
            result = evaluate_generation(latent, imitator, mapping, lib, make_sim, self.params, video=ctx.publish("generation.mp4"), console=ctx.console)
        except ValueError as exc:
            raise StageFailed(f"generation_eval: {exc}") from None
        atomic_write_json(ctx.publish("generation.json"), result)
        atomic_write_text(ctx.publish("generation.md"), render_generation({ctx.spec.latent.name: result}) + "\n" + render_falls_by_start_clip(result))
        numeric = {k: float(v) for k, v in result.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
        ctx.log.log(0, **numeric)
        return StageResult(checkpoint=None, metrics=numeric)


__all__ = [
    "GenerationEval",
    "dataset_transitions",
    "evaluate_generation",
    "falls_by_start_clip",
    "generate_from_target",
    "fallen_down",
    "heading_frame",
    "in_start_frame",
    "motion_matching",
    "pairwise_diversity",
    "start_states",
]
