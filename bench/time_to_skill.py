"""Time to skill: what an imitator spec learns from scratch in a fixed wall-clock budget.

Trains ``--spec`` (default ``specs/imitator/amp_bundled.yaml``) from nothing with ``mocap run`` in
a child process for ``--minutes`` of wall-clock (default 60). Every ``--eval-every`` minutes
(default 10) the trainer's newest checkpoint (written every ``--checkpoint-every`` iterations) is
copied aside; at the end the child is stopped with Ctrl-C (a clean stop), and every snapshot is
evaluated with ``mocap eval``'s protocol (each clip once from its first frame, deterministic
actions; success = mean body error <= 0.5 m at every frame). The evaluations run after training,
so they do not take time from it: the wall-clock axis is training time only.

Output (``--out``, JSON + a PNG next to it): per snapshot the minutes, env steps, clips tracked,
MPJPE-g on the tracked clips and on all clips, and the per-clip successes; the load average before
and after (run it on an otherwise idle machine: the curve is wall-clock bound).

    python bench/time_to_skill.py --minutes 60 --out bench/results/time_to_skill_after.json

With ``--env-steps N`` the budget is N env steps instead (the trainer's ``total_env_steps``) and the
snapshots are taken every ``--snapshot-steps`` env steps: an A/B at equal samples, whose outcome
does not depend on what else shares the cores (the minutes are still recorded).

It measures whatever code ``mocap`` imports: to measure another checkout, run this script with that
checkout's packages first on ``PYTHONPATH`` (the child inherits it), ``--label`` naming it.

Nothing is lost on interruption: with ``--workdir`` every snapshot is listed in
``WORKDIR/snapshots.json`` as it is taken and each evaluation is kept next to its snapshot
(``eval.json``, reused when newer than the snapshot). If the session ends mid-run, evaluate what
was saved with ``--evaluate-only --workdir WORKDIR`` (the JSON then says the training did not
finish, and at how many env steps it stopped).

``--eval-motions deepmimic`` evaluates every snapshot on that motion source's default clips (all 15
bundled) instead of the spec's: for a run trained on a subset of the clips (a curriculum phase), so
that what it forgets shows too.

``--after PREV.json`` makes this run the next phase of PREV's (e.g. a curriculum: the hard clips, then
all of them, started from PREV's last snapshot through ``--set imitator.trainer.params.init_policy=``):
its snapshots are counted on from PREV's last env steps and minutes, PREV's points come first, and
``phases`` lists each phase's spec, overrides and env steps.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def _newest_checkpoint(store: Path) -> Path | None:
    found = sorted(store.glob("imitator-*/ppo.pt"), key=lambda p: p.stat().st_mtime)
    return found[-1] if found else None


def _env_steps(path: Path) -> int:
    import torch

    ck = torch.load(path, map_location="cpu", weights_only=False)  # our own trainer's file, written by the child
    return int(ck.get("env_steps", 0))


def _start(spec: Path, work: Path, checkpoint_every: int, overrides: list[str]) -> tuple[subprocess.Popen, Any, float]:
    """``mocap run`` of the spec in ``work/runs`` (no eval stage, checkpoints every ``checkpoint_every``
    iterations, the ``--set`` overrides) as a child logging to ``work/train.log``: (child, log, start time)."""
    out, store = work / "runs" / "tts", work / "runs" / "artifacts"
    cmd = [sys.executable, "-m", "mocap", "run", str(spec), "--out", str(out), "--store", str(store), "--set", "eval=null"]
    cmd += ["--set", f"imitator.trainer.params.checkpoint_every={checkpoint_every}"]
    for o in overrides:
        cmd += ["--set", o]
    log = open(work / "train.log", "w")
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT), log, time.perf_counter()


def save_snapshots(work: Path, snaps: list[dict], finished: bool) -> None:
    """List the snapshots taken so far in ``work/snapshots.json`` (atomically), so an interrupted run
    can still be evaluated."""
    tmp = work / "snapshots.json.tmp"
    tmp.write_text(json.dumps({"finished": finished, "snapshots": snaps}, indent=2) + "\n")
    os.replace(tmp, work / "snapshots.json")


def load_snapshots(work: Path) -> tuple[list[dict], bool]:
    """The snapshots listed in ``work/snapshots.json`` and whether the training finished."""
    d = json.loads((work / "snapshots.json").read_text())
    return list(d["snapshots"]), bool(d["finished"])


def _stop(child: subprocess.Popen) -> None:
    """A clean stop of the training child (Ctrl-C: it saves its checkpoint), killed after 2 min."""
    if child.poll() is None:
        child.send_signal(signal.SIGINT)
        try:
            child.wait(timeout=120)
        except subprocess.TimeoutExpired:
            child.kill()


def train(spec: Path, minutes: float, eval_every: float, checkpoint_every: int, work: Path, overrides: list[str]) -> list[dict]:
    """Run the spec for ``minutes``; return the snapshots taken (path, minute, env steps)."""
    store = work / "runs" / "artifacts"
    child, log, t0 = _start(spec, work, checkpoint_every, overrides)
    snaps: list[dict] = []
    marks = [eval_every * (k + 1) for k in range(int(minutes / eval_every + 1e-9))]
    try:
        for mark in marks:
            while time.perf_counter() - t0 < mark * 60 and child.poll() is None:
                time.sleep(1.0)
            newest = _newest_checkpoint(store)
            if newest is None:
                print(f"[{mark:5.1f} min] no checkpoint yet", flush=True)
                continue
            dst = work / f"snapshot_{mark:07.2f}" / "ppo.pt"  # mocap eval knows a trainer checkpoint by its name
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(newest, dst)
            steps = _env_steps(dst)
            snaps.append({"minutes": mark, "env_steps": steps, "path": str(dst)})
            print(f"[{mark:5.1f} min] snapshot at {steps / 1e6:.2f}M env steps", flush=True)
            save_snapshots(work, snaps, finished=False)
            if child.poll() is not None:
                break
    finally:
        _stop(child)
        log.close()
    save_snapshots(work, snaps, finished=True)
    return snaps


def train_steps(spec: Path, env_steps: int, snapshot_steps: int, checkpoint_every: int, work: Path, overrides: list[str]) -> list[dict]:
    """Run the spec for ``env_steps`` env steps; snapshot the newest checkpoint each time it passes a
    multiple of ``snapshot_steps`` (and at the end); return the snapshots (path, minute, env steps)."""
    store = work / "runs" / "artifacts"
    child, log, t0 = _start(spec, work, checkpoint_every, [f"imitator.trainer.params.total_env_steps={env_steps}", *overrides])
    snaps: list[dict] = []
    next_mark, seen_mtime = snapshot_steps, 0.0
    try:
        while True:
            done = child.poll() is not None
            newest = _newest_checkpoint(store)
            if newest is not None and newest.stat().st_mtime != seen_mtime:
                seen_mtime = newest.stat().st_mtime
                tmp = work / "newest.pt"
                shutil.copy2(newest, tmp)
                steps = _env_steps(tmp)
                if steps >= next_mark or (done and (not snaps or snaps[-1]["env_steps"] < steps)):
                    dst = work / f"snapshot_{steps:010d}" / "ppo.pt"  # mocap eval knows a trainer checkpoint by its name
                    dst.parent.mkdir(parents=True, exist_ok=True)
                    shutil.move(tmp, dst)
                    minutes = (time.perf_counter() - t0) / 60
                    snaps.append({"minutes": round(minutes, 2), "env_steps": steps, "path": str(dst)})
                    print(f"[{minutes:5.1f} min] snapshot at {steps / 1e6:.2f}M env steps", flush=True)
                    save_snapshots(work, snaps, finished=False)
                    while next_mark <= steps:
                        next_mark += snapshot_steps
            if done:
                break
            time.sleep(5.0)
    finally:
        _stop(child)
        log.close()
    save_snapshots(work, snaps, finished=child.returncode == 0)
    if child.returncode not in (0, None):
        print(f"warning: the training child exited with {child.returncode}; see {work / 'train.log'}", flush=True)
    return snaps


def evaluate(snap: dict, work: Path, motions: str | None = None) -> dict:
    """``mocap eval`` of one snapshot (on the training clips, or on the motion source ``motions`` with
    its default params: e.g. all 15 bundled clips for a run trained on a subset)."""
    out = Path(snap["path"]).parent / ("eval.json" if motions is None else f"eval_on_{motions}.json")
    if not out.exists() or out.stat().st_mtime < Path(snap["path"]).stat().st_mtime:
        cmd = [sys.executable, "-m", "mocap", "eval", snap["path"], "--json", str(out)]
        subprocess.run(cmd + ([] if motions is None else ["--motions", motions]), check=True, capture_output=True)
    d = json.loads(out.read_text())
    agg = d["aggregate"]
    return {
        **{k: v for k, v in snap.items() if k != "path"},
        "clips_tracked": int(agg["succeeded"]),
        "clips_total": int(agg["total"]),
        "mpjpe_g_succ_mm": agg.get("mpjpe_g_succ"),
        "mpjpe_g_all_mm": agg.get("mpjpe_g"),
        "tracked": sorted(name for name, c in d["clips"].items() if c["success"]),
    }


def chain(prev: dict, points: list[dict], phase: dict) -> tuple[list[dict], list[dict]]:
    """This phase's points counted on from the previous phase's last snapshot (env steps and minutes),
    after that phase's points; the phases list (``--after``)."""
    if not prev.get("points"):
        raise SystemExit("error: --after: the previous phase's result has no snapshot")
    last = prev["points"][-1]
    moved = [{**p, "env_steps": p["env_steps"] + last["env_steps"], "minutes": p["minutes"] + last["minutes"]} for p in points]
    before = prev.get("phases") or [{"spec": prev.get("spec"), "overrides": prev.get("overrides", []), "env_steps": last["env_steps"]}]
    return prev["points"] + moved, [*before, phase]


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = result["points"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    x_min = [p["minutes"] for p in pts]
    x_steps = [p["env_steps"] / 1e6 for p in pts]
    clips = [p["clips_tracked"] for p in pts]
    mm = [p["mpjpe_g_succ_mm"] if p["mpjpe_g_succ_mm"] is not None else float("nan") for p in pts]
    axes[0].plot(x_min, clips, "o-")
    axes[0].set(xlabel="wall-clock, min", ylabel="clips tracked (of 15)", title="clips vs wall-clock")
    axes[1].plot(x_steps, clips, "o-")
    axes[1].set(xlabel="env steps, M", ylabel="clips tracked", title="clips vs env steps")
    axes[2].plot(x_min, mm, "o-")
    axes[2].set(xlabel="wall-clock, min", ylabel="MPJPE-g on tracked clips, mm", title="error vs wall-clock")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"time to skill: {result['label']} ({result['spec']})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spec", type=Path, default=Path("specs/imitator/amp_bundled.yaml"))
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--eval-every", type=float, default=10.0, help="minutes between snapshots")
    ap.add_argument("--env-steps", type=int, default=None, help="budget in env steps instead of minutes")
    ap.add_argument("--snapshot-steps", type=int, default=500_000, help="with --env-steps: env steps between snapshots")
    ap.add_argument("--checkpoint-every", type=int, default=2, help="trainer iterations between checkpoints")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="extra spec override (repeatable)")
    ap.add_argument("--evaluate-only", action="store_true", help="no training: evaluate the snapshots listed in WORKDIR/snapshots.json")
    ap.add_argument("--eval-motions", default=None, help="evaluate on this motion source's default clips instead of the training ones")
    ap.add_argument("--after", type=Path, default=None, help="result JSON of the phase this run continues (its points come first)")
    ap.add_argument("--label", default="this checkout")
    ap.add_argument("--workdir", type=Path, default=None, help="keep the run and snapshots here (default: a temporary folder)")
    ap.add_argument("--out", type=Path, default=Path("bench/results/time_to_skill.json"))
    args = ap.parse_args(argv)
    if args.env_steps is None and (args.eval_every <= 0 or args.minutes < args.eval_every):
        ap.error("--eval-every must be > 0 and at most --minutes")
    if args.evaluate_only and (args.workdir is None or not (args.workdir / "snapshots.json").is_file()):
        ap.error("--evaluate-only needs --workdir holding the snapshots.json of an earlier run")
    if args.after is not None and not args.after.is_file():
        ap.error(f"--after {args.after}: no such result file")
    if args.env_steps is not None and (args.env_steps <= 0 or args.snapshot_steps <= 0):
        ap.error("--env-steps and --snapshot-steps must be > 0")
    os.environ.setdefault("MUJOCO_GL", "egl")
    from mocap.checkpoint import hardware, package_versions

    work = args.workdir or Path(tempfile.mkdtemp(prefix="time_to_skill_"))
    work.mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()
    started = time.strftime("%Y-%m-%dT%H:%M:%S")
    finished = True
    if args.evaluate_only:
        snaps, finished = load_snapshots(work)
    elif args.env_steps is not None:
        snaps = train_steps(args.spec.resolve(), args.env_steps, args.snapshot_steps, args.checkpoint_every, work, args.overrides)
    else:
        snaps = train(args.spec.resolve(), args.minutes, args.eval_every, args.checkpoint_every, work, args.overrides)
    load_after = os.getloadavg()
    points = []
    for snap in snaps:
        points.append(evaluate(snap, work, args.eval_motions))
        p = points[-1]
        print(f"[{p['minutes']:5.1f} min, {p['env_steps'] / 1e6:.2f}M] {p['clips_tracked']}/{p['clips_total']} clips", flush=True)
    phase = {"spec": str(args.spec), "overrides": args.overrides, "env_steps": points[-1]["env_steps"] if points else 0}
    phases = [phase]
    if args.after is not None:
        points, phases = chain(json.loads(args.after.read_text()), points, phase)
    result = {
        "label": args.label,
        "phases": phases,
        "spec": str(args.spec),
        "overrides": args.overrides,
        "minutes": args.minutes if args.env_steps is None else None,
        "env_steps_budget": args.env_steps,
        "started": None if args.evaluate_only else started,  # --evaluate-only: the training's start and load are not known here
        "load_avg_before": None if args.evaluate_only else load_before,
        "load_avg_at_end_of_training": None if args.evaluate_only else load_after,
        "protocol": "mocap eval (mocap-imitation-v1), each snapshot evaluated after training",
        "eval_motions": args.eval_motions,
        "training_finished": finished,
        "points": points,
        "versions": package_versions(),
        "hardware": hardware(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    plot(result, args.out.with_suffix(".png"))
    print(f"wrote {args.out} and {args.out.with_suffix('.png')}")
    if args.workdir is None:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
