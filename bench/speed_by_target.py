"""The ``speed`` task's error by commanded speed: where a trained speed policy meets the command.

``speed`` draws the commanded speed v* from U[0, 5] m/s (PULSE App. C, the ASE code); the bundled
clips run at about 3-4 m/s at most, so commands near 5 m/s may be out of reach of any policy
that moves like them. For each checkpoint or run directory of a trained speed policy
(``mocap export`` of a task run, or the run itself) this rolls out the deterministic policy
(:func:`mocap.task_run.open_task_run`, ``--envs`` envs x ``--seconds``, episodes restarting as in
training) and bins every control step by its commanded speed: the mean |v* - v.d| (m/s) with v the
state's root velocity (the reward's default), the mean speed along the target direction v.d, and the
number of steps per 1 m/s bin. Steps that end an episode are left out (the env then already holds
its next start state); steps of a humanoid falling before that count.

Usage: ``python bench/speed_by_target.py checkpoints/speed_pulse_v15 checkpoints/speed_scratch_v15
--out bench/results/speed_by_target_v15`` (writes ``.json`` and ``.png``).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import torch

BINS = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0)


def by_target(path: Path, envs: int, seconds: float) -> dict:
    from mocap.task_run import open_task_run

    run = open_task_run(path, envs)
    env, task = run.env, run.env.task
    steps = int(round(seconds / float(env.sim.dt)))
    n = len(BINS) - 1
    err, along, count = torch.zeros(n, dtype=torch.float64), torch.zeros(n, dtype=torch.float64), torch.zeros(n, dtype=torch.float64)
    try:
        obs = env.reset()
        for _ in range(steps):
            v_star = task.target_speed.clone().double()  # the command this step is rewarded against
            d = task.target_dir.clone().double()
            result = env.step(run.act(obs))
            obs = result.obs
            # the velocity the step reached; an env whose episode ended this step already holds its
            # next start state, so it is left out of this step's count
            kept = ~(result.terminated.bool() | result.truncated.bool()).cpu()
            v = env.sim.state.root_lin_vel.double().cpu()[:, :2]
            a = (v * d).sum(-1)
            idx = torch.bucketize(v_star, torch.tensor(BINS[1:-1], dtype=torch.float64), right=True)
            err.index_add_(0, idx[kept], (v_star - a).abs()[kept])
            along.index_add_(0, idx[kept], a[kept])
            count.index_add_(0, idx[kept], torch.ones_like(a)[kept])
    finally:
        run.close()
    c = count.clamp(min=1)
    return {
        "target": str(path),
        "latent": run.resolved.spec.latent.name,
        "bins_m_s": [[BINS[i], BINS[i + 1]] for i in range(n)],
        "speed_error": (err / c).tolist(),
        "speed_along": (along / c).tolist(),
        "steps": count.long().tolist(),
        "speed_error_all": float(err.sum() / count.sum()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("targets", nargs="+", type=Path)
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--out", type=Path, default=Path("bench/results/speed_by_target"))
    args = ap.parse_args()
    torch.set_num_threads(1)
    t0 = time.time()
    rows = [by_target(t, args.envs, args.seconds) for t in args.targets]
    out = {
        "command": "python bench/speed_by_target.py " + " ".join(str(t) for t in args.targets) + f" --envs {args.envs} --seconds {args.seconds:g}",
        "load_avg_1m": os.getloadavg()[0],
        "wall_s": round(time.time() - t0, 1),
        "results": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(out, indent=1) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    mids = [(lo + hi) / 2 for lo, hi in zip(BINS[:-1], BINS[1:])]
    for r in rows:
        label = f"{r['latent']} ({Path(r['target']).name})"
        a1.plot(mids, r["speed_error"], marker="o", label=label)
        a2.plot(mids, r["speed_along"], marker="o", label=label)
    a2.plot([0, 5], [0, 5], "k--", lw=0.8, label="commanded")
    a1.set(xlabel="commanded speed v* (m/s, 1 m/s bins)", ylabel="mean |v* - v.d| (m/s)", title="speed error by command")
    a2.set(xlabel="commanded speed v* (m/s)", ylabel="mean speed along the target direction (m/s)", title="achieved speed")
    for a in (a1, a2):
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.out.with_suffix(".png"), dpi=100)
    for r in rows:
        print(r["latent"], "error by bin", [round(x, 2) for x in r["speed_error"]], "along", [round(x, 2) for x in r["speed_along"]], "steps", r["steps"])
    print(f"wrote {args.out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
