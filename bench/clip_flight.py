"""Is a reference clip's flight physically possible? COM fall and angular momentum in each flight phase.

With no contact the only external force on the body is gravity, so during a flight phase the
whole-body centre of mass (COM) follows a parabola with vertical acceleration exactly g = -9.81
m/s^2, and the angular momentum about the COM is conserved (no external torque about it; Newton-Euler,
e.g. Featherstone, *Rigid Body Dynamics Algorithms*, 2008, ch. 2, or any mechanics text). A clip
that breaks either cannot be tracked by a simulated humanoid without external help.

For each clip, on the humanoid and motion library built from a checkpoint's embedded spec
(float64), every frame's ``qpos`` goes into the simulator's MJCF (``mocap_sim_mujoco.mjcf``, floor
at z = 0). A frame is in flight when every body geom is more than ``--threshold`` above the floor
(``mj_geomDistance``). Per flight phase (frames a..b): a least-squares parabola through the COM
height (its a_z and rms), the takeoff COM v_z (over the first flight step), the ballistic flight
time that v_z allows back to the landing height, the frame rate at which the fitted parabola
would be free fall (``fps * sqrt(g / a_z)``), and the vertical angular momentum about the COM
(``subtree_angmom`` at the midpoint of each flight step, qvel = the step's difference) with its
range relative to its largest magnitude in the phase.

    python bench/clip_flight.py --checkpoint checkpoints/imitator/policy.pt \\
        --clips spin,jump,backflip --threshold 0.03 --out bench/results/clip_flight

Writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

G = -9.81


# ------------------------------------------------------------------------------------ pure math
def flight_segments(mask: Any) -> list[tuple[int, int]]:
    """``[(first, last)]`` of every maximal run of True in a 1-D boolean mask (inclusive)."""
    m = np.asarray(mask, dtype=bool)
    edges = np.diff(np.concatenate(([0], m.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(int(a), int(b)) for a, b in zip(starts, ends)]


def fit_parabola(t: Any, z: Any) -> tuple[float, float, float]:
    """Least-squares ``z = z0 + v0 (t - t[0]) + a_z (t - t[0])^2 / 2``: ``(a_z, v0, rms residual)``."""
    t, z = np.asarray(t, dtype=float), np.asarray(z, dtype=float)
    if len(t) < 3:
        raise ValueError("a parabola needs at least 3 samples")
    tt = t - t[0]
    coef = np.polyfit(tt, z, 2)
    rms = float(np.sqrt(np.mean((np.polyval(coef, tt) - z) ** 2)))
    return float(2 * coef[0]), float(coef[1]), rms


def ballistic_flight_time(vz: float, dz: float, g: float = G) -> float | None:
    """Time a free-falling point leaving with vertical speed ``vz`` takes to come back down to ``dz``
    above its start (the later root of ``dz = vz T + g T^2 / 2``); None when it never gets there."""
    disc = vz * vz + 2 * g * dz
    if disc < 0:
        return None
    T = (vz + math.sqrt(disc)) / -g
    return T if T >= 0 else None


def free_fall_fps(fps: float, a_z: float, g: float = G) -> float | None:
    """The frame rate at which a parabola with acceleration ``a_z`` (per recorded second, recorded at
    ``fps``) would be free fall: replaying at ``f`` scales time by ``fps / f`` and the acceleration by
    ``(f / fps)^2``. None when ``a_z`` and ``g`` differ in sign (or ``a_z`` is 0)."""
    if a_z * g <= 0:
        return None
    return fps * math.sqrt(g / a_z)


# ------------------------------------------------------------------------------------ the clips
def build(checkpoint: Path, clips: list[str]) -> tuple[Any, Any, Any, Any]:
    """``(skeleton, motion library, MuJoCo model, model index)`` from the checkpoint's embedded spec,
    built through the plugins as ``mocap eval`` builds them (:mod:`mocap.eval_targets`). Raises
    ``LookupError`` for an unknown clip name, ``UserError`` / ``CheckpointError`` for a bad checkpoint."""
    import torch

    from mocap.eval_targets import load_evaluation_target
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins
    from mocap_sim_mujoco.mjcf import build_model, model_index

    plugins = get_plugins()
    resolved = load_evaluation_target(checkpoint, plugins).resolved
    spec = resolved.spec
    skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params.get("humanoid"))
    mset = plugins.get("motion_source", spec.motions.name).build(resolved.params.get("motions")).load(skeleton)
    unknown = [c for c in clips if c not in mset.names]
    if unknown:
        raise LookupError(f"unknown clip(s) {', '.join(unknown)}; available: {', '.join(mset.names)}")
    chosen = replace(mset, clips=[mset.clips[mset.names.index(c)] for c in clips])  # keeps the velocity choice
    lib = MotionLibrary(chosen, skeleton, dtype=torch.float64)
    model = build_model(skeleton)
    return skeleton, lib, model, model_index(model, skeleton)


def analyse(lib: Any, model: Any, idx: Any, clip: str, threshold: float) -> dict[str, Any]:
    """Flight phases of one clip (module docstring)."""
    import mujoco

    c = lib.clip_index(clip)
    n, fps, s = int(lib.num_frames[c]), float(lib.fps[c]), lib.frame_index(c, 0)
    qpos = np.zeros((n, model.nq))
    qpos[:, idx.root_qpos : idx.root_qpos + 3] = lib.root_pos[s : s + n].double().numpy()
    qpos[:, idx.root_qpos + 3 : idx.root_qpos + 7] = lib.root_rot[s : s + n].double().numpy()
    qpos[:, idx.dof_qpos] = lib.dof_pos[s : s + n].double().numpy()
    d = mujoco.MjData(model)
    body_geoms = [g for g in range(model.ngeom) if idx.geom_body[g] >= 0]
    fromto = np.zeros(6)
    com, clearance = np.zeros((n, 3)), np.zeros(n)
    for i in range(n):
        d.qpos[:] = qpos[i]
        mujoco.mj_forward(model, d)
        com[i] = d.subtree_com[0]
        clearance[i] = min(mujoco.mj_geomDistance(model, d, g, idx.floor_geom, 1.0, fromto) for g in body_geoms)
    # angular momentum about the COM at t_{i+1/2}: qpos halfway along step i, qvel = the step's difference
    Lz = np.zeros(n - 1)
    v = np.zeros(model.nv)
    for i in range(n - 1):
        mujoco.mj_differentiatePos(model, v, 1.0 / fps, qpos[i], qpos[i + 1])
        qm = qpos[i].copy()
        mujoco.mj_integratePos(model, qm, v, 0.5 / fps)
        d.qpos[:], d.qvel[:] = qm, v
        mujoco.mj_forward(model, d)
        mujoco.mj_subtreeVel(model, d)
        Lz[i] = d.subtree_angmom[0][2]
    t = np.arange(n) / fps
    phases = []
    for a, b in flight_segments(clearance > threshold):
        ph: dict[str, Any] = {"first_frame": a, "last_frame": b, "t_start": a / fps, "t_end": b / fps, "duration_s": (b - a) / fps}
        ph["max_clearance_m"] = float(clearance[a : b + 1].max())
        az = v0 = rms = None
        if b - a >= 3:
            az, v0, rms = fit_parabola(t[a : b + 1], com[a : b + 1, 2])
        vz = float((com[min(a + 1, b), 2] - com[a, 2]) * fps)
        ph.update(com_az_fit=az, com_vz0_fit=v0, com_fit_rms_m=rms, com_vz_takeoff=vz)
        ph["ballistic_flight_s"] = ballistic_flight_time(vz, float(com[b, 2] - com[a, 2]))
        ph["free_fall_fps"] = free_fall_fps(fps, az) if az is not None else None
        if b > a:
            lz = Lz[a:b]
            ph.update(Lz_min=float(lz.min()), Lz_max=float(lz.max()))
            ph["Lz_range_rel"] = float((lz.max() - lz.min()) / max(np.abs(lz).max(), 1e-9))
        phases.append(ph)
    return {"clip": clip, "fps": fps, "frames": n, "mass_kg": float(model.body_subtreemass[0]), "phases": phases}


# ------------------------------------------------------------------------------------ output
def _f(v: float | None, spec: str = ".2f") -> str:
    return "-" if v is None else format(v, spec)


def render(result: dict[str, Any]) -> str:
    """The markdown report: one table row per flight phase."""
    hdr = (
        "| clip | fps | flight s | duration s | COM a_z m/s² (rms mm) | takeoff v_z m/s | ballistic flight s | free-fall fps "
        "| L_z min / max kg m²/s | L_z range / max abs L_z |"
    )
    lines = [hdr, "|" + "---|" * 10]
    for r in result["clips"]:
        for p in r["phases"]:
            az = "-" if p["com_az_fit"] is None else f"{p['com_az_fit']:.2f} ({p['com_fit_rms_m'] * 1e3:.1f})"
            lz = f"{p['Lz_min']:.1f} / {p['Lz_max']:.1f}" if "Lz_min" in p else "-"
            rel = f"{p['Lz_range_rel'] * 100:.0f}%" if "Lz_range_rel" in p else "-"
            lines.append(
                f"| {r['clip']} | {r['fps']:.0f} | {p['t_start']:.3f}–{p['t_end']:.3f} | {p['duration_s']:.3f} | {az} | "
                f"{p['com_vz_takeoff']:.2f} | {_f(p['ballistic_flight_s'])} | {_f(p['free_fall_fps'], '.1f')} | {lz} | {rel} |"
            )
    load = ", ".join(f"{x:.2f}" for x in result["loadavg"])
    return (
        f"# Flight phases of reference clips\n\nFlight = every body geom more than {result['threshold_m']} m above the floor. "
        f"In free flight the COM falls at g = {G} m/s² and L_z (about the COM) is constant.\n"
        f"Humanoid and motions: the spec embedded in `{result['checkpoint']}`.\n\n"
        + "\n".join(lines)
        + f"\n\nLoad average: {load}. Command: `{result['command']}`\n"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", type=Path, required=True, help="a checkpoint with an embedded spec (mocap eval's targets)")
    ap.add_argument("--clips", default="spin,jump,backflip", help="comma-separated clip names")
    ap.add_argument("--threshold", type=float, default=0.03, help="flight: every body geom more than this above the floor, m")
    ap.add_argument("--out", type=Path, default=Path("bench/results/clip_flight"), help="writes <out>.json and <out>.md")
    args = ap.parse_args(argv)
    clips = [c.strip() for c in args.clips.split(",") if c.strip()]
    if not args.checkpoint.is_file():
        print(f"error: no checkpoint {args.checkpoint}", file=sys.stderr)
        return 2
    import torch

    from mocap.checkpoint import CheckpointError
    from mocap.errors import UserError

    torch.set_num_threads(1)
    try:
        _, lib, model, idx = build(args.checkpoint, clips)
    except (LookupError, CheckpointError, UserError) as exc:
        print(f"error: {exc.args[0] if exc.args else exc}", file=sys.stderr)
        return 2
    argv_ = sys.argv[1:] if argv is None else argv
    result = {
        "command": shlex.join(["python", "bench/clip_flight.py", *argv_]),
        "checkpoint": str(args.checkpoint),
        "threshold_m": args.threshold,
        "g": G,
        "loadavg": list(os.getloadavg()),
        "clips": [analyse(lib, model, idx, c, args.threshold) for c in clips],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    (args.out.parent / f"{args.out.name}.json").write_text(json.dumps(result, indent=1) + "\n")
    md = render(result)
    (args.out.parent / f"{args.out.name}.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
