"""Random generation from a latent prior against the prior's noise scale.

PULSE's random generation samples ``z = mu_p + s * sigma_p * eps`` from the learned prior
R(z | s) with s = 1; ``mocap generate --noise s`` exposes s. This bench runs the project's
generation protocol (``mocap.generation``, protocol mocap-generation-v1: 64 rollouts of 10 s from
library start states) at several noise scales for each checkpoint, so that the fall rate and the
diversity can be read as a trade-off::

    python bench/generation_noise.py checkpoints/pulse_amp_v2 checkpoints/pulse_amp \\
        --noise 0 0.25 0.5 1 --out bench/results/generation_noise.json

It writes the JSON (one record per checkpoint and noise scale, every field ``mocap generate
--json`` writes) and a two-panel plot next to it (``.png``): fall rate and diversity against the
noise scale. s = 1 is the paper's setting; s = 0 rolls out the prior mean (the start states still
differ). Falls, diversity and matching are defined in ``mocap.generation``. Each record also
splits the falls by the clip a rollout started from (``falls_by_start_clip`` of ``mocap.generation_eval``:
rollouts, falls, the mean time to the first fall, how many were down at the end). ``--starts all walk,run`` repeats every measurement with the rollouts
started from all clips and from walk and run frames only (``mocap generate --start-clips``)::

    python bench/generation_noise.py checkpoints/pulse_amp_v15 --noise 1 --starts all walk,run \
        --out bench/results/generation_starts.json

The markdown next to the JSON (``.md``) tabulates every record and its falls per start clip.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path


def load(target: Path):
    """The built evaluation target of a latent checkpoint (loaded once, rolled out at every scale)."""
    from mocap.eval_targets import build_evaluation_target, load_evaluation_target
    from mocap.plugins import get_plugins

    plugins = get_plugins()
    info = load_evaluation_target(target, plugins)
    if info.latent_checkpoint is None:
        raise SystemExit(f"{target}: not a latent space")
    return build_evaluation_target(info, plugins)


def run_one(loaded, target: Path, noise: float, rollouts: int, seconds: float, seed: int, starts: str = "all") -> dict:
    """One generation measurement; ``starts``: ``all`` (every clip) or comma-separated clip names."""
    from mocap.generation import GenerationParams
    from mocap.generation_eval import generate_from_target
    from mocap.task_eval import split_clips

    clips = None if starts == "all" else split_clips(starts)
    params = GenerationParams(num_rollouts=rollouts, seconds=seconds, noise_scale=noise, seed=seed, start_clips=clips)
    t0 = time.perf_counter()
    result = generate_from_target(loaded, params)
    result["wall_s"] = time.perf_counter() - t0
    result["noise_scale"] = noise
    result["starts"] = starts
    result["checkpoint"] = str(target)
    return result


def render_markdown(records: list[dict]) -> str:
    """Every record as a row (checkpoint, starts, noise, falls, survival, diversity, coverage), then its falls per start clip."""
    lines = [
        f"# Random generation by start states ({records[0]['num_rollouts']} rollouts x {records[0]['seconds']:g} s each)" if records else "# Random generation",
        "",
        "| checkpoint | starts | noise | fell (share) | down at the end (share) | survival (s) | diversity (m) | coverage |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        lines.append(
            f"| {Path(r['checkpoint']).name} | {r.get('starts', 'all')} | {r['noise_scale']:g} | {r['fall_rate']:.3f} | "
            f"{r['down_at_end']:.3f} | {r['survival_s']:.2f} | {r['diversity_m']:.2f} | {r['coverage']:.3f} |"
        )
    lines += ["", "Falls per start clip (rollouts that fell / rollouts started there, at the mean time to the fall; down at the end):", ""]
    for r in records:
        per = r.get("falls_by_start_clip", {})
        text = ", ".join(f"{c} {v['falls']}/{v['rollouts']}{_fall_time(v)} ({v['down_at_end']})" for c, v in per.items())
        lines.append(f"- {Path(r['checkpoint']).name}, starts {r.get('starts', 'all')}, noise {r['noise_scale']:g}: {text}")
    return "\n".join([*lines, ""])


def _fall_time(row: dict) -> str:
    t = row.get("time_to_fall_s")
    return "" if t is None else f" at {t:.1f} s"


def plot(records: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.5))
    for ck, starts in dict.fromkeys((r["checkpoint"], r.get("starts", "all")) for r in records):
        rs = sorted((r for r in records if r["checkpoint"] == ck and r.get("starts", "all") == starts), key=lambda r: r["noise_scale"])
        xs = [r["noise_scale"] for r in rs]
        label = Path(ck).name + ("" if starts == "all" else f" ({starts} starts)")
        ax1.plot(xs, [r["fall_rate"] for r in rs], "o-", label=label)
        ax2.plot(xs, [r["diversity_m"] for r in rs], "o-", label=label)
    ax1.axhline(0.5, color="grey", ls="--", lw=0.8)
    ax1.set(xlabel="prior noise scale s", ylabel="fall rate (64 rollouts, 10 s)", ylim=(0, 1.05))
    ax2.set(xlabel="prior noise scale s", ylabel="diversity (m)")
    ax1.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--noise", nargs="+", type=float, default=[0.0, 0.25, 0.5, 1.0])
    ap.add_argument("--rollouts", type=int, default=64)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--starts", nargs="+", default=["all"], help="start-state sets: 'all' or comma-separated clips (e.g. walk,run)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--out", type=Path, default=Path("bench/results/generation_noise.json"))
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    records = []
    for ck in args.checkpoints:
        loaded = load(ck)
        for starts, s in [(st, s) for st in args.starts for s in args.noise]:
            r = run_one(loaded, ck, s, args.rollouts, args.seconds, args.seed, starts)
            print(
                f"{ck} starts {starts} noise {s:g}: fall {r['fall_rate']:.3f} after {r['time_to_fall_s']:.2f} s, "
                f"diversity {r['diversity_m']:.2f} m, match {r['match_distance']:.1f}"
            )
            records.append({k: v for k, v in r.items() if k != "video"})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    out = {
        "protocol": records[0]["protocol"] if records else None,
        "command": "python bench/generation_noise.py "
        + " ".join(map(str, args.checkpoints))
        + " --noise "
        + " ".join(f"{s:g}" for s in args.noise)
        + " --starts "
        + " ".join(args.starts),
        "load_average": list(os.getloadavg()),
        "records": records,
    }
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    plot(records, args.out.with_suffix(".png"))
    args.out.with_suffix(".md").write_text(render_markdown(records))
    print(f"wrote {args.out} and its .png, .md")


if __name__ == "__main__":
    main()
