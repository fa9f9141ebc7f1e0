"""Recovery rates of several imitators, with and without the get-up planner, over several seeds.

Runs ``mocap recover TARGET --planner P --seed S --json ...`` (protocol ``mocap-recovery-v2``: 64
fallen starts, half of them also 2-5 m away, 10 s, a standing-still reference) for every target,
planner and seed, in child processes (``--jobs`` at a time), and writes ``--out`` (JSON) and a markdown table next to it:
per target and planner the recovery rate (mean and per seed), the near and far rates, the share
that stood up (planner only), the share whose root came back, and the share still on the reference
at the end. The load average goes in the JSON; the rates do not depend on it (the rollouts are
deterministic), only the minutes do.

    python bench/recovery_compare.py --target v4=checkpoints/imitator_amp_v4 --planner none --planner getup \\
        --seed 0 --seed 1 --out bench/results/recovery_planner.json
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ThreadPoolExecutor
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

KEYS = ("recovery_rate", "fallen_near_recovery_rate", "fallen_far_recovery_rate", "stood_up_rate", "root_back_rate", "tracking_at_end")


def summarize(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean over the seeds of each rate in :data:`KEYS` that every run reports; the per-seed recovery rates."""
    out: dict[str, Any] = {"seeds": [r["seed"] for r in runs], "recovery_rate_per_seed": [r["recovery_rate"] for r in runs]}
    for k in KEYS:
        vals = [r[k] for r in runs if k in r]
        if vals and len(vals) == len(runs):
            out[k] = sum(vals) / len(vals)
    return out


def render(rows: list[dict[str, Any]], title: str) -> str:
    def pct(v: Any) -> str:
        return "-" if v is None else f"{100 * v:.1f}%"

    lines = [
        f"# {title}",
        "",
        "| target | planner | recovery (mean) | per seed | fallen near | fallen and far | stood up | root back | on the reference at the end |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        s = r["summary"]
        seeds = ", ".join(pct(v) for v in s["recovery_rate_per_seed"])
        lines.append(
            f"| {r['target']} | {r['planner']} | {pct(s.get('recovery_rate'))} | {seeds} | {pct(s.get('fallen_near_recovery_rate'))} | "
            f"{pct(s.get('fallen_far_recovery_rate'))} | {pct(s.get('stood_up_rate'))} | {pct(s.get('root_back_rate'))} | {pct(s.get('tracking_at_end'))} |"
        )
    return "\n".join(lines) + "\n"


def run_one(target: str, planner: str, seed: int, trials: int, seconds: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "r.json"
        cmd = [sys.executable, "-m", "mocap", "recover", target, "--planner", planner, "--seed", str(seed), "--trials", str(trials)]
        cmd += ["--seconds", str(seconds), "--json", str(out)]
        subprocess.run(cmd, check=True, capture_output=True)
        res = json.loads(out.read_text())
    res["seed"] = seed
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", action="append", required=True, help="NAME=PATH, what `mocap recover` accepts (repeatable)")
    ap.add_argument("--planner", action="append", choices=["none", "getup", "getup-pose"], help="repeatable (default: none and getup)")
    ap.add_argument("--seed", dest="seeds", action="append", type=int, help="repeatable (default: 0)")
    ap.add_argument("--jobs", type=int, default=1, help="`mocap recover` processes at a time")
    ap.add_argument("--trials", type=int, default=64)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--title", default="Recovery rate (mocap recover, protocol mocap-recovery-v2)")
    ap.add_argument("--out", type=Path, default=Path("bench/results/recovery_compare.json"))
    args = ap.parse_args(argv)
    targets = []
    for t in args.target:
        name, sep, path = t.partition("=")
        if not sep or not name or not path:
            ap.error(f"--target must be NAME=PATH, not {t!r}")
        targets.append((name, path))
    planners, seeds = args.planner or ["none", "getup"], args.seeds or [0]
    load_before = list(os.getloadavg())
    start = time.perf_counter()
    jobs = [(name, path, planner, s) for name, path in targets for planner in planners for s in seeds]
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        done = list(pool.map(lambda j: run_one(j[1], j[2], j[3], args.trials, args.seconds), jobs))
    rows = []
    for name, path in targets:
        for planner in planners:
            runs = [r for j, r in zip(jobs, done, strict=True) if j[0] == name and j[2] == planner]
            rows.append({"target": name, "path": path, "planner": planner, "runs": runs, "summary": summarize(runs)})
            print(f"{name} {planner}: recovery {rows[-1]['summary']['recovery_rate_per_seed']}", flush=True)
    result = {
        "protocol": "mocap-recovery-v2",
        "command": "python bench/recovery_compare.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "trials": args.trials,
        "seconds": args.seconds,
        "minutes": round((time.perf_counter() - start) / 60.0, 2),
        "load_avg_before": load_before,
        "load_avg_after": list(os.getloadavg()),
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    args.out.with_suffix(".md").write_text(render(rows, args.title), encoding="utf-8")
    print(f"wrote {args.out} and {args.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
