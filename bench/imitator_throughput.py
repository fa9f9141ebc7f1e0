"""The learning loop against the physics limit, all measured in ONE run on one machine.

* ``raw_physics_steps_per_s``: one long ``mujoco.rollout`` of the bare humanoid model (no sensors,
  no Python per step), the same N, the simulator's thread count and physics options, from the
  env's own kind of start states (RSI reference frames of the bundled clips, PD targets = the
  reference pose, held) — the ceiling;
* ``sim_steps_per_s``: ``MujocoSimulator.step`` from the same states and targets (state
  extraction included);
* ``env_only``: the PHC imitation env (simulator + observations + reward + termination + resets),
  N envs, with zero actions (residual actions: PD target = the reference pose; envs fall often, so
  resets are frequent) and, with ``--checkpoint``, with the trained policy's deterministic actions
  (the policy's forward pass is not timed: actions precomputed per step would differ, so it is
  run but its time subtracted);
* ``learning``: PPO iterations of the spec (rollout with the policy + update), from the trainer's
  own log, same N, with the rollout and update time split;
* ``task_rollout`` / ``distill_rollout`` (``--task-spec``, ``--distill-spec``): the rollout
  steps/s that the speed task through PULSE and PULSE's distillation log (their envs + policy);
* ``realtime_factor_1_env`` (``--checkpoint``): one humanoid driven by the imitator, simulated
  seconds per wall-clock second.

Every ``*_per_s`` gets a ratio to ``raw_physics_steps_per_s``; ``load_avg_1m`` records how idle the
machine was (do not run it next to a training run).

    python bench/imitator_throughput.py --checkpoint checkpoints/imitator_amp_v3/policy.pt

Targets (issue 21): env-only / raw >= 0.8; task and distillation env / raw >= 0.6; learning / raw >= 0.4.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path


def _imitation_env(resolved, plugins, num_envs: int):  # type: ignore[no-untyped-def]
    from mocap.motion.library import MotionLibrary
    from mocap_phc.env import ImitationEnv

    spec = resolved.spec
    skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params["humanoid"])
    lib = MotionLibrary(plugins.get("motion_source", spec.motions.name).build(resolved.params["motions"]).load(skeleton), skeleton)
    sim = plugins.get("simulator", spec.simulator.name).build(resolved.params["simulator"], skeleton=skeleton, num_envs=num_envs, seed=0)
    return ImitationEnv(resolved.params["imitator"], skeleton, lib, sim, seed=0), skeleton, lib, sim


def env_only(resolved, plugins, num_envs: int, steps: int, policy=None) -> dict:  # type: ignore[no-untyped-def]
    """Env steps/s with zero actions, or with ``policy`` (flat obs -> action; its time not counted)."""
    import torch

    env, *_ = _imitation_env(resolved, plugins, num_envs)
    obs = env.reset()
    zeros = torch.zeros(num_envs, *env.action_space.shape)
    resets = 0
    spent = 0.0
    for k in range(5 + steps):
        if k == 5:
            t0, spent, resets = time.perf_counter(), 0.0, 0
        if policy is None:
            action = zeros
        else:
            tp = time.perf_counter()
            with torch.no_grad():
                action = policy(obs)
            spent += time.perf_counter() - tp
        res = env.step(action)
        obs = res.obs
        resets += int((res.terminated | res.truncated).sum())
    wall = time.perf_counter() - t0 - spent
    env.close()
    return {"steps_per_s": steps * num_envs / wall, "resets_per_step": resets / steps}


def physics(resolved, plugins, num_envs: int, steps: int) -> dict:  # type: ignore[no-untyped-def]
    """Raw bare-model rollout and the simulator's step from the same RSI states and held targets."""
    import mujoco
    import numpy as np
    import torch
    from mujoco import rollout as mj_rollout

    from mocap_sim_mujoco.mjcf import build_mjcf

    env, skeleton, lib, sim = _imitation_env(resolved, plugins, num_envs)
    env.reset()
    ids = torch.arange(num_envs)
    ref = lib.frames(env.clip_ids, env.start_time)
    targets = ref.dof_pos.clone()
    p = sim.params
    sim.reset(ids, ref)
    s0 = sim.get_physics_state()
    sim.step(targets)  # warm-up
    sim.reset(ids, ref)
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step(targets)
    sim_rate = num_envs * steps / (time.perf_counter() - t0)
    bare = mujoco.MjModel.from_xml_string(
        build_mjcf(skeleton, timestep=p.timestep, iterations=p.iterations, ls_iterations=p.ls_iterations, joint_limits=p.joint_limits)
    )
    if bare.nu != targets.shape[1] or not sim.index.identity_order:
        raise RuntimeError("bare model actuators are not in skeleton DoF order")
    # the bare model's state layout is the simulator's (no props): time, qpos, qvel, ...
    n_bare = mujoco.mj_stateSize(bare, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    s_bare = np.ascontiguousarray(s0[:, :n_bare])
    ctrl = np.repeat(targets.double().numpy()[:, None, :], p.substeps * steps, axis=1)
    nthread = sim.threads
    datas = [mujoco.MjData(bare) for _ in range(max(1, nthread))]
    with mj_rollout.Rollout(nthread=nthread if nthread > 1 else 0) as pool:
        pool.rollout(bare, datas, s_bare, ctrl[:, : p.substeps], nstep=p.substeps)  # warm-up
        t0 = time.perf_counter()
        pool.rollout(bare, datas, s_bare, ctrl, nstep=p.substeps * steps)
        raw_rate = num_envs * steps / (time.perf_counter() - t0)
    env.close()
    return {"raw_physics_steps_per_s": raw_rate, "sim_steps_per_s": sim_rate, "rollout_threads": nthread}


def learning(spec_path: Path, plugins, iterations: int, num_envs: int, horizon: int, stage: str = "imitator", extra: list[str] | None = None) -> dict:  # type: ignore[no-untyped-def]
    """PPO/distillation iterations of one stage of a spec; rates from the trainer's own log."""
    from rich.console import Console

    from mocap.pipeline import run_pipeline
    from mocap.spec import load_spec

    t = f"{stage}.trainer.params"
    overrides = [
        f"{t}.total_env_steps={iterations * num_envs * horizon}",
        f"{t}.num_envs={num_envs}",
        f"{t}.horizon={horizon}",
        "eval=null",
        *(extra or []),
    ]
    resolved = load_spec(spec_path, plugins, overrides)
    with tempfile.TemporaryDirectory() as tmp:
        run_pipeline(resolved, plugins, Path(tmp) / "runs" / "bench", console=Console(file=open(os.devnull, "w")))
        rows = [json.loads(line) for line in (Path(tmp) / "runs" / "bench" / "metrics.jsonl").read_text().splitlines()]
    rows = [r for r in rows if r["stage"] == stage and "time/rollout_s" in r][1:]  # skip the first iteration (warm-up)
    if not rows:
        raise RuntimeError(f"no {stage} iterations logged")
    steps = num_envs * horizon * len(rows)
    rollout = sum(r["time/rollout_s"] for r in rows)
    update = sum(r["time/update_s"] for r in rows)
    return {
        "steps_per_s": steps / (rollout + update),
        "rollout_steps_per_s": steps / rollout,
        "rollout_s_per_iteration": rollout / len(rows),
        "update_s_per_iteration": update / len(rows),
        "iterations_measured": len(rows),
    }


def _policy_fn(checkpoint: Path, plugins):  # type: ignore[no-untyped-def]
    """flat observation -> the imitator's deterministic raw action (what the env's step takes)."""
    from mocap.eval_targets import load_evaluation_target

    target = load_evaluation_target(checkpoint, plugins)
    resolved = target.resolved
    skeleton = plugins.get("humanoid", resolved.spec.humanoid.name).build(resolved.params.get("humanoid"))
    imitator = plugins.get("imitator", resolved.spec.imitator.name).build(
        resolved.params.get("imitator"), skeleton=skeleton, checkpoint=target.imitator_checkpoint
    )
    return lambda obs: imitator.policy_action(obs, deterministic=True)


def realtime(checkpoint: Path, plugins, seconds: float) -> float:
    import torch

    from mocap.eval_targets import load_evaluation_target
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
    parser.add_argument("--checkpoint", type=Path, default=None, help="imitator: env-only with its actions, real-time factor")
    parser.add_argument("--task-spec", type=Path, default=None, help="e.g. specs/tasks/speed_pulse.yaml (task rollout rate)")
    parser.add_argument("--distill-spec", type=Path, default=None, help="e.g. specs/latent/pulse_amp.yaml (distillation rollout rate)")
    parser.add_argument("--num-envs", type=int, default=128)
    parser.add_argument("--horizon", type=int, default=64)
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument("--env-steps", type=int, default=200, help="control steps per env-only / physics measurement")
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
    result["load_avg_1m_before"] = os.getloadavg()[0]
    result.update(physics(resolved, plugins, args.num_envs, args.env_steps))
    raw = result["raw_physics_steps_per_s"]
    result["env_only_steps_per_s"] = env_only(resolved, plugins, args.num_envs, args.env_steps)["steps_per_s"]
    if args.checkpoint is not None:
        policy = _policy_fn(args.checkpoint, plugins)
        result["env_only_policy"] = env_only(resolved, plugins, args.num_envs, args.env_steps, policy)
    result["learning"] = learning(args.spec, plugins, args.iterations, args.num_envs, args.horizon, "imitator", ["imitator.params.eval_every=0"])
    if args.task_spec is not None:
        result["task_rollout"] = learning(args.task_spec, plugins, args.iterations, args.num_envs, args.horizon, "task")
    if args.distill_spec is not None:
        result["distill_rollout"] = learning(args.distill_spec, plugins, args.iterations, args.num_envs, args.horizon, "latent")
    ratios = {
        "sim": result["sim_steps_per_s"] / raw,
        "env_only": result["env_only_steps_per_s"] / raw,
        "learning": result["learning"]["steps_per_s"] / raw,
        "learning_rollout": result["learning"]["rollout_steps_per_s"] / raw,
    }
    if "env_only_policy" in result:
        ratios["env_only_policy"] = result["env_only_policy"]["steps_per_s"] / raw
    for key in ("task_rollout", "distill_rollout"):
        if key in result:
            ratios[key] = result[key]["rollout_steps_per_s"] / raw
    result["ratio_to_raw_physics"] = ratios
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
