"""Learning curve of an imitator training run: success and MPJPE-g against env steps and wall-clock.

The PPO trainer keeps one resumable checkpoint (``ppo.pt``) in the run's artifact directory. This
script evaluates it with the project's imitation protocol (``mocap eval``'s: every clip once from
its first frame, deterministic actions) each time it changes, and appends a point:

    python bench/imitator_curve.py watch runs/artifacts/imitator-<key> --every 600   # while training
    python bench/imitator_curve.py plot runs/artifacts/imitator-<key>/curve.jsonl --out bench/results/imitator_curve

``plot`` writes ``<out>.json`` (the points and the final values) and ``<out>.png``. Run ``watch`` in
the background next to the training; each evaluation takes ~10-20 s of CPU on 2 cores, so a
point every 10 minutes costs the run about 2%.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path


def evaluate_checkpoint(checkpoint: Path) -> dict:
    import torch

    from mocap.checkpoint import load_checkpoint
    from mocap.evaluation import ImitationEvalParams
    from mocap.eval_targets import load_evaluation_target
    from mocap.imitation_eval import evaluate_imitator
    from mocap.metrics import default_metrics
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins

    torch.set_num_threads(1)
    plugins = get_plugins()
    target = load_evaluation_target(checkpoint, plugins)
    resolved, ckpt = target.resolved, target.imitator_checkpoint
    spec = resolved.spec
    skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params.get("humanoid"))
    lib = MotionLibrary(plugins.get("motion_source", spec.motions.name).build(resolved.params.get("motions")).load(skeleton), skeleton)
    imitator = plugins.get("imitator", spec.imitator.name).build(resolved.params.get("imitator"), skeleton=skeleton, checkpoint=ckpt)
    sim = plugins.get("simulator", spec.simulator.name)
    params = resolved.params.get("simulator")
    table = evaluate_imitator(
        imitator, lib, lambda n: sim.build(params, skeleton=skeleton, num_envs=n, seed=spec.seed), ImitationEvalParams(), default_metrics()
    )
    data = load_checkpoint(checkpoint)
    agg = table["aggregate"]
    return {
        "env_steps": int(data.get("env_steps", 0)),
        "iteration": int(data.get("iteration", 0)),
        "success_rate": agg["success_rate"],
        "succeeded": agg["succeeded"],
        "total": agg["total"],
        "mpjpe_g": agg["mpjpe_g"],
        "mpjpe_g_succ": agg["mpjpe_g_succ"],
        "mpjpe_l": agg["mpjpe_l"],
        "clips_succeeded": [name for name, row in table["clips"].items() if row["success"]],
    }


def watch(artifact_dir: Path, every: float, once: bool = False) -> None:
    ckpt = artifact_dir / "ppo.pt"
    out = artifact_dir / "curve.jsonl"
    start = _run_start(artifact_dir)
    last_mtime = 0.0
    while True:
        if ckpt.is_file() and ckpt.stat().st_mtime != last_mtime:
            last_mtime = ckpt.stat().st_mtime
            point = evaluate_checkpoint(ckpt)
            point["wall_s"] = round(last_mtime - start, 1) if start else None
            with out.open("a") as fh:
                fh.write(json.dumps(point) + "\n")
            print(json.dumps(point), flush=True)
        if once or (artifact_dir / "DONE.json").is_file():
            return
        time.sleep(every)


def _run_start(artifact_dir: Path) -> float | None:
    """Wall-clock start of the training: the first record of the stage's metrics (via stages' spec.yaml mtime)."""
    spec = artifact_dir / "spec.yaml"
    return spec.stat().st_mtime if spec.is_file() else None


def plot(curve: Path, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = [json.loads(line) for line in curve.read_text().splitlines() if line.strip()]
    points.sort(key=lambda p: p["env_steps"])
    out.parent.mkdir(parents=True, exist_ok=True)
    summary = {"source": str(curve), "points": points, "final": points[-1] if points else None}
    out.with_suffix(".json").write_text(json.dumps(summary, indent=2) + "\n")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    steps = [p["env_steps"] / 1e6 for p in points]
    hours = [(p.get("wall_s") or 0) / 3600 for p in points]
    for ax, x, label in ((axes[0], steps, "env steps (M)"), (axes[1], hours, "wall-clock (h)")):
        ax.plot(x, [100 * p["success_rate"] for p in points], "o-", color="tab:green", label="success (%)")
        ax.set_xlabel(label)
        ax.set_ylabel("clips succeeded (%)", color="tab:green")
        ax.set_ylim(0, 100)
        twin = ax.twinx()
        twin.plot(x, [p["mpjpe_g"] for p in points], "s--", color="tab:red", label="MPJPE-g all clips (mm)")
        twin.plot(x, [p["mpjpe_g_succ"] for p in points], "^:", color="tab:purple", label="MPJPE-g successful clips (mm)")
        twin.set_ylabel("MPJPE-g (mm)", color="tab:red")
        twin.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"imitator learning curve ({curve.parent.name})")
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=100)
    print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.png')}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("watch", help="evaluate the run's checkpoint whenever it changes")
    w.add_argument("artifact_dir", type=Path)
    w.add_argument("--every", type=float, default=600.0, help="seconds between checks")
    w.add_argument("--once", action="store_true", help="evaluate once and exit")
    p = sub.add_parser("plot", help="write the curve's JSON and PNG")
    p.add_argument("curve", type=Path)
    p.add_argument("--out", type=Path, default=Path("bench/results/imitator_curve"))
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    if args.cmd == "watch":
        watch(args.artifact_dir, args.every, args.once)
    else:
        plot(args.curve, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
