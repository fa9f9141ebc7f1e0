"""Learning curves of a ``pmcp`` run, one panel row per phase (get-up, P(F), composer, primitives).

Reads the run's ``metrics.jsonl`` (every PMCP phase logs under its own stage label,
``imitator/prim1_getup``, ``imitator/prim1``, ``imitator/composer``, ...) and writes a compact JSON
(the chosen scalars every ``--every`` iterations) and a plot next to it::

    python bench/pmcp_phase_curves.py RUN_DIR/metrics.jsonl --out bench/results/pmcp_getup_from_v2/curves.json

Scalars: the mean reward per step, the AMP reward and the discriminator's accuracy (when the phase
has AMP on), the training episode length, and the share of envs whose root is farther than the
recovery goal's close distance (``recovery/far``); for a P(F) distilled with ``method: planner_distill``,
its fitting loss and the share of its rollouts that recovered.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

KEYS = {
    "reward_mean": "reward per step",
    "env/reward/amp": "AMP reward",
    "eval/amp/accuracy": "discriminator accuracy",
    "episode/length": "episode length (steps)",
    "env/recovery/far": "share of envs far (> close distance)",
    "loss": "distillation loss (P(F) planner_distill)",
    "distill/recovered": "rollouts recovered (distillation, mostly the teacher)",
}


def phase_curves(lines: list[dict], every: int) -> dict[str, dict[str, list[float]]]:
    """Per stage label: ``env_steps`` and each of :data:`KEYS` present, every ``every`` iterations
    (always keeping each phase's last line)."""
    by: dict[str, list[dict]] = {}
    for d in lines:
        by.setdefault(str(d.get("stage", "")), []).append(d)
    out: dict[str, dict[str, list[float]]] = {}
    for stage, ds in by.items():
        ds = sorted(ds, key=lambda d: d["step"])
        keep = [d for i, d in enumerate(ds) if int(d["step"]) % every == 0 or i == len(ds) - 1]
        curves: dict[str, list[float]] = {"iteration": [int(d["step"]) for d in keep], "env_steps": [float(d.get("env_steps", 0)) for d in keep]}
        for k in KEYS:
            if any(k in d for d in keep):
                curves[k] = [float(d[k]) if k in d else float("nan") for d in keep]
        out[stage] = curves
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("metrics", type=Path)
    ap.add_argument("--every", type=int, default=5)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    lines = [json.loads(x) for x in args.metrics.read_text().splitlines() if x.strip()]
    curves = phase_curves(lines, args.every)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"source": str(args.metrics.name), "every": args.every, "phases": curves}, indent=1) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stages = [s for s in curves if s]  # lines without a stage label are not a phase
    keys = [k for k in KEYS if any(k in curves[s] for s in stages)]
    fig, axes = plt.subplots(1, len(keys), figsize=(3.2 * len(keys), 3.0), squeeze=False)
    for ax, k in zip(axes[0], keys):
        for s in stages:
            if k in curves[s]:
                ax.plot([x / 1e6 for x in curves[s]["env_steps"]], curves[s][k], label=s.split("/")[-1])
        ax.set(xlabel="env steps in the phase (M)", title=KEYS[k])
        ax.title.set_fontsize(9)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out.with_suffix(".png"), dpi=100)
    print(f"wrote {args.out} and {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
