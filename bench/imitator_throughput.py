"""Imitator throughput, in one run: env-only steps/s vs PPO learning steps/s, and the real-time factor.

* ``env_only``: the PHC imitation env (simulator + observations + reward + termination + resets)
  stepped with zero actions, N envs — the ceiling for learning;
* ``learning``: PPO iterations of the spec (rollout with the policy + update), steps/s from the
  trainer's own log, same N;
* ``realtime``: one humanoid driven by an imitator (policy + physics, 1 env, CPU): simulated
  seconds per wall-clock second (> 1 is faster than real time).

    python bench/imitator_throughput.py --spec specs/imitator/amp_bundled.yaml \
        --checkpoint checkpoints/imitator_amp/policy.pt --out bench/results/imitator_throughput.json

Target (issue 4): learning >= 0.5 x env-only.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path


def env_only(resolved, plugins, num_envs: int, steps: int) -> float:
    import torch

    from mocap.motion.library import MotionLibrary
    from mocap_phc.env import ImitationEnv

    spec = resolved.spec
    skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params["humanoid"])
    lib = MotionLibrary(plugins.get("motion_source", spec.motions.name).build(resolved.params["motions"]).load(skeleton), skeleton)
    sim = plugins.get("simulator", spec.simulator.name).build(resolved.params["simulator"], skeleton=skeleton, num_envs=num_envs, seed=0)
    env = ImitationEnv(resolved.params["imitator"], skeleton, lib, sim, seed=0)
    env.reset()
    zeros = torch.zeros(num_envs, *env.action_space.shape)
    for _ in range(5):
        env.step(zeros)
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(zeros)
    rate = steps * num_envs / (time.perf_counter() - t0)
    env.close()
    return rate


def learning(spec_path: Path, plugins, iterations: int, num_envs: int, horizon: int) -> dict:
    from rich.console import Console

    from mocap.pipeline import run_pipeline
    from mocap.spec import load_spec

    overrides = [
        f"imitator.trainer.params.total_env_steps={iterations * num_envs * horizon}",
        f"imitator.trainer.params.num_envs={num_envs}",
        f"imitator.trainer.params.horizon={horizon}",
        f"imitator.trainer.params.minibatch_size={min(num_envs * horizon, 2048)}",
        "imitator.params.eval_every=0",
        "eval=null",
    ]
    resolved = load_spec(spec_path, plugins, overrides)
    with tempfile.TemporaryDirectory() as tmp:
        run_pipeline(resolved, plugins, Path(tmp) / "runs" / "bench", console=Console(file=open(os.devnull, "w")))
        rows = [json.loads(line) for line in (Path(tmp) / "runs" / "bench" / "metrics.jsonl").read_text().splitlines()]
    rows = [r for r in rows if r["stage"] == "imitator"][1:]  # skip the first iteration (warm-up)
    steps = sum(num_envs * horizon for _ in rows)
    seconds = sum(r["time/rollout_s"] + r["time/update_s"] for r in rows)
    return {
        "steps_per_s": steps / seconds,
        "rollout_s_per_iteration": sum(r["time/rollout_s"] for r in rows) / len(rows),
        "update_s_per_iteration": sum(r["time/update_s"] for r in rows) / len(rows),
        "iterations_measured": len(rows),
    }


def realtime(checkpoint: Path, plugins, seconds: float) -> float:
    import torch

    from mocap.evaluation import load_evaluation_target
    from mocap.motion.library import MotionLibrary

    target = load_evaluation_target(checkpoint, plugins)
    resolved, ckpt = target.resolved, target.imitator_checkpoint
    spec = resolved.spec
    skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params.get("humanoid"))
    lib = MotionLibrary(plugins.get("motion_source", spec.motions.name).build(resolved.params.get("motions")).load(skeleton), skeleton)
    imitator = plugins.get("imitator", spec.imitator.name).build(resolved.params.get("imitator"), skeleton=skeleton, checkpoint=ckpt)
    sim = plugins.get("simulator", spec.simulator.name).build(resolved.params.get("simulator"), skeleton=skeleton, num_envs=1, seed=0)
    clip = torch.tensor([lib.clip_index("walk") if "walk" in lib.clip_names else 0])
    sim.reset(torch.arange(1), lib.frames(clip, torch.zeros(1)))
    state = sim.state
    steps = int(seconds / sim.dt)
    t0 = time.perf_counter()
    for k in range(1, steps + 1):
        ref = lib.frames(clip, torch.full((1,), k * sim.dt))
        with torch.no_grad():
            state = sim.step(imitator.act(imitator.observe(state, ref)))
    wall = time.perf_counter() - t0
    sim.close()
    return steps * sim.dt / wall


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spec", type=Path, default=Path("specs/imitator/amp_bundled.yaml"))
    parser.add_argument("--checkpoint", type=Path, default=None, help="imitator for the real-time factor")
    parser.add_argument("--num-envs", type=int, default=128)
    parser.add_argument("--horizon", type=int, default=64)
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument("--out", type=Path, default=Path("bench/results/imitator_throughput.json"))
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")

    import torch

    from mocap.checkpoint import hardware, package_versions
    from mocap.plugins import get_plugins
    from mocap.spec import load_spec

    plugins = get_plugins()
    resolved = load_spec(args.spec, plugins)
    threads = resolved.params["imitator.trainer"].torch_threads
    if threads:
        torch.set_num_threads(threads)
    result: dict = {"spec": str(args.spec), "num_envs": args.num_envs, "horizon": args.horizon, "torch_threads": threads}
    result["env_only_steps_per_s"] = env_only(resolved, plugins, args.num_envs, steps=args.horizon * 2)
    result["learning"] = learning(args.spec, plugins, args.iterations, args.num_envs, args.horizon)
    result["ratio_learning_to_env_only"] = result["learning"]["steps_per_s"] / result["env_only_steps_per_s"]
    if args.checkpoint is not None:
        result["realtime_factor_1_env"] = realtime(args.checkpoint, plugins, seconds=10.0)
    result["load_avg_1m"] = os.getloadavg()[0]
    result["versions"] = package_versions()
    result["hardware"] = hardware()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k not in ("versions", "hardware")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
