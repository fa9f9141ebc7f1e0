"""Data-parallel scaling of imitator training: the bundled imitator spec run with 1 and with K processes.

Each setting is a real ``mocap run`` in a fresh directory under /tmp: one process as usual
(``python -m mocap run``), K processes with ``python -m torch.distributed.run --nproc_per_node K
-m mocap run`` (= ``torchrun``). Weak scaling: every process steps ``--num-envs`` envs, so an
iteration of K processes collects K times the samples; every setting runs ``--iterations`` PPO
iterations (the budget is set to match). From each run's ``metrics.jsonl`` (first iteration skipped
as warm-up when there are more): env steps/s over all processes (samples / (rollout + update
time); under torchrun the logged times are the slowest rank's), and rollout and update seconds per
iteration. The ratios are relative to 1 process. The periodic and final evaluations are off.

    python bench/scaling.py --iterations 6 --out bench/results/scaling.json

Quick check that it works (tiny budget): ``python bench/scaling.py --iterations 2 --num-envs 8
--horizon 8 --out /tmp/scaling.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_setting(args: argparse.Namespace, procs: int) -> dict:
    """One ``mocap run`` with ``procs`` processes; returns its measured throughput."""
    n, h = args.num_envs, args.horizon
    cores = os.cpu_count() or 1
    threads = args.torch_threads
    sim_threads = args.sim_threads or max(1, cores // procs)
    overrides = [
        f"imitator.trainer.params.num_envs={n}",
        f"imitator.trainer.params.horizon={h}",
        f"imitator.trainer.params.total_env_steps={args.iterations * n * h * procs}",
        f"imitator.trainer.params.minibatch_size={min(n * h, args.minibatch_size)}",
        f"imitator.trainer.params.torch_threads={threads}",
        f"imitator.trainer.params.checkpoint_every={args.iterations}",
        f"simulator.params.threads={sim_threads}",
        "imitator.params.eval_every=0",
        "eval=null",
    ]
    tmp = Path(tempfile.mkdtemp(prefix=f"mocap-scaling-{procs}p-", dir=args.tmp))
    out = tmp / "runs" / "scaling"
    run_args = ["run", str(args.spec), "--out", str(out), *[a for o in overrides for a in ("--set", o)]]
    if procs == 1:
        cmd = [sys.executable, "-m", "mocap", *run_args]
    else:
        cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", str(procs), "--master_port", str(_free_port())]
        cmd += ["-m", "mocap", *run_args]
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    env.setdefault("MUJOCO_GL", "egl")
    print(f"{procs} process(es): {' '.join(cmd)}", flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"error: the {procs}-process run failed (exit {proc.returncode}):\n{(proc.stdout + proc.stderr)[-3000:]}")
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines() if line.strip()]
    rows = [r for r in rows if r.get("stage") == "imitator"]
    measured = rows[1:] if len(rows) > 1 else rows  # the first iteration warms up
    samples = n * h * procs * len(measured)
    seconds = sum(r["time/rollout_s"] + r["time/update_s"] for r in measured)
    result = {
        "processes": procs,
        "iterations": len(rows),
        "iterations_measured": len(measured),
        "samples_per_iteration": n * h * procs,
        "env_steps": rows[-1]["env_steps"] if rows else 0.0,
        "env_steps_per_s": samples / seconds if seconds > 0 else float("nan"),
        "rollout_s_per_iteration": sum(r["time/rollout_s"] for r in measured) / len(measured),
        "update_s_per_iteration": sum(r["time/update_s"] for r in measured) / len(measured),
        "steps_per_s_run": rows[-1].get("steps_per_s_run") if rows else None,
        "sim_threads_per_process": sim_threads,
        "wall_s": wall,
    }
    if args.keep:
        result["run_dir"] = str(out)
    else:
        shutil.rmtree(tmp, ignore_errors=True)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spec", type=Path, default=Path("specs/imitator/amp_bundled.yaml"))
    parser.add_argument("--procs", type=int, nargs="+", default=[1, 2], help="process counts to run (1 is the baseline)")
    parser.add_argument("--iterations", type=int, default=6, help="PPO iterations per setting")
    parser.add_argument("--num-envs", type=int, default=128, help="envs per process")
    parser.add_argument("--horizon", type=int, default=64)
    parser.add_argument("--minibatch-size", type=int, default=2048, help="per process (capped at num_envs x horizon)")
    parser.add_argument("--torch-threads", type=int, default=1, help="torch threads per process")
    parser.add_argument("--sim-threads", type=int, default=None, help="MuJoCo threads per process (default: cores / processes)")
    parser.add_argument("--tmp", type=Path, default=Path("/tmp"), help="where the fresh run directories go")
    parser.add_argument("--keep", action="store_true", help="keep the run directories (default: deleted after reading)")
    parser.add_argument("--out", type=Path, default=Path("bench/results/scaling.json"))
    args = parser.parse_args(argv)
    if not args.spec.is_file():
        parser.error(f"--spec {args.spec}: no such file")
    if args.iterations < 1 or any(k < 1 for k in args.procs):
        parser.error("--iterations and --procs must be >= 1")
    procs = sorted(set(args.procs) | {1})

    from mocap.checkpoint import hardware, package_versions

    settings = {str(k): run_setting(args, k) for k in procs}
    base = settings["1"]
    for k, r in settings.items():
        r["throughput_ratio"] = r["env_steps_per_s"] / base["env_steps_per_s"]
        r["update_time_ratio"] = r["update_s_per_iteration"] / base["update_s_per_iteration"]
        r["efficiency"] = r["throughput_ratio"] / int(k)
    result = {
        "spec": str(args.spec),
        "mode": "weak scaling: every process steps num_envs envs; env_steps_per_s counts all processes",
        "num_envs_per_process": args.num_envs,
        "horizon": args.horizon,
        "torch_threads_per_process": args.torch_threads,
        "settings": settings,
        "load_avg_1m": os.getloadavg()[0],
        "hardware": hardware(),
        "versions": package_versions(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    for k, r in settings.items():
        print(
            f"{k} process(es): {r['env_steps_per_s']:,.0f} env steps/s, rollout {r['rollout_s_per_iteration']:.2f} s/it, "
            f"update {r['update_s_per_iteration']:.2f} s/it, x{r['throughput_ratio']:.2f} vs 1 process"
        )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
