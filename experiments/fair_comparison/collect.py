"""Collect an A/B of task runs into one table: per arm (run directories ``<arm>_s<seed>``), the
deterministic task-eval metrics (``mocap task-eval RUN --start-clips walk,run --json
RUN/eval_walkrun.json``, naturalness included), mean and 95% bootstrap interval over seeds, and the
sample efficiency of its training curves (:mod:`mocap.sample_efficiency`).

    python experiments/fair_comparison/collect.py RUNS_DIR --arms speed_pulse_walkrun speed_scratch_walkrun \\
        --out experiments/fair_comparison/starts_speed

writes ``OUT.json`` and ``OUT.md``. A run without its ``eval_walkrun.json`` is evaluated first.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

METRICS = ("speed_error", "terminated_share", "episode_return", "mm_distance", "mm_within", "foot_skating", "root_jerk", "crouch_share", "realism")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path)
    ap.add_argument("--arms", nargs="+", required=True)
    ap.add_argument("--eval-name", default="eval_walkrun.json")
    ap.add_argument("--start-clips", default="walk,run")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    from mocap.intervals import bootstrap_mean
    from mocap.sample_efficiency import efficiency, read_curve, render_efficiency

    table: dict[str, dict] = {}
    curves = {}
    for arm in args.arms:
        runs = sorted(p for p in args.runs.glob(f"{arm}_s*") if p.is_dir() and (p / "stages.json").is_file())
        evals = []
        for run in runs:
            path = run / args.eval_name
            if not path.is_file():
                cmd = ["mocap", "task-eval", str(run), "--start-clips", args.start_clips, "--json", str(path)]
                subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
            evals.append(json.loads(path.read_text()))
        row = {"seeds": [r.name for r in runs]}
        for m in METRICS:
            vals = [float(e[m]) for e in evals if isinstance(e.get(m), (int, float)) and math.isfinite(float(e[m]))]
            row[m] = {"mean": float(np.mean(vals)) if vals else math.nan, "ci95": bootstrap_mean(vals), "values": vals}
        table[arm] = row
        curves[arm] = [c for c in (read_curve(r / "metrics.jsonl") for r in runs) if len(c[0])]
    eff = efficiency({a: c for a, c in curves.items() if c})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    record = {"command": "python " + " ".join(sys.argv), "eval": args.eval_name, "arms": table, "efficiency": eff}
    args.out.with_suffix(".json").write_text(json.dumps(record, indent=2) + "\n")
    lines = [f"# {args.out.name}", "", f"Deterministic task-eval ({args.eval_name}: 64 envs x 10 s from {args.start_clips} starts); "
             "mean over seeds [95% bootstrap interval] (each seed's value in the JSON).", "",
             "| arm | seeds | " + " | ".join(METRICS) + " |", "|---|---|" + "---|" * len(METRICS)]  # fmt: skip
    for arm, row in table.items():
        cells = []
        for m in METRICS:
            e = row[m]
            text = "-" if not math.isfinite(e["mean"]) else f"{e['mean']:.3g}"
            if e["ci95"]:
                text += f" [{e['ci95'][0]:.3g}, {e['ci95'][1]:.3g}]"
            cells.append(text)
        lines.append(f"| {arm} | {len(row['seeds'])} | " + " | ".join(cells) + " |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n" + render_efficiency(eff))
    print(args.out.with_suffix(".md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
