"""Downstream tasks through each latent space: normalized-return curves and final task metrics.

Trains the shipped per-pairing specs ``specs/tasks/<task>_<latent>.yaml`` (the same PPO task policy
acting on PD targets for ``scratch``, or through a frozen, committed latent space) with one budget
and a list of seeds, then collects every cell's learning curve from its ``metrics.jsonl``:

    python bench/task_compare.py run --tasks speed reach strike \\
        --latents scratch pulse hybrid_rvq vmp --seeds 0 --steps 500000 --out /tmp/task-compare
    python bench/task_compare.py collect --out /tmp/task-compare --json bench/results/task_compare

``collect --include-unfinished`` also tabulates cells whose run was stopped (their training curves so
far, the latent labelled with the step count; no evaluation). ``--suffix _v15`` trains
``specs/tasks/<task>_<latent>_v15.yaml`` instead (the latent spaces of the 14/15-clip teacher).
``collect --task-eval 64`` also evaluates every finished cell's task policy with its deterministic
action (``mocap task-eval``: 64 envs x ``--task-eval-seconds`` 10 s), the numbers a user of the policy
gets, beside the training ones (which include exploration noise); each cell keeps its evaluation in
``task_eval_cache.json`` and a later ``collect`` reuses it while the policy file and the protocol match.
``collect --task-eval-start-clips walk,run`` starts those evaluations from frames of the named clips
(``mocap task-eval --start-clips``), e.g. to compare policies trained from different start states on
the same ones. ``collect --at-steps N`` compares the cells at equal env steps: each curve is cut at N (a run that went
further, e.g. an earlier seed trained longer, counts with its first N steps; its final values are the
last 10% of iterations up to N), and only the cells whose saved policy was trained for N steps (within
one iteration) are evaluated with ``--task-eval``; the tables name N and the deterministic table counts
the seeds it evaluated. ``--at-steps strike=5000000`` sets one task's budget (repeat the option; a plain N is
the budget of the other tasks). The markdown ends with a summary: each task's primary metric per latent
space (of the deterministic policy where evaluated, else of training), and which latent space is best.
``--merge bench/results/task_compare.json`` adds new cells (a latent space, more seeds) to an earlier
comparison whose run directories are gone: its cells are kept unless collected again, the budgets and
evaluation start clips must match, and the JSON records the earlier command under ``merged_from``.

``run`` is resumable: a finished cell is reused by the pipeline, an interrupted one resumes from
its checkpoint; cells run in seed-major order, so an early stop still leaves every pairing with
seed 0. ``collect`` writes ``<json>.json`` (per cell: the curve of ``episode/normalized_return``,
episode length and every ``eval/*`` task metric, binned to 20 points, plus the final values, i.e.
the mean over the last 10% of iterations), ``<json>.md`` (those final values per task as tables,
mean ± std over seeds) and ``<json>.png`` (one panel per task, one line per latent space, a band
over seeds when there are several).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CURVE_KEYS = ("episode/normalized_return", "episode/length", "episode/success")
#: the task metric plotted in the third row, per task
PRIMARY = {"speed": "eval/speed_error", "reach": "eval/success_rate", "strike": "eval/hit_rate", "point_goal": "eval/success_rate"}


def cell_name(task: str, latent: str, seed: int) -> str:
    return f"{task}_{latent}_s{seed}"


def run(args: argparse.Namespace) -> int:
    args.out.mkdir(parents=True, exist_ok=True)
    cells = [(t, l, s) for s in args.seeds for t in args.tasks for l in args.latents]
    missing = [ROOT / "specs" / "tasks" / f"{t}_{l}{args.suffix}.yaml" for t, l, _ in cells]
    missing = [p for p in missing if not p.is_file()]
    if missing:
        print("error: no spec " + ", ".join(str(p.relative_to(ROOT)) for p in missing), file=sys.stderr)
        return 2
    for i, (task, latent, seed) in enumerate(cells, 1):
        name = cell_name(task, latent, seed)
        cell_dir = args.out / name
        if (cell_dir / "stages.json").is_file() and _finished(cell_dir, args.steps):
            print(f"[{i}/{len(cells)}] {name}: done")
            continue
        spec = ROOT / "specs" / "tasks" / f"{task}_{latent}{args.suffix}.yaml"
        cell_dir.mkdir(parents=True, exist_ok=True)
        (cell_dir / "cell.json").write_text(json.dumps({"task": task, "latent": latent, "seed": seed, "spec": str(spec.relative_to(ROOT))}) + "\n")
        cmd = [
            sys.executable, "-m", "mocap", "run", str(spec),
            "--set", f"task.trainer.params.total_env_steps={args.steps}",
            "--set", f"seed={seed}",
            "--out", str(cell_dir), "--store", str(args.out / "artifacts"),
        ]  # fmt: skip
        print(f"[{i}/{len(cells)}] {name}: training {args.steps:,} env steps", flush=True)
        t0 = time.time()
        with open(args.out / f"{name}.log", "a") as log:
            rc = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
        print(f"[{i}/{len(cells)}] {name}: exit {rc} after {time.time() - t0:.0f} s", flush=True)
        if rc != 0:
            return rc
    return 0


def _finished(cell_dir: Path, steps: int) -> bool:
    rows = _rows(cell_dir)
    return bool(rows) and rows[-1].get("env_steps", 0) >= steps


def _task_done(cell_dir: Path) -> bool:
    path = cell_dir / "stages.json"
    try:
        return any(s.get("stage") == "task" and s.get("checkpoint") for s in json.loads(path.read_text()))
    except (OSError, ValueError):
        return False


def _task_policy(cell_dir: Path) -> Path:
    stages = json.loads((cell_dir / "stages.json").read_text())
    return Path(next(s["checkpoint"] for s in stages if s.get("stage") == "task"))


def _task_eval(cell_dir: Path, num_envs: int, seconds: float, start_clips: list[str] | None = None) -> dict:
    """``mocap task-eval`` of a finished cell, kept in ``<cell>/task_eval_cache.json`` with the task policy's
    SHA-256 and the protocol (envs, seconds, start clips): a later ``collect`` reuses it while all match."""
    import hashlib

    policy = _task_policy(cell_dir)
    key: dict = {"policy_sha256": hashlib.sha256(policy.read_bytes()).hexdigest() if policy.is_file() else None, "num_envs": num_envs, "seconds": seconds}
    if start_clips is not None:  # absent for the run's own starts, so that caches written before the option still match
        key["start_clips"] = start_clips
    cache = cell_dir / "task_eval_cache.json"
    try:
        cached = json.loads(cache.read_text())
        if cached.get("key") == key:
            print(f"{cell_dir.name}: task-eval reused from {cache.name}", flush=True)
            return cached["metrics"]
    except (OSError, ValueError, AttributeError):
        pass
    from mocap.task_eval import evaluate_task

    print(f"{cell_dir.name}: task-eval, {num_envs} envs x {seconds:g} s", flush=True)
    result = evaluate_task(cell_dir, num_envs=num_envs, seconds=seconds, start_clips=start_clips)
    metrics = {k: v for k, v in result.items() if isinstance(v, (int, float)) and k != "seed"}
    cache.write_text(json.dumps({"key": key, "metrics": metrics}, indent=1) + "\n")
    return metrics


def _rows(cell_dir: Path) -> list[dict]:
    path = cell_dir / "metrics.jsonl"
    if not path.is_file():
        return []
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [r for r in rows if r.get("stage") == "task" and "env_steps" in r]


def summarize(rows: list[dict], bins: int = 20) -> dict:
    """Binned curve (mean of each metric within equal env-step bins) and final values (last 10%)."""
    keys = [k for k in CURVE_KEYS if any(k in r for r in rows)]
    keys += sorted({k for r in rows for k in r if k.startswith("eval/")})
    top = max(r["env_steps"] for r in rows)
    curve = []
    for b in range(bins):
        lo, hi = top * b / bins, top * (b + 1) / bins
        sel = [r for r in rows if lo < r["env_steps"] <= hi]
        if not sel:
            continue
        point = {"env_steps": max(r["env_steps"] for r in sel)}
        for k in keys:
            vals = [r[k] for r in sel if r.get(k) is not None]
            if vals:
                point[k] = sum(vals) / len(vals)
        curve.append(point)
    tail = rows[-max(1, len(rows) // 10) :]
    final = {"env_steps": top}
    for k in keys:
        vals = [r[k] for r in tail if r.get(k) is not None]
        if vals:
            final[k] = sum(vals) / len(vals)
    wall = rows[-1]["time"] - rows[0]["time"] if len(rows) > 1 else 0.0
    return {"curve": curve, "final": final, "wall_s": round(wall, 1)}


def cut_at(rows: list[dict], steps: int | None) -> tuple[list[dict], str]:
    """(the rows up to ``steps`` env steps, where the run's last row lies: 'at' ``steps`` within one
    iteration (its saved policy is the policy at ``steps``), 'past' it, or 'short' of it). ``steps``
    None: all rows, 'at'."""
    if steps is None or not rows:
        return rows, "at"
    iteration = rows[1]["env_steps"] - rows[0]["env_steps"] if len(rows) > 1 else rows[0]["env_steps"]
    last = rows[-1]["env_steps"]
    where = "at" if abs(last - steps) <= iteration else "past" if last > steps else "short"
    return [r for r in rows if r["env_steps"] <= steps], where


def parse_at_steps(values: list[str] | None) -> dict[str, int]:
    """``--at-steps`` values to budgets: ``N`` for every task (key ``*``), ``task=N`` for one task."""
    budgets: dict[str, int] = {}
    for value in values or []:
        task, _, number = value.rpartition("=")
        try:
            steps = int(float(number))
        except ValueError:
            raise ValueError(f"--at-steps {value!r}: expected N or TASK=N (an env-step count)") from None
        if steps <= 0:
            raise ValueError(f"--at-steps {value!r}: the env-step count must be positive")
        budgets[task.strip() or "*"] = steps
    return budgets


def _cell_meta(cell_dir: Path) -> tuple[str, str, int] | None:
    """(task, latent, seed) of a cell directory: its ``cell.json``, else its name ``<task>_<latent>_s<seed>``;
    None for a directory that is neither (an artifact store, a log folder)."""
    meta_file = cell_dir / "cell.json"
    if meta_file.is_file():  # written by `run`; names with underscores (point_goal, hybrid_rvq) parse safely
        meta = json.loads(meta_file.read_text())
        return meta["task"], meta["latent"], int(meta["seed"])
    match = re.fullmatch(r"([^_]+)_(.+)_s(\d+)", cell_dir.name)
    return (match[1], match[2], int(match[3])) if match else None


def collect(args: argparse.Namespace) -> int:
    cells = {}
    try:
        budgets = parse_at_steps(args.at_steps)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for cell_dir in sorted(p for p in args.out.iterdir() if p.is_dir() and p.name != "artifacts"):
        meta = _cell_meta(cell_dir)
        if meta is None:
            print(f"skipped {cell_dir.name}: not a cell (no cell.json, not named <task>_<latent>_s<seed>)")
            continue
        task, latent, seed = meta
        at_steps = budgets.get(task, budgets.get("*"))
        rows, where = cut_at(_rows(cell_dir), at_steps)
        if not rows:
            continue
        if where == "short":
            print(f"skipped {cell_dir.name}: it has not reached {at_steps:,} env steps")
            continue
        finished = _task_done(cell_dir)
        if not finished and not args.include_unfinished:
            print(f"skipped {cell_dir.name}: its task stage has not finished")
            continue
        if not finished:  # --include-unfinished: its training curve so far, labelled, never evaluated
            latent = f"{latent} (stopped at {rows[-1]['env_steps'] / 1e6:.1f}M)"
        cells[cell_dir.name] = {"task": task, "latent": latent, "seed": seed, "finished": finished, **summarize(rows)}
        if args.task_eval > 0 and finished and where == "at":
            cells[cell_dir.name]["task_eval"] = _task_eval(cell_dir, args.task_eval, args.task_eval_seconds, args.task_eval_start_clips)
    merged_from: list[dict] = []
    if args.merge is not None:
        try:
            kept, merged_from = merge_cells(args.merge, cells, budgets, args.task_eval_start_clips)
        except ValueError as exc:
            print(f"error: {args.merge}: {exc}", file=sys.stderr)
            return 2
        cells = {**kept, **cells}
    if not cells:
        print(f"error: no finished cells under {args.out}", file=sys.stderr)
        return 2
    groups = group_cells(cells)
    out = {
        "command": " ".join(["python", "bench/task_compare.py", *args.argv]),
        "at_steps": budgets.get("*"),
        "at_steps_per_task": {k: v for k, v in budgets.items() if k != "*"},
        "task_eval_start_clips": args.task_eval_start_clips,
        "merged_from": merged_from,
        "groups": groups,
        "cells": dict(sorted(cells.items())),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.with_suffix(".json").write_text(json.dumps(out, indent=1) + "\n")
    _plot(cells, args.json.with_suffix(".png"))
    args.json.with_suffix(".md").write_text(render_markdown(groups, budgets, args.task_eval_start_clips))
    for name, g in sorted(groups.items()):
        f = g["final"]
        nr = f.get("episode/normalized_return", {})
        ln = f.get("episode/length", {})
        print(
            f"{name:24s} seeds {len(g['seeds'])}  normalized return {nr.get('mean', float('nan')):.3f} ± {nr.get('std', 0):.3f}  "
            f"length {ln.get('mean', float('nan')):.1f}"
        )
    return 0


def group_cells(cells: dict) -> dict[str, dict]:
    """``task/latent`` -> the seeds and, per metric, {mean, std, n} over them (final values and evaluations)."""
    groups: dict[str, dict] = {}
    for c in cells.values():
        g = groups.setdefault(f"{c['task']}/{c['latent']}", {"seeds": [], "final": {}, "task_eval": {}})
        g["seeds"].append(c["seed"])
        for part in ("final", "task_eval"):
            for k, v in c.get(part, {}).items():
                g[part].setdefault(k, []).append(v)
    for g in groups.values():
        for part in ("final", "task_eval"):
            g[part] = {k: {"mean": sum(v) / len(v), "std": _std(v), "n": len(v)} for k, v in g[part].items()}
    return dict(sorted(groups.items()))


def merge_cells(path: Path, new_cells: dict, budgets: dict[str, int], start_clips: list[str] | None) -> tuple[dict, list[dict]]:
    """The cells of an earlier ``collect`` JSON that this one did not collect again (a cell of the same
    name collected now replaces the earlier one), and the provenance list to record: the earlier
    command and the cells taken from it (plus whatever that JSON had merged itself). Raises ValueError
    when the earlier comparison is not at the same budget for a task it shares with this one, or its
    deterministic evaluations started elsewhere: those cells would not be comparable."""
    try:
        old = json.loads(path.read_text())
        old_cells, old_default, old_per_task = old["cells"], old.get("at_steps"), old.get("at_steps_per_task") or {}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"not a task_compare JSON ({exc})") from None
    if old.get("task_eval_start_clips") != start_clips:
        raise ValueError(f"its evaluations start from {old.get('task_eval_start_clips')}, this one's from {start_clips}")
    kept = {name: c for name, c in old_cells.items() if name not in new_cells}
    for task in sorted({c["task"] for c in kept.values()}):
        before, now = old_per_task.get(task, old_default), budgets.get(task, budgets.get("*"))
        if before != now:
            raise ValueError(f"its {task} cells are at {before} env steps, this comparison's at {now}")
    provenance = [*old.get("merged_from", []), {"command": old.get("command"), "cells": sorted(kept)}]
    return kept, provenance


def _budget_text(steps: int) -> str:
    return f"{steps / 1e6:g}M env steps"


def render_markdown(groups: dict, budgets: dict[str, int] | None = None, start_clips: list[str] | None = None) -> str:
    """One table per task: a row per latent space, final values as mean ± std over seeds (at the env-step
    ``budgets`` when given: key ``*`` for every task, a task's name for its own; the deterministic
    evaluation from ``start_clips`` when given), then the summary of each task's primary metric."""
    budgets = budgets or {}
    per_task = {k: v for k, v in budgets.items() if k != "*"}
    where = f" at {_budget_text(budgets['*'])}" if "*" in budgets and not per_task else " at equal env steps per task" if per_task else ""
    lines = [f"# Task comparison{where}: final values (mean over the last 10% of iterations; mean ± std over seeds)", ""]
    tasks = sorted({name.split("/")[0] for name in groups})
    for task in tasks:
        rows = {name.split("/")[1]: g for name, g in sorted(groups.items()) if name.split("/")[0] == task}
        keys = ["episode/normalized_return", "episode/length"]
        keys += sorted({k for g in rows.values() for k in g["final"] if k.startswith("eval/") and k not in ("eval/steps",)})
        budget = budgets.get(task, budgets.get("*"))
        heading = f"## {task}" + (f" at {_budget_text(budget)}" if per_task and budget is not None else "")
        lines += [heading, "", "| latent | seeds | " + " | ".join(k.split("/")[-1] for k in keys) + " |"]
        lines.append("|---|---|" + "---|" * len(keys))
        for latent, g in rows.items():
            cells = []
            for k in keys:
                f = g["final"].get(k)
                cells.append("-" if f is None else f"{f['mean']:.3g} ± {f['std']:.2g}" if f["n"] > 1 else f"{f['mean']:.3g}")
            lines.append(f"| {latent} | {len(g['seeds'])} | " + " | ".join(cells) + " |")
        lines.append("")
        evaluated = {latent: g for latent, g in rows.items() if g.get("task_eval")}
        if evaluated:
            any_eval = next(iter(evaluated.values()))["task_eval"]
            skip = {"steps", "env_steps", "num_envs", "seconds"}
            ekeys = [k for k in any_eval if k not in skip]
            n_env, secs = int(any_eval["num_envs"]["mean"]), any_eval["seconds"]["mean"]
            starts = "" if start_clips is None else f", episodes start from {', '.join(start_clips)}"
            lines += [f"Deterministic policy (`mocap task-eval`, mean action, {n_env} envs x {secs:.3g} s{starts}):", ""]
            lines += ["| latent | seeds | " + " | ".join(ekeys) + " |", "|---|---|" + "---|" * len(ekeys)]
            for latent, g in evaluated.items():
                vals = [g["task_eval"].get(k) for k in ekeys]
                cells = ["-" if f is None else f"{f['mean']:.3g} ± {f['std']:.2g}" if f["n"] > 1 else f"{f['mean']:.3g}" for f in vals]
                lines.append(f"| {latent} | {g['task_eval']['num_envs']['n']} | " + " | ".join(cells) + " |")
            lines.append("")
    return "\n".join(lines + summary_lines(groups))


#: primary metrics where a smaller value is better (the others: larger is better)
LOWER_IS_BETTER = {"speed_error"}


def summary(groups: dict) -> dict[str, dict]:
    """Per task: its primary metric (``PRIMARY``) per latent space as {mean, std, n, source}, taken from the
    deterministic evaluation when every latent space of the task has one, else from the training
    episodes, and ``best``, the latent space with the best mean (None without a primary metric)."""
    out: dict[str, dict] = {}
    for task in sorted({name.split("/")[0] for name in groups}):
        key = PRIMARY.get(task)
        if key is None:
            continue
        rows = {name.split("/")[1]: g for name, g in groups.items() if name.split("/")[0] == task}
        metric = key.split("/")[-1]
        source = "deterministic" if all(metric in g.get("task_eval", {}) for g in rows.values()) else "training"
        values = {}
        for latent, g in sorted(rows.items()):
            v = g["task_eval"].get(metric) if source == "deterministic" else g["final"].get(key)
            if v is not None:
                values[latent] = {**v, "source": source}
        sign = -1.0 if metric in LOWER_IS_BETTER else 1.0
        best = max(values, key=lambda latent: sign * values[latent]["mean"]) if values else None
        out[task] = {"metric": metric, "lower_is_better": metric in LOWER_IS_BETTER, "values": values, "best": best}
    return out


def summary_lines(groups: dict) -> list[str]:
    table = summary(groups)
    if not table:
        return []
    lines = ["## Summary: each task's primary metric", ""]
    lines += ["| task | metric | " + " | ".join(["latent: mean ± std (seeds, source)", "best"]) + " |", "|---|---|---|---|"]
    for task, t in table.items():
        better = "lower is better" if t["lower_is_better"] else "higher is better"
        cells = "; ".join(f"{latent}: {v['mean']:.3g} ± {v['std']:.2g} ({v['n']}, {v['source']})" for latent, v in t["values"].items())
        lines.append(f"| {task} | {t['metric']} ({better}) | {cells} | {t['best']} |")
    return [*lines, ""]


def _std(v: list[float]) -> float:
    if len(v) < 2:
        return 0.0
    m = sum(v) / len(v)
    return (sum((x - m) ** 2 for x in v) / (len(v) - 1)) ** 0.5


def _plot(cells: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    tasks = sorted({c["task"] for c in cells.values()})
    latents = sorted({c["latent"] for c in cells.values()})
    fig, axes = plt.subplots(3, len(tasks), figsize=(5 * len(tasks), 10), squeeze=False)
    for col, task in enumerate(tasks):
        for latent in latents:
            runs = [c for c in cells.values() if c["task"] == task and c["latent"] == latent]
            if not runs:
                continue
            for row, key in enumerate(("episode/normalized_return", "episode/length", PRIMARY.get(task, ""))):
                if not any(key in point for r in runs for point in r["curve"]):
                    continue
                n = min(len(r["curve"]) for r in runs)
                x = np.array([runs[0]["curve"][i]["env_steps"] for i in range(n)]) / 1e6
                y = np.array([[r["curve"][i].get(key, np.nan) for i in range(n)] for r in runs], dtype=float)
                if np.isnan(y).all(0).any():  # points where no seed logged the metric: not drawn
                    x, y = x[~np.isnan(y).all(0)], y[:, ~np.isnan(y).all(0)]
                if not y.size:
                    continue
                ax = axes[row][col]
                color = f"C{latents.index(latent) % 10}"  # one colour per latent space in every panel
                (line,) = ax.plot(x, np.nanmean(y, 0), color=color, label=f"{latent} ({len(runs)} seed{'s' * (len(runs) > 1)})")
                if len(runs) > 1:
                    ax.fill_between(x, np.nanmin(y, 0), np.nanmax(y, 0), color=line.get_color(), alpha=0.2)
        axes[0][col].set_title(task)
        axes[0][col].set_ylabel("normalized return (training episodes)")
        axes[1][col].set_ylabel("episode length (steps)")
        axes[2][col].set_ylabel(f"{PRIMARY.get(task, '-').split('/')[-1]} (training episodes)")
        for row in range(3):
            axes[row][col].set_xlabel("env steps (M)")
            if axes[row][col].get_legend_handles_labels()[0]:
                axes[row][col].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _split_clips(text: str) -> list[str]:
    from mocap.task_eval import split_clips

    return split_clips(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="train every task x latent x seed cell")
    p.add_argument("--tasks", nargs="+", default=["speed", "reach", "strike"])
    p.add_argument("--latents", nargs="+", default=["scratch", "pulse", "hybrid_rvq", "vmp"])
    p.add_argument("--seeds", nargs="+", type=int, default=[0])
    p.add_argument("--steps", type=int, default=500_000)
    p.add_argument("--suffix", default="", help="spec name suffix: specs/tasks/<task>_<latent><suffix>.yaml (e.g. _v15)")
    p.add_argument("--out", type=Path, required=True)
    c = sub.add_parser("collect", help="gather curves and final metrics into JSON and a plot")
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--json", type=Path, default=Path("bench/results/task_compare"))
    c.add_argument("--include-unfinished", action="store_true", help="also tabulate cells whose task stage was stopped (training curve only)")
    c.add_argument("--task-eval", type=int, default=0, help="also evaluate each cell's deterministic policy with this many envs (0: no)")
    c.add_argument("--task-eval-seconds", type=float, default=10.0, help="simulated seconds per env of --task-eval")
    c.add_argument(
        "--task-eval-start-clips",
        type=_split_clips,
        default=None,
        help="comma-separated clips the --task-eval episodes start from (default: each run's motion set)",
    )
    c.add_argument(
        "--at-steps",
        action="append",
        default=None,
        help="compare every cell at this many env steps (its curve cut there); TASK=N for one task's budget (repeatable)",
    )
    c.add_argument(
        "--merge",
        type=Path,
        default=None,
        help="keep the cells of this earlier collect JSON (same budgets) that are not collected again, e.g. when their run directories are gone",
    )
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # recorded as the JSON's command
    return run(args) if args.command == "run" else collect(args)


if __name__ == "__main__":
    raise SystemExit(main())
