"""Distillation learning curves: the student's imitation success and MPJPE-g against env steps.

The ``distill`` trainer evaluates the student as an imitator (z = encoder mean, every clip from its
first frame) every ``eval_every`` iterations and logs ``eval/*`` to the run's ``metrics.jsonl``.
This script collects those points from one or more run directories and plots them next to the
teacher's result:

    python bench/distill_curves.py runs/pulse-amp-bundled runs/hybrid-rvq-amp-bundled \
        --teacher checkpoints/imitator_amp/eval.json --out bench/results/distill_curves

writes ``<out>.json`` (per run: the eval points and the training action loss) and ``<out>.png``.
``--offset`` shifts each run's env steps (one value per run): a run that continued another one's
latent (the distill trainer's ``init_latent``) is plotted from where its source ended.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def shift(steps: float | None, offset: int) -> float | None:
    """``steps`` + ``offset`` (None stays None)."""
    return None if steps is None else float(steps) + offset


def read_run(run_dir: Path, offset: int = 0) -> dict:
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines() if line.strip()]
    rows = [r for r in rows if r.get("stage") == "latent"]
    evals = [
        {
            "iteration": r["step"],
            "env_steps": shift(r.get("env_steps"), offset),
            "success_rate": r["eval/success_rate"],
            "mpjpe_g": r.get("eval/mpjpe_g"),
            "mpjpe_g_succ": r.get("eval/mpjpe_g_succ"),
        }
        for r in rows
        if "eval/success_rate" in r
    ]
    loss = [{"env_steps": shift(r.get("env_steps"), offset), "action": r.get("loss/action")} for r in rows if "loss/action" in r]
    from mocap.runfiles import read_spec_file

    spec = read_spec_file(run_dir / "spec.yaml") if (run_dir / "spec.yaml").is_file() else {}
    section = (spec or {}).get("latent") or {}
    latent = f"{section.get('name', '?')} ({(section.get('params') or {}).get('variant', '')})".replace(" ()", "")
    return {"run": run_dir.name, "latent": latent, "offset": offset, "evals": evals, "action_loss": loss[:: max(1, len(loss) // 200)]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, nargs="+", help="run directories of distillation runs")
    parser.add_argument("--teacher", type=Path, default=None, help="the teacher's `mocap eval --json` output")
    parser.add_argument("--out", type=Path, default=Path("bench/results/distill_curves"))
    parser.add_argument("--offset", type=int, nargs="+", default=None, help="env steps added to each run's points, one per run")
    args = parser.parse_args(argv)
    offsets = args.offset or [0] * len(args.runs)
    if len(offsets) != len(args.runs):
        parser.error(f"--offset takes one value per run ({len(args.runs)}), got {len(offsets)}")
    runs = [read_run(r, o) for r, o in zip(args.runs, offsets)]
    teacher = json.loads(args.teacher.read_text())["aggregate"] if args.teacher else None
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps({"teacher": teacher, "runs": runs}, indent=2) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for run in runs:
        x = [p["env_steps"] / 1e6 for p in run["evals"]]
        axes[0].plot(x, [100 * p["success_rate"] for p in run["evals"]], "o-", label=run["run"])
        axes[1].plot(x, [p["mpjpe_g"] for p in run["evals"]], "s-", label=run["run"])
        lx = [p["env_steps"] / 1e6 for p in run["action_loss"]]
        axes[2].plot(lx, [p["action"] for p in run["action_loss"]], label=run["run"])
    if teacher:
        axes[0].axhline(100 * teacher["success_rate"], color="k", ls="--", label="teacher (imitator)")
        axes[1].axhline(teacher["mpjpe_g"], color="k", ls="--", label="teacher (imitator)")
    axes[0].set_ylabel("clips succeeded (%)")
    axes[1].set_ylabel("MPJPE-g, all clips (mm)")
    axes[2].set_ylabel("training action loss (own units per latent)")
    axes[2].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("env steps (M)")
        ax.legend(fontsize=8)
    fig.suptitle("distillation from the committed imitator (bundled clips)")
    fig.tight_layout()
    fig.savefig(args.out.with_suffix(".png"), dpi=100)
    print(f"wrote {args.out.with_suffix('.json')} and {args.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
