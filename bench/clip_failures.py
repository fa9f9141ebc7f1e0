"""Per-clip training failures of a PHC imitation run next to its evaluation.

Reads the env state inside a PPO checkpoint (``ppo.pt`` of a ``phc`` stage: the hard-negative
counts of every training episode, ``episodes_per_clip`` / ``failures_per_clip``, and the clip
sampling weights) and, optionally, an ``eval.json`` of ``mocap eval``. A training episode fails when
it terminates before its time limit (300 steps) or its clip's end; episodes of looping clips run
the clip over and over until the limit, so for those "success" means 10 s of repeats, while the
evaluation plays every clip once. The table shows where training samples go and why.

    python bench/clip_failures.py RUN/artifacts/imitator-KEY/ppo.pt --eval checkpoints/imitator_amp_v4/eval.json \\
        --out bench/results/clip_failures_v4.json

Writes ``--out`` (JSON) and a markdown table next to it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def clip_rows(env: dict[str, Any], loops: dict[str, bool] | None = None, evaluation: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """One row per clip from an imitation env's ``state_dict`` (and an eval table)."""
    names = list(env["clip_names"])
    episodes = [float(x) for x in env["episodes_per_clip"]]
    failures = [float(x) for x in env["failures_per_clip"]]
    weights = [float(x) for x in env["weights"]]
    total_w = sum(weights) or 1.0
    rows = []
    for i, name in enumerate(names):
        row: dict[str, Any] = {
            "clip": name,
            "training_episodes": int(episodes[i]),
            "training_failure_rate": failures[i] / episodes[i] if episodes[i] > 0 else None,
            "sampling_weight": weights[i] / total_w,
        }
        if loops is not None:
            row["loops"] = loops.get(name)
        if evaluation is not None and name in evaluation.get("clips", {}):
            c = evaluation["clips"][name]
            row["eval_success"] = bool(c["success"])
            row["eval_mpjpe_g_mm"] = c.get("mpjpe_g")
        rows.append(row)
    return rows


def render(rows: list[dict[str, Any]], source: str) -> str:
    def f(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    lines = [
        f"# Per-clip training failures: {source}",
        "",
        "Training failure rate: share of the run's training episodes of the clip that terminated early (looping clips run "
        "until the 10 s limit, so they must survive every repeat). Sampling weight: the clip's share of new episodes "
        "(hard-negative mining). Evaluation: `mocap eval` (each clip once from its first frame, deterministic).",
        "",
        "| clip | loops | training episodes | training failure rate | sampling weight | eval | eval MPJPE-g (mm) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ev = r.get("eval_success")
        lines.append(
            f"| {r['clip']} | {f(r.get('loops'), '')} | {r['training_episodes']} | {f(r['training_failure_rate'], '.2f')} "
            f"| {r['sampling_weight']:.3f} | {'-' if ev is None else ('yes' if ev else 'no')} | {f(r.get('eval_mpjpe_g_mm'), '.1f')} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint", type=Path, help="ppo.pt of a phc imitator stage")
    ap.add_argument("--eval", type=Path, default=None, help="eval.json of `mocap eval` for the same policy")
    ap.add_argument("--motions", default="deepmimic", help="show the looping flags of this motion source's clips ('' to skip)")
    ap.add_argument("--out", type=Path, default=Path("bench/results/clip_failures.json"))
    args = ap.parse_args(argv)
    from mocap.checkpoint import load_checkpoint

    data = load_checkpoint(args.checkpoint)
    env = data.get("env")
    if not isinstance(env, dict) or "failures_per_clip" not in env:
        raise SystemExit(f"error: {args.checkpoint}: no imitation env state with per-clip failure counts (a ppo.pt of a phc stage?)")
    evaluation = json.loads(args.eval.read_text()) if args.eval else None
    loops = _loops(args.motions, list(env["clip_names"])) if args.motions else None
    rows = clip_rows(env, loops, evaluation)
    result = {"checkpoint": str(args.checkpoint), "env_steps": data.get("env_steps"), "eval": str(args.eval) if args.eval else None, "clips": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    md = render(rows, f"{args.checkpoint} ({data.get('env_steps')} env steps)")
    args.out.with_suffix(".md").write_text(md)
    print(md)
    return 0


def _loops(source: str, names: list[str]) -> dict[str, bool]:
    """Looping flags of the bundled DeepMimic clips (the only source this script knows)."""
    if source != "deepmimic":
        raise SystemExit(f"error: --motions {source!r}: only 'deepmimic' (the bundled clips) is known here; pass --motions '' to skip")
    from mocap.humanoids import AmpParams, make_amp
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource

    motion_set = DeepMimicSource(DeepMimicParams()).load(make_amp(AmpParams()))
    return {c.name: bool(c.loop) for c in motion_set.clips if c.name in names}


if __name__ == "__main__":
    raise SystemExit(main())
