"""The imitator's whole training lineage as one learning curve: clips tracked and MPJPE-g against
cumulative env steps and cumulative training wall-clock, from the committed per-run results.

Each committed imitator was continued from the previous one (``init_policy``), so its own curve
starts where its parent's run was cut. A segment names a result file and the env steps of that run
at which the next segment branched off (its exported snapshot), e.g. v7 is the 14.0M snapshot of a
16M-step run, and v8 continued from it: the points after 14.0M belong to a branch that was dropped.

Two result formats are read: ``bench/time_to_skill.py``'s (``points`` with ``env_steps``,
``minutes``, ``clips_tracked``, ``mpjpe_g_succ_mm``, ``mpjpe_g_all_mm``) and
``bench/imitator_curve.py plot``'s (``points`` with ``env_steps``, ``wall_s``, ``succeeded``,
``mpjpe_g_succ``, ``mpjpe_g``).

    python bench/imitator_lineage.py \\
        --segment v3=bench/results/imitator_curve.json \\
        --segment v4=bench/results/imitator_ab_init_lr.json \\
        --segment v6=bench/results/imitator_ab_v4_shoulders_xzy.json \\
        --segment v7=bench/results/imitator_v7_curve.json@14024704 \\
        --segment v8=bench/results/imitator_ab_g99.json \\
        --segment v11=bench/results/imitator_ab_hard_remix.json@13041664 \\
        --segment v12=bench/results/imitator_ab_cycles.json \\
        --segment v13=bench/results/imitator_ab_v12_control.json@1507328 \\
        --segment v14=bench/results/imitator_ab_v13_seed0.json@1015808 \\
        --segment v15=bench/results/imitator_ab_v14_fixed_sigma.json \\
        --segment v16=bench/results/imitator_v16_run.json@8028160 \\
        --out bench/results/imitator_lineage

``NAME=FILE[@STEPS]``: ``@STEPS`` cuts the segment at that env-step count (the snapshot the next
segment started from; the point at exactly that count must exist). Without it the whole run is kept,
and the next segment starts from its last point. Writes ``<out>.json`` and ``<out>.png``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def parse_segment(text: str) -> tuple[str, Path, int | None]:
    """``NAME=FILE[@STEPS]`` -> (name, file, cut env steps or None)."""
    name, sep, rest = text.partition("=")
    if not sep or not name or not rest:
        raise ValueError(f"--segment {text!r}: expected NAME=FILE[@STEPS]")
    path, at, steps = rest.rpartition("@") if "@" in rest else (rest, "", "")
    return name, Path(path), int(steps) if at else None


def run_points(data: dict[str, Any]) -> list[dict[str, float]]:
    """One run's points as ``env_steps``, ``minutes`` (training wall-clock), ``clips``, ``mpjpe_g_succ_mm``, ``mpjpe_g_all_mm``."""
    out = []
    for p in data["points"]:
        if "clips_tracked" in p:  # time_to_skill.py
            row = {"env_steps": p["env_steps"], "minutes": p["minutes"], "clips": p["clips_tracked"]}
            row |= {"mpjpe_g_succ_mm": p["mpjpe_g_succ_mm"], "mpjpe_g_all_mm": p["mpjpe_g_all_mm"]}
        else:  # imitator_curve.py
            row = {"env_steps": p["env_steps"], "minutes": p["wall_s"] / 60.0, "clips": p["succeeded"]}
            row |= {"mpjpe_g_succ_mm": p["mpjpe_g_succ"], "mpjpe_g_all_mm": p["mpjpe_g"]}
        out.append({k: float(v) if v is not None else float("nan") for k, v in row.items()})
    return sorted(out, key=lambda r: r["env_steps"])


def stitch(segments: list[tuple[str, list[dict[str, float]], int | None]]) -> list[dict[str, Any]]:
    """Chain the runs: each segment's env steps and minutes are offset by where its parent was cut.

    A segment's points after its cut are dropped; the parent's cut point (the child's starting
    policy) is the child's origin, so a child's own 0-step point (if any) is not repeated.
    """
    lineage: list[dict[str, Any]] = []
    steps0 = minutes0 = 0.0
    for name, points, cut in segments:
        if cut is not None:
            if not any(p["env_steps"] == cut for p in points):
                raise ValueError(f"segment {name}: no point at exactly {cut} env steps to cut at")
            points = [p for p in points if p["env_steps"] <= cut]
        points = [p for p in points if p["env_steps"] > 0 or not lineage]
        if not points:
            raise ValueError(f"segment {name}: no points")
        for p in points:
            row: dict[str, Any] = {"segment": name, **p}
            row["run_env_steps"], row["run_minutes"] = p["env_steps"], p["minutes"]
            row["env_steps"], row["minutes"] = p["env_steps"] + steps0, p["minutes"] + minutes0
            lineage.append(row)
        steps0, minutes0 = lineage[-1]["env_steps"], lineage[-1]["minutes"]
    return lineage


def plot(lineage: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    names = list(dict.fromkeys(r["segment"] for r in lineage))
    for name in names:
        rows = [r for r in lineage if r["segment"] == name]
        steps = [r["env_steps"] / 1e6 for r in rows]
        axes[0].plot(steps, [r["clips"] for r in rows], marker="o", ms=3, label=name)
        axes[1].plot(steps, [r["mpjpe_g_succ_mm"] for r in rows], marker="o", ms=3, label=name)
        axes[2].plot([r["minutes"] / 60 for r in rows], [r["clips"] for r in rows], marker="o", ms=3, label=name)
    axes[0].set(xlabel="env steps (M, cumulative)", ylabel="clips tracked (of 15)", ylim=(0, 15.5))
    axes[1].set(xlabel="env steps (M, cumulative)", ylabel="MPJPE-g on tracked clips (mm)")
    axes[2].set(xlabel="training wall-clock (h, cumulative, 2 cores)", ylabel="clips tracked (of 15)", ylim=(0, 15.5))
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].axhline(15, color="k", lw=0.8, ls="--")
    axes[1].axhline(50, color="k", lw=0.8, ls="--")
    axes[0].legend(fontsize=8)
    fig.suptitle("PHC imitator lineage on the 15 bundled clips (mocap eval after training; dashed: the targets)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--segment", action="append", required=True, help="NAME=FILE[@STEPS], in lineage order (repeatable)")
    ap.add_argument("--out", type=Path, required=True, help="output stem: <out>.json and <out>.png")
    ap.add_argument("--no-plot", action="store_true")
    args = ap.parse_args(argv)
    parsed = [parse_segment(s) for s in args.segment]
    segments = [(name, run_points(json.loads(path.read_text())), cut) for name, path, cut in parsed]
    lineage = stitch(segments)
    sources = [{"segment": n, "file": str(p), "cut_env_steps": c} for n, p, c in parsed]
    result = {
        "what": "the imitator lineage: each segment continued from the previous one's cut point (init_policy)",
        "sources": sources,
        "points": lineage,
        "final": lineage[-1],
        "best_clips": max(r["clips"] for r in lineage),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    if not args.no_plot:
        plot(lineage, args.out.with_suffix(".png"))
    last = lineage[-1]
    print(f"{len(lineage)} points, {last['env_steps'] / 1e6:.1f}M env steps, {last['minutes'] / 60:.1f} h: {last['clips']:.0f}/15 at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
