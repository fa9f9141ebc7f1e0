"""Control steps per second of the ``mujoco`` simulator vs the raw physics limit of the same model.

For each humanoid (``amp``, ``smpl``) and N in {1, 16, 64, 256}:

* **sim**: ``MujocoSimulator.step`` in a Python loop, PD targets = a reference pose per env, with
  the full ``SimState`` extraction every step (what an RL env pays);
* **raw**: one ``mujoco.rollout`` call (``nthread`` = the simulator's threads, all cores by
  default) over the same N initial states and the same PD targets for the same number of control
  steps x substeps, no Python per step. Measured for the simulator's own model (``raw``, its
  contact/actuator sensors included) and for the bare model of
  :func:`~mocap_sim_mujoco.mjcf.build_mjcf` without sensors (``bare``);
* **ratio** = sim / bare (the stricter one) and sim / raw, from wall-clock rates; **cpu ratio** =
  the same from process CPU time (all threads; MuJoCo's pool does not spin), which a shared,
  loaded machine distorts much less than wall-clock (it still counts the Python overhead);
* optionally (``--threadpool``) the alternative design: one ``MjData`` per env stepped by a
  ``ThreadPoolExecutor`` over chunks (``mj_step(m, d, substeps)`` per env on the simulator's model,
  GIL released inside), with ``mj_kinematics``/``mj_comPos``/``mj_comVel`` and the per-env copies
  of qpos, qvel, xpos, xquat, cvel and the contact sensors that a state extraction needs (but not
  the batched tensor conversion the simulator also pays);
* optionally (``--warp``) the ``mujoco_warp`` simulator (MuJoCo Warp, same model) on ``--warp-device``
  (default: cuda if available, else Warp's CPU device): ``MujocoWarpSimulator.step`` in the same
  loop with the same states and targets (**warp**, and **warp/sim** against ``mujoco``), the
  device recorded in the JSON. Warp compiles its kernels on first use (minutes on a CPU, cached
  in ~/.cache/warp); that warm-up is not timed. ``--warp-only`` skips the ``mujoco`` numbers
  (for GPU sizes such as 4096 envs, where they would take long).

Initial states: ``amp``: reference frames of the 15 DeepMimic clips at random times, PD targets =
each env's reference pose at its frame, held. ``smpl`` (no motion data ships): the rest pose
with DoFs drawn uniformly within +-0.3 of the rest angle (clamped to the joint ranges), PD targets
= that pose. Both fall or stand as physics decides; sim and raw simulate the same trajectories.

Each number is the best of ``--repeats`` short runs (default 7 of 3000 env steps), sim, raw and
bare interleaved: on a shared machine other processes slow some runs down by up to 2x, and the
best run of each is the least disturbed one. Numbers from runs made at different times are not
comparable; ratios within one run are. Results go to
``bench/results/sim_throughput.json``.

Usage: ``python bench/sim_throughput.py [--quick] [--threadpool] [--warp [--warp-device cpu] [--warp-only]]
[--humanoids amp smpl] [--sizes 1 16 64 256]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import mujoco
import numpy as np
import torch
from mujoco import rollout as mj_rollout

from mocap.skeleton import Skeleton
from mocap_sim_mujoco.mjcf import build_mjcf
from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator

RESULTS = Path(__file__).parent / "results" / "sim_throughput.json"


def initial_states(name: str, skeleton: Skeleton, n: int, seed: int = 0):  # type: ignore[no-untyped-def]
    """(HumanoidState rows, PD targets (n, D)) for the benchmark."""
    gen = torch.Generator().manual_seed(seed)
    if name == "amp":
        from mocap.motion.library import MotionLibrary
        from mocap.plugins import get_plugins

        motions = get_plugins().get("motion_source", "deepmimic").build({}).load(skeleton)
        lib = MotionLibrary(motions, skeleton)
        ids, times = lib.sample(n, generator=gen)
        ref = lib.frames(ids, times)
        return ref, ref.dof_pos.clone()
    # a perturbed rest pose: simulator state after reset from it
    lo = torch.tensor([h.range[0] for h in skeleton.hinges])
    hi = torch.tensor([h.range[1] for h in skeleton.hinges])
    dof = ((torch.rand(n, skeleton.num_dofs, generator=gen) * 2 - 1) * 0.3).clamp(lo, hi)
    sim = MujocoSimulator(MujocoParams(threads=1), skeleton=skeleton, num_envs=n)
    st = sim.state
    st.dof_pos = dof
    st.dof_vel = torch.zeros_like(dof)
    sim.close()
    return st, dof


def bench_sim(sim: MujocoSimulator, ref, targets: torch.Tensor, steps: int) -> float:  # type: ignore[no-untyped-def]
    sim.reset(torch.arange(sim.num_envs), ref)
    sim.step(targets)  # warm-up
    sim.reset(torch.arange(sim.num_envs), ref)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        state = sim.step(targets)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    assert state.body_pos.shape[0] == sim.num_envs
    return sim.num_envs * steps / dt, sim.num_envs * steps / dc


def bench_raw(model: mujoco.MjModel, s0: np.ndarray, ctrl: np.ndarray, substeps: int, steps: int, nthread: int) -> float:
    n = s0.shape[0]
    datas = [mujoco.MjData(model) for _ in range(max(1, nthread))]
    ctrl3 = np.repeat(ctrl[:, None, :], substeps * steps, axis=1)
    with mj_rollout.Rollout(nthread=nthread if nthread > 1 else 0) as pool:
        pool.rollout(model, datas, s0, ctrl3[:, :substeps], nstep=substeps)  # warm-up
        t0, c0 = time.perf_counter(), time.process_time()
        pool.rollout(model, datas, s0, ctrl3, nstep=substeps * steps)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
    return n * steps / dt, n * steps / dc


def bench_threadpool(model: mujoco.MjModel, s0: np.ndarray, ctrl: np.ndarray, substeps: int, steps: int, nthread: int) -> float:
    """The alternative design: per-env MjData, a ThreadPoolExecutor over chunks, per-env copies."""
    n = s0.shape[0]
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    datas = [mujoco.MjData(model) for _ in range(n)]
    for d, s in zip(datas, s0):
        mujoco.mj_setState(model, d, s, full)
        mujoco.mj_forward(model, d)
    nb = model.nbody
    qpos, qvel = np.zeros((n, model.nq)), np.zeros((n, model.nv))
    xpos, xquat, cvel = np.zeros((n, nb, 3)), np.zeros((n, nb, 4)), np.zeros((n, nb, 6))
    sens = np.zeros((n, model.nsensordata))
    chunks = [c for c in np.array_split(np.arange(n), nthread) if len(c)]

    def work(ids: np.ndarray) -> None:
        for i in ids:
            d = datas[i]
            d.ctrl[:] = ctrl[i]
            mujoco.mj_step(model, d, substeps)
            mujoco.mj_kinematics(model, d)
            mujoco.mj_comPos(model, d)
            mujoco.mj_comVel(model, d)
            qpos[i], qvel[i], xpos[i], xquat[i], cvel[i], sens[i] = d.qpos, d.qvel, d.xpos, d.xquat, d.cvel, d.sensordata

    with ThreadPoolExecutor(nthread) as ex:
        list(ex.map(work, chunks))  # warm-up
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(steps):
            list(ex.map(work, chunks))
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
    return n * steps / dt, n * steps / dc


def bench_warp(sim, ref, targets: torch.Tensor, steps: int) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Env steps/s (wall, cpu) of ``MujocoWarpSimulator.step``; the warm-up step (kernel compilation,
    CUDA graph capture) is not timed, and CUDA work is synchronized before the clock stops."""

    def sync() -> None:
        if sim.sim_device.type == "cuda":
            torch.cuda.synchronize(sim.sim_device)

    sim.reset(torch.arange(sim.num_envs), ref)
    sim.step(targets)  # warm-up
    sim.reset(torch.arange(sim.num_envs), ref)
    sync()
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        state = sim.step(targets)
    sync()
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    assert state.body_pos.shape[0] == sim.num_envs
    return sim.num_envs * steps / dt, sim.num_envs * steps / dc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps and repeats (a smoke run)")
    ap.add_argument("--humanoids", nargs="+", default=["amp", "smpl"])
    ap.add_argument("--sizes", nargs="+", type=int, default=[1, 16, 64, 256])
    ap.add_argument("--threads", type=int, default=None, help="simulator/rollout threads (default: all cores)")
    ap.add_argument("--repeats", type=int, default=None, help="best of this many runs (default 7, --quick 1)")
    ap.add_argument("--env-steps", type=int, default=None, help="env steps per run (N x control steps; default 3000, --quick 1000)")
    ap.add_argument("--threadpool", action="store_true", help="also measure the ThreadPoolExecutor design")
    ap.add_argument("--warp", action="store_true", help="also measure the mujoco_warp simulator (needs pip install 'mocap[warp]')")
    ap.add_argument("--warp-device", default=None, help="Warp device for --warp (default: cuda if available, else cpu)")
    ap.add_argument("--warp-only", action="store_true", help="with --warp: skip the mujoco measurements")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    if args.warp_only and not args.warp:
        ap.error("--warp-only needs --warp")
    torch.set_num_threads(1)
    repeats = args.repeats or (1 if args.quick else 7)
    env_steps = args.env_steps or (1000 if args.quick else 3000)
    threads = args.threads or os.cpu_count() or 1

    from mocap.plugins import get_plugins

    rows = []
    header = f"{'humanoid':8s} {'N':>4s} {'sim steps/s':>12s} {'raw':>10s} {'bare':>10s} {'sim/bare':>9s} {'sim/raw':>8s} {'cpu ratio':>9s}"
    if args.threadpool:
        header += f" {'threadpool':>11s} {'tp cpu':>8s}"
    warp_info = None
    if args.warp:
        from mocap_sim_mujoco_warp.simulator import (
            MujocoWarpParams,
            MujocoWarpSimulator,
            import_warp,
        )

        wp, mjw = import_warp()
        header += f" {'warp':>10s} {'warp/sim':>8s}"
    print(header, flush=True)
    for name in args.humanoids:
        skeleton = get_plugins().get("humanoid", name).build()
        bare = mujoco.MjModel.from_xml_string(build_mjcf(skeleton))
        bare.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        for n in args.sizes:
            steps = max(20, env_steps // n)
            sim = MujocoSimulator(MujocoParams(threads=threads), skeleton=skeleton, num_envs=n)
            ref, targets = initial_states(name, skeleton, n)
            sim.reset(torch.arange(n), ref)
            s0 = sim.get_physics_state()
            ctrl = np.zeros((n, sim.model.nu))
            ctrl[:, sim.index.actuator_ids] = targets.double().numpy()
            best = {k: np.zeros(2) for k in ("sim", "raw", "bare", "threadpool", "warp")}  # (wall, cpu) rates
            wsim = None
            if args.warp:
                wsim = MujocoWarpSimulator(MujocoWarpParams(device=args.warp_device), skeleton=skeleton, num_envs=n)
                warp_info = {"device": str(wsim.wp_device), "device_name": wsim.wp_device.name, "mujoco_warp": mjw.__version__, "warp": wp.__version__}
            for _ in range(repeats):
                if wsim is not None:
                    best["warp"] = np.maximum(best["warp"], bench_warp(wsim, ref, targets, steps))
                if args.warp_only:
                    continue
                best["sim"] = np.maximum(best["sim"], bench_sim(sim, ref, targets, steps))
                best["raw"] = np.maximum(best["raw"], bench_raw(sim.model, s0, ctrl, sim.params.substeps, steps, threads))
                best["bare"] = np.maximum(best["bare"], bench_raw(bare, s0, ctrl, sim.params.substeps, steps, threads))
                if args.threadpool:
                    tp = bench_threadpool(sim.model, s0, ctrl, sim.params.substeps, steps, threads)
                    best["threadpool"] = np.maximum(best["threadpool"], tp)
            sim.close()
            if wsim is not None:
                wsim.close()
            cpu = {k: float(v[1]) for k, v in best.items()}
            best = {k: float(v[0]) for k, v in best.items()}
            if args.warp_only:
                row = {"humanoid": name, "num_envs": n, "control_steps": steps, "warp_steps_per_s": round(best["warp"], 1)}
                rows.append(row)
                print(f"{name:8s} {n:4d} {'-':>12s} {'-':>10s} {'-':>10s} {'-':>9s} {'-':>8s} {'-':>9s} {best['warp']:10.0f}", flush=True)
                continue
            row = {
                "humanoid": name,
                "num_envs": n,
                "control_steps": steps,
                "sim_steps_per_s": round(best["sim"], 1),
                "raw_steps_per_s": round(best["raw"], 1),
                "bare_steps_per_s": round(best["bare"], 1),
                "ratio_sim_bare": round(best["sim"] / best["bare"], 3),
                "ratio_sim_raw": round(best["sim"] / best["raw"], 3),
                "cpu_ratio_sim_bare": round(cpu["sim"] / cpu["bare"], 3),
            }
            if args.threadpool:
                row["threadpool_steps_per_s"] = round(best["threadpool"], 1)
                row["cpu_ratio_threadpool_bare"] = round(cpu["threadpool"] / cpu["bare"], 3)
            if args.warp:
                row["warp_steps_per_s"] = round(best["warp"], 1)
                row["ratio_warp_sim"] = round(best["warp"] / best["sim"], 3)
            rows.append(row)
            line = (
                f"{name:8s} {n:4d} {row['sim_steps_per_s']:12.0f} {row['raw_steps_per_s']:10.0f} {row['bare_steps_per_s']:10.0f} "
                f"{row['ratio_sim_bare']:9.2f} {row['ratio_sim_raw']:8.2f} {row['cpu_ratio_sim_bare']:9.2f}"
            )
            if args.threadpool:
                line += f" {row['threadpool_steps_per_s']:11.0f} {row['cpu_ratio_threadpool_bare']:8.2f}"
            if args.warp:
                line += f" {row['warp_steps_per_s']:10.0f} {row['ratio_warp_sim']:8.2f}"
            print(line, flush=True)

    out = {
        "what": "30 Hz control steps per second (env steps/s) of MujocoSimulator.step incl. SimState extraction, "
        "vs one mujoco.rollout over the same states/targets (raw: the simulator's model; bare: no sensors)",
        "timestep": MujocoParams().timestep,
        "substeps": MujocoParams().substeps,
        "threads": threads,
        "repeats_best_of": repeats,
        "quick": args.quick,
        "mujoco": mujoco.__version__,
        "torch": torch.__version__,
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "load_avg_1m": os.getloadavg()[0]},
        "results": rows,
    }
    if warp_info is not None:
        out["warp"] = warp_info  # the mujoco_warp rows' device (warp_steps_per_s)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
