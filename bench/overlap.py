"""Does overlapping physics with the policy pay on 2 cores? (EnvPool's async idea inside one process)

The PPO rollout alternates, for all N envs at once: policy forward (torch) -> env step (MuJoCo
``rollout`` of N envs on the simulator's thread pool, which releases the GIL, then observation,
reward and resets in torch). The overlapped variant splits the envs into two halves A and B, each its
own env of N/2, and runs A's env step on a worker thread while the main thread runs B's policy
forward and then B's env step, so that one half's physics can run while the other half's Python
and torch work does. Both variants take the same actions from the same policy; the measure is env
steps per second including the policy (what a rollout costs).

Variants (each timed over ``--steps`` control steps after a warm-up):

* ``sync_full``: one env of N, the simulator's default threads (today's rollout);
* ``sync_halves``: two envs of N/2 stepped one after the other (the cost of splitting alone);
* ``overlap_halves``: the two halves overlapped with a worker thread, each simulator with
  ``--overlap-sim-threads`` threads (default 1: the two halves' physics then use one core each).

    python bench/overlap.py --checkpoint checkpoints/imitator_amp_v3/policy.pt --out bench/results/overlap.json

Run it on an otherwise idle machine (the load average goes in the JSON).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


def _env(resolved, plugins, num_envs: int, threads: int | None):  # type: ignore[no-untyped-def]
    from mocap.motion.library import MotionLibrary
    from mocap_phc.env import ImitationEnv

    spec = resolved.spec
    skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params["humanoid"])
    lib = MotionLibrary(plugins.get("motion_source", spec.motions.name).build(resolved.params["motions"]).load(skeleton), skeleton)
    sim_params = resolved.params["simulator"]
    if threads is not None:
        sim_params = sim_params.model_copy(update={"threads": threads})
    sim = plugins.get("simulator", spec.simulator.name).build(sim_params, skeleton=skeleton, num_envs=num_envs, seed=0)
    return ImitationEnv(resolved.params["imitator"], skeleton, lib, sim, seed=0)


def run(resolved, plugins, policy, num_envs: int, steps: int, mode: str, sim_threads: int | None) -> float:  # type: ignore[no-untyped-def]
    import torch

    def act(obs):  # type: ignore[no-untyped-def]
        with torch.no_grad():
            return policy.act(obs)[0]

    if mode == "sync_full":
        envs = [_env(resolved, plugins, num_envs, None)]
    else:
        envs = [_env(resolved, plugins, num_envs // 2, sim_threads if mode == "overlap_halves" else None) for _ in range(2)]
    obs = [e.reset() for e in envs]
    pool = ThreadPoolExecutor(max_workers=1)
    t0 = 0.0
    for k in range(10 + steps):
        if k == 10:
            t0 = time.perf_counter()
        if mode == "overlap_halves":
            a = act(obs[0])
            fut = pool.submit(envs[0].step, a)  # A's physics (GIL released) while B's policy runs
            b = act(obs[1])
            res_b = envs[1].step(b)
            res_a = fut.result()
            obs = [res_a.obs, res_b.obs]
        else:
            obs = [e.step(act(o)).obs for e, o in zip(envs, obs)]
    wall = time.perf_counter() - t0
    pool.shutdown()
    for e in envs:
        e.close()
    return steps * num_envs / wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", type=Path, default=Path("specs/imitator/amp_bundled.yaml"))
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--num-envs", type=int, default=128)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--overlap-sim-threads", type=int, default=1)
    ap.add_argument("--torch-threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("bench/results/overlap.json"))
    args = ap.parse_args(argv)
    import torch

    from mocap.plugins import get_plugins
    from mocap.rl.networks import load_policy
    from mocap.spec import load_spec

    torch.set_num_threads(args.torch_threads)
    plugins = get_plugins()
    resolved = load_spec(args.spec, plugins)
    policy = load_policy(args.checkpoint)
    load_before = os.getloadavg()
    modes = ("sync_full", "sync_halves", "overlap_halves")
    samples: dict[str, list[float]] = {m: [] for m in modes}
    for _ in range(args.repeats):  # interleaved, so that drift hits every variant alike
        for m in modes:
            samples[m].append(run(resolved, plugins, policy, args.num_envs, args.steps, m, args.overlap_sim_threads))
            print(f"{m}: {samples[m][-1]:,.0f} steps/s", flush=True)
    med = {m: sorted(v)[len(v) // 2] for m, v in samples.items()}
    result = {
        "num_envs": args.num_envs,
        "steps": args.steps,
        "torch_threads": args.torch_threads,
        "overlap_sim_threads": args.overlap_sim_threads,
        "steps_per_s": samples,
        "median_steps_per_s": med,
        "overlap_over_sync_full": med["overlap_halves"] / med["sync_full"],
        "load_avg_before": list(load_before),
        "load_avg_after": list(os.getloadavg()),
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(med), f"overlap / sync = {result['overlap_over_sync_full']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
