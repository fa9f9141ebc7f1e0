"""Imitation from noisy references along training runs: `mocap eval-noisy` of every snapshot of each arm.

Each ``--arm`` is the work directory of a ``bench/time_to_skill.py`` run (its ``snapshots.json`` lists the
snapshots and their env steps; each snapshot folder holds the clean ``eval.json`` that time_to_skill
wrote). For every snapshot this runs ``mocap eval-noisy SNAPSHOT --levels L --seed S`` for each noise
seed (separate processes, one thread each) and records the clips tracked and MPJPE-g, next to the
clean numbers. A ``--checkpoint LABEL=PATH`` is an arm of one point (a committed policy). With
``--smooth a1,a2`` every point is also evaluated on the stream after `mocap eval-noisy --smooth a` (a
causal exponential filter; 1 = the raw stream). Output: JSON with every value and the command, and a PNG
(clips tracked on the noisy stream and on the clean clips against env steps, one line per arm and
smoothing, the noise seeds' mean with their min-max as a band).

    python bench/noisy_snapshots.py --arm control=/work/runs/v18 --arm noise=/work/runs/v18_noise \\
        --checkpoint v17=checkpoints/imitator_amp_v17/policy.pt --level 1 --seeds 0,1,2 --smooth 1,0.8 \\
        --out bench/results/imitator_ab_v17_noise
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def eval_noisy(snapshot: Path, level: str, seed: int, smooth: float = 1.0, velocities: str | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "noisy.json"
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        cmd = [
            sys.executable,
            "-m",
            "mocap",
            "eval-noisy",
            str(snapshot),
            "--levels",
            level,
            "--seed",
            str(seed),
            "--smooth",
            f"{smooth:g}",
            "--json",
            str(out),
        ] + ([] if velocities is None else ["--velocities", velocities])
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"error: {snapshot}: eval-noisy failed: {proc.stderr.strip().splitlines()[-1:]}")
        return {"seed": seed, "smooth": smooth, **summarize(json.loads(out.read_text()))}


def summarize(result: dict) -> dict:
    """Clips tracked, their names and MPJPE-g of the (single) level of a `mocap eval-noisy --json` result."""
    if len(result["levels"]) != 1:
        raise ValueError(f"expected one noise level, got {len(result['levels'])}")
    level = result["levels"][0]
    agg = level["aggregate"]
    tracked = sorted(name for name, c in level["clips"].items() if c["success"])
    if len(tracked) != agg["succeeded"]:
        raise ValueError(f"{len(tracked)} clips marked successful but the aggregate says {agg['succeeded']}")
    return {"succeeded": agg["succeeded"], "total": agg["total"], "mpjpe_g_mm": agg["mpjpe_g"], "tracked": tracked}


def clean_eval(snapshot_dir: Path) -> dict | None:
    path = snapshot_dir / "eval.json"
    if not path.exists():
        return None
    agg = json.loads(path.read_text())["aggregate"]
    return {"succeeded": agg["succeeded"], "total": agg["total"], "mpjpe_g_mm": agg["mpjpe_g"]}


def plot(result: dict, path: Path) -> None:
    """Clips tracked on the noisy stream (solid, band: min-max over noise seeds) and on the clean clips (dashed,
    same colour) against the env steps of each arm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 1, figsize=(10, 4.5))
    line = 0
    for arm in result["arms"]:
        x = [p["env_steps"] / 1e6 for p in arm["points"]]
        first = f"C{line % 10}"
        for a in result["smooth"]:
            color = f"C{line % 10}"
            line += 1
            noisy = [[r["succeeded"] for r in p["noisy"] if r["smooth"] == a] for p in arm["points"]]
            name = f"{arm['label']}: noisy level {result['level']}" + (f", smoothing {a:g}" if a != 1 else "")
            ax.plot(x, [sum(v) / len(v) for v in noisy], "o-", color=color, label=name)
            ax.fill_between(x, [min(v) for v in noisy], [max(v) for v in noisy], color=color, alpha=0.15)
        clean = [p["clean"]["succeeded"] if p["clean"] else float("nan") for p in arm["points"]]
        ax.plot(x, clean, "s--", color=first, alpha=0.6, label=f"{arm['label']}: clean clips")
    ax.set_xlabel("env steps of the run (M)")
    ax.set_ylabel("clips tracked (of 15)")
    seeds = ",".join(str(s) for s in result["seeds"])
    ax.set_title(f"noisy references, level {result['level']}: mean and min-max over noise seeds {seeds}; clean clips dashed")
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _pair(spec: str, option: str, form: str) -> tuple[str, str]:
    label, sep, value = spec.partition("=")
    if not sep or not label or not value:
        raise SystemExit(f"error: {option} {spec!r}: expected {form}")
    return label, value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--arm", action="append", default=[], help="LABEL=WORKDIR of a time_to_skill run (repeatable)")
    parser.add_argument("--checkpoint", action="append", default=[], help="LABEL=PATH of one policy, an arm of one point (repeatable)")
    parser.add_argument("--level", default="1", help="a noise level as `mocap eval-noisy --levels` takes it (one level)")
    parser.add_argument("--seeds", default="0,1,2", help="noise seeds, comma-separated")
    parser.add_argument("--smooth", default="1", help="smoothing factors a in (0, 1], comma-separated (1: the raw stream)")
    parser.add_argument("--velocities", default=None, help="`mocap eval-noisy --velocities` (default: each policy's own)")
    parser.add_argument("--replot", type=Path, default=None, help="no evaluation: redraw the PNG of this JSON (written by this script)")
    parser.add_argument("--out", type=Path, required=True, help="output stem: writes STEM.json and STEM.png")
    args = parser.parse_args(argv)
    if args.replot is not None:
        if not args.replot.is_file():
            raise SystemExit(f"error: {args.replot}: not found")
        plot(json.loads(args.replot.read_text()), args.out.with_suffix(".png"))
        print(f"wrote {args.out.with_suffix('.png')}")
        return 0
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        raise SystemExit(f"error: --seeds {args.seeds!r}: expected integers, comma-separated") from None
    if not seeds:
        raise SystemExit("error: --seeds: give at least one noise seed")

    smooths = [float(a) for a in args.smooth.split(",") if a.strip()]
    if not smooths or any(not 0 < a <= 1 for a in smooths):
        raise SystemExit(f"error: --smooth {args.smooth!r}: each factor must be in (0, 1]")
    if not args.arm and not args.checkpoint:
        raise SystemExit("error: give at least one --arm or --checkpoint")

    sources: list[tuple[str, str, list[dict]]] = []
    for spec in args.arm:
        label, workdir = _pair(spec, "--arm", "LABEL=WORKDIR")
        index = Path(workdir) / "snapshots.json"
        if not index.exists():
            raise SystemExit(f"error: {index}: not found (a bench/time_to_skill.py work directory has it)")
        sources.append((label, workdir, json.loads(index.read_text())["snapshots"]))
    for spec in args.checkpoint:
        label, path = _pair(spec, "--checkpoint", "LABEL=PATH")
        if not Path(path).exists():
            raise SystemExit(f"error: {path}: not found")
        sources.append((label, path, [{"env_steps": 0, "path": path}]))

    arms = []
    for label, source, snapshots in sources:
        points = []
        for snap in snapshots:
            path = Path(snap["path"])
            runs = [eval_noisy(path, args.level, s, a, args.velocities) for a in smooths for s in seeds]
            point = {"env_steps": snap["env_steps"], "minutes": snap.get("minutes"), "snapshot": str(path), "noisy": runs, "clean": clean_eval(path.parent)}
            for a in smooths:
                mine = [r["succeeded"] for r in runs if r["smooth"] == a]
                print(f"{label}: {snap['env_steps']:,} env steps, smoothing {a:g}: noisy {sum(mine) / len(mine):.2f}/{runs[0]['total']} clips", flush=True)
            points.append(point)
        arms.append({"label": label, "source": source, "points": points})

    load = os.getloadavg()
    result = {
        "protocol": "mocap eval-noisy of each snapshot (errors against the clean clip), one process per noise seed",
        "level": args.level,
        "seeds": seeds,
        "smooth": smooths,
        "velocities": args.velocities or "each policy's own",
        "arms": arms,
        "load_avg_at_end": list(load),
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "command": "python bench/noisy_snapshots.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")

    plot(result, args.out.with_suffix(".png"))
    print(f"wrote {args.out.with_suffix('.json')} and {args.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
