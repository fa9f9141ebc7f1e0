"""A/B comparison of imitator training levers, from ``bench/time_to_skill.py`` runs of one spec.

Each arm is a ``time_to_skill.py`` run of the same spec (same seed, same wall-clock budget, same
starting policy when the spec sets ``init_policy``) with one ``--set`` lever changed. This script
puts the arms side by side: clips tracked and MPJPE-g (``mocap eval``'s protocol, evaluated after
training) at each snapshot, and, from the training log of each arm (``--workdir`` of
``time_to_skill.py``), the mean training episode length and success over the last iterations (a
less noisy signal than 15 deterministic evaluation episodes). ``--start`` adds the starting
policy's own ``eval.json`` as the point at 0 minutes. ``--max-env-steps N`` keeps only the snapshots
at or below N env steps, so that arms of different lengths (one stopped early, say) are averaged over
the same range; an arm whose training did not finish is marked as such.

    python bench/imitator_ab.py --arm uniform=bench/results/imitator_ab_uniform.json:/work/abwork/uniform \\
        --arm adaptive=...:... --start checkpoints/imitator_amp_v3/eval.json --out bench/results/imitator_ab.json

Writes ``--out`` (JSON), a markdown table and a PNG next to it.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any


def training_tail(workdir: Path, last: int = 20, max_env_steps: int | None = None) -> dict[str, float]:
    """Mean of the last ``last`` PPO iterations' episode length/success/return in the arm's log (only
    the iterations at or below ``max_env_steps`` when given)."""
    logs = sorted(workdir.glob("runs/*/metrics.jsonl"))
    rows = []
    for log in logs:
        for line in log.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            if row.get("stage") == "imitator" and "episode/length" in row:
                if max_env_steps is None or row.get("env_steps", 0) <= max_env_steps:
                    rows.append(row)
    rows = rows[-last:]
    out: dict[str, float] = {"iterations": float(len(rows))}
    for key in ("episode/length", "episode/success", "episode/return", "steps_per_s", "lr", "std", "approx_kl"):
        vals = [float(r[key]) for r in rows if key in r and r[key] is not None]
        if vals:
            out[key] = sum(vals) / len(vals)
    return out


def load_arm(name: str, result: Path, workdir: Path | None, max_env_steps: int | None = None) -> dict[str, Any]:
    data = json.loads(result.read_text())
    points = [p for p in data["points"] if max_env_steps is None or p["env_steps"] <= max_env_steps]
    if not points:
        raise SystemExit(f"error: {result}: no snapshot at or below {max_env_steps} env steps")
    arm: dict[str, Any] = {
        "name": name,
        "spec": data.get("spec"),
        "overrides": data.get("overrides", []),
        "minutes": data.get("minutes"),
        "env_steps_budget": data.get("env_steps_budget"),
        "load_avg_before": data.get("load_avg_before"),
        "load_avg_at_end_of_training": data.get("load_avg_at_end_of_training"),
        "training_finished": bool(data.get("training_finished", True)),
        "points": points,
        "phases": data.get("phases") or [],
    }
    if workdir is not None:
        arm["training_last_20_iterations"] = training_tail(workdir, max_env_steps=max_env_steps)
    return arm


def start_point(eval_json: Path) -> dict[str, Any]:
    d = json.loads(eval_json.read_text())
    agg = d["aggregate"]
    return {
        "minutes": 0.0,
        "env_steps": 0,
        "clips_tracked": int(agg["succeeded"]),
        "clips_total": int(agg["total"]),
        "mpjpe_g_succ_mm": agg.get("mpjpe_g_succ"),
        "mpjpe_g_all_mm": agg.get("mpjpe_g"),
        "tracked": sorted(n for n, c in d["clips"].items() if c["success"]),
    }


def _f(v: Any, fmt: str = ".1f") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)


def _lever(arm: dict[str, Any], spec: str | None) -> str:
    """What an arm changes: its own spec when it is not the table's, and its ``--set`` overrides
    (without ``torch_threads``, which changes the speed, not the training)."""
    if len(arm.get("phases") or []) > 1:  # a curriculum (time_to_skill --after): each phase's lever and length
        return " then ".join(f"{_lever({**ph, 'phases': []}, spec)} for {ph['env_steps'] / 1e6:.2f}M" for ph in arm["phases"])
    parts = [f"spec {arm['spec']}"] if arm.get("spec") and arm["spec"] != spec else []
    parts += [o for o in arm["overrides"] if "torch_threads=" not in o]
    return "; ".join(parts) or "(the spec as is)"


def render(result: dict[str, Any]) -> str:
    by_steps = all(arm.get("env_steps_budget") for arm in result["arms"])
    budget = (
        "the same env-step budget (`time_to_skill.py --env-steps`; the minutes include any time the machine was shared or "
        "the run paused, so compare at equal env steps)"
        if by_steps
        else "the same wall-clock budget"
    )
    lines = [
        f"# Imitator A/B: {result['spec']}",
        "",
        f"Each arm: the spec plus one lever (a `--set` or a spec extending it), trained for {budget} from the same start, "
        "then evaluated with `mocap eval`'s protocol (15 clips, each once from its first frame). The last columns "
        "average the arm's last 20 PPO iterations: training episode length and success, learning rate and approx. KL.",
        "",
    ]
    if result.get("start"):
        s = result["start"]
        lines += [f"Start: {s['clips_tracked']}/{s['clips_total']} clips, MPJPE-g {_f(s['mpjpe_g_succ_mm'])} mm on them.", ""]
    if result.get("max_env_steps"):
        lines += [f"Only the snapshots at or below {result['max_env_steps'] / 1e6:.2f}M env steps are shown, so the arms cover the same range.", ""]
    for arm in result["arms"]:
        if not arm.get("training_finished", True):
            last = arm["points"][-1]["env_steps"] / 1e6
            lines += [f"{arm['name']}: the training did not finish (stopped after its last snapshot, at {last:.2f}M env steps shown).", ""]
    lines += [
        "| arm | lever | min | env steps | clips | MPJPE-g tracked (mm) | MPJPE-g all (mm) | train ep. length | train success | lr | KL | load avg |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for arm in result["arms"]:
        tail = arm.get("training_last_20_iterations", {})
        lever = _lever(arm, result["spec"])
        load = arm.get("load_avg_at_end_of_training")
        for p in arm["points"]:
            lines.append(
                f"| {arm['name']} | `{lever}` | {_f(p['minutes'])} | {p['env_steps'] / 1e6:.2f}M | {p['clips_tracked']}/{p['clips_total']} "
                f"| {_f(p['mpjpe_g_succ_mm'])} | {_f(p['mpjpe_g_all_mm'])} | {_f(tail.get('episode/length'))} "
                f"| {_f(tail.get('episode/success'), '.2f')} | {_f(tail.get('lr'), '.1e')} | {_f(tail.get('approx_kl'), '.3f')} "
                f"| {_f(load[0] if load else None, '.2f')} |"
            )
    lines += [
        "",
        "Over each arm's snapshots (mean, and the range): the evaluation moves by a clip or two between snapshots "
        "of one run, so compare these rather than single points.",
        "",
        "| arm | lever | snapshots | clips tracked | MPJPE-g all (mm) |",
        "|---|---|---|---|---|",
    ]
    for arm in result["arms"]:
        clips = [p["clips_tracked"] for p in arm["points"]]
        err = [p["mpjpe_g_all_mm"] for p in arm["points"] if p.get("mpjpe_g_all_mm") is not None]
        lines.append(
            f"| {arm['name']} | `{_lever(arm, result['spec'])}` | {len(clips)} | {sum(clips) / len(clips):.2f} ({min(clips)}-{max(clips)}) "
            f"| {_f(sum(err) / len(err) if err else None)} ({_f(min(err) if err else None)}-{_f(max(err) if err else None)}) |"
        )
    lines += ["", "Clips tracked at the end of each arm:", ""]
    for arm in result["arms"]:
        last = arm["points"][-1]
        lines.append(f"- {arm['name']}: {', '.join(last['tracked'])}")
    return "\n".join(lines) + "\n"


def plot(result: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    start = result.get("start")
    for arm in result["arms"]:
        pts = ([start] if start else []) + arm["points"]
        x = [p["env_steps"] / 1e6 for p in pts]
        axes[0].plot(x, [p["clips_tracked"] for p in pts], "o-", label=arm["name"])
        axes[1].plot(x, [p["mpjpe_g_succ_mm"] if p["mpjpe_g_succ_mm"] is not None else float("nan") for p in pts], "o-", label=arm["name"])
    axes[0].set(xlabel="env steps of this stage, M", ylabel="clips tracked (of 15)")
    axes[1].set(xlabel="env steps of this stage, M", ylabel="MPJPE-g on tracked clips, mm")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"imitator A/B ({result['spec']})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", action="append", required=True, help="NAME=RESULT.json[:WORKDIR] (repeatable)")
    ap.add_argument("--start", type=Path, default=None, help="eval.json of the starting policy (the 0-minute point)")
    ap.add_argument("--max-env-steps", type=int, default=None, help="keep only the snapshots at or below this many env steps")
    ap.add_argument("--out", type=Path, default=Path("bench/results/imitator_ab.json"))
    args = ap.parse_args(argv)
    arms, spec = [], None
    for item in args.arm:
        name, _, rest = item.partition("=")
        result_path, _, workdir = rest.partition(":")
        arm = load_arm(name, Path(result_path), Path(workdir) if workdir else None, args.max_env_steps)
        spec = spec or json.loads(Path(result_path).read_text()).get("spec")
        arms.append(arm)
    result = {"spec": spec, "start": start_point(args.start) if args.start else None, "max_env_steps": args.max_env_steps, "arms": arms}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    args.out.with_suffix(".md").write_text(render(result))
    plot(result, args.out.with_suffix(".png"))
    print(render(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
