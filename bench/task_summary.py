"""One table of the downstream tasks across ``bench/task_compare.py collect`` JSONs.

Each column is an action space taken from one JSON (a latent label of its groups; the first of several labels that
the JSON has for a task, so that ``pulse,pulse_far_reward`` picks reach's wide-reward cells). Per task and column: the
deterministic policy's primary metric (``task_compare.PRIMARY``: speed error, reach and point_goal success, strike
hits) as mean ± std over the seeds that have one, the env-step budget, and for reach and point_goal the closest
approach per target. ``--versus A:B`` adds, per task, whether column A beats column B: ``yes`` when A's mean is
better at the same budget (within 2%), ``no`` when it is not better with at least B's budget, else ``not
comparable``. The PULSE paper's Fig. 4 claim is that PULSE beats scratch on 3 of 4 of its tasks.

    python bench/task_summary.py --column scratch=bench/results/task_compare.json:scratch \\
        --column PULSE=bench/results/task_compare_v20.json:pulse,pulse_far_reward \\
        --versus PULSE:scratch --out bench/results/task_summary

writes ``task_summary.md`` and ``task_summary.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from task_compare import LOWER_IS_BETTER, PRIMARY  # noqa: E402

TASKS = ("speed", "reach", "strike", "point_goal")
#: the second number shown for tasks whose success rate hides how close the policy came
CLOSEST = {"reach": "closest_distance", "point_goal": "closest_distance"}
#: budgets within this fraction of each other count as equal
BUDGET_TOLERANCE = 0.02


def parse_column(text: str) -> tuple[str, Path, list[str]]:
    """``LABEL=JSON:LATENT[,LATENT...]`` -> (label, path, latents); ValueError on another shape."""
    label, sep, rest = text.partition("=")
    path, sep2, latents = rest.rpartition(":")
    names = [n.strip() for n in latents.split(",") if n.strip()]
    if not sep or not sep2 or not label.strip() or not path or not names:
        raise ValueError(f"--column {text!r}: expected LABEL=JSON:LATENT[,LATENT...]")
    return label.strip(), Path(path), names


def pick_group(groups: dict, task: str, latents: list[str]) -> tuple[str, dict] | None:
    """The first of ``latents`` that ``groups`` has for ``task`` (keys ``task/latent``), with its group."""
    for latent in latents:
        group = groups.get(f"{task}/{latent}")
        if group is not None:
            return latent, group
    return None


def cell(groups: dict, task: str, latents: list[str]) -> dict | None:
    """What the table shows for one task and column: the latent label used, its primary metric from the
    deterministic evaluation ({mean, std, n}), its budget in env steps and the closest approach (None for a task
    without it). None when the JSON has no group for the task or the group has no deterministic evaluation."""
    found = pick_group(groups, task, latents)
    if found is None:
        return None
    latent, group = found
    metric = PRIMARY[task].split("/")[-1]
    value = group.get("task_eval", {}).get(metric)
    if value is None:
        return None
    closest = group["task_eval"].get(CLOSEST[task]) if task in CLOSEST else None
    return {"latent": latent, "metric": metric, "value": value, "env_steps": group["final"]["env_steps"]["mean"], "closest": closest}


def verdict(a: dict | None, b: dict | None) -> str:
    """Whether cell ``a`` beats cell ``b`` on their primary metric: yes / no / not comparable (see the module text)."""
    if a is None or b is None:
        return "not comparable"
    sign = -1.0 if a["metric"] in LOWER_IS_BETTER else 1.0
    better = sign * (a["value"]["mean"] - b["value"]["mean"]) > 0
    same_budget = abs(a["env_steps"] - b["env_steps"]) <= BUDGET_TOLERANCE * max(a["env_steps"], b["env_steps"])
    if better and same_budget:
        return "yes"
    if not better and (same_budget or a["env_steps"] >= b["env_steps"]):
        return "no"
    return "not comparable"


def _fmt(c: dict | None) -> str:
    if c is None:
        return "-"
    v, pct = c["value"], c["metric"] != "speed_error"
    scale, unit = (100.0, "%") if pct else (1.0, " m/s")
    seeds = "1 seed" if v["n"] == 1 else f"{v['n']} seeds"
    spread = "" if v["n"] == 1 else f" ± {scale * v['std']:.2g}"
    text = f"{scale * v['mean']:.3g}{spread}{unit} ({seeds}, {c['env_steps'] / 1e6:.0f}M)"
    if c["closest"] is not None:
        text += f"; closest {c['closest']['mean']:.2f} m"
    return text


def build(columns: list[tuple[str, Path, list[str]]], versus: list[tuple[str, str]]) -> dict:
    tables = {}
    for label, path, _latents in columns:
        try:
            tables[label] = json.loads(path.read_text())["groups"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: not a task_compare JSON ({type(exc).__name__}: {exc})") from None
    rows = {task: {label: cell(tables[label], task, latents) for label, _, latents in columns} for task in TASKS}
    labels = {label for label, _, _ in columns}
    for a, b in versus:
        if a not in labels or b not in labels:
            raise ValueError(f"--versus {a}:{b}: both must be column labels ({', '.join(sorted(labels))})")
    verdicts = {f"{a} beats {b}": {task: verdict(rows[task][a], rows[task][b]) for task in TASKS} for a, b in versus}
    return {"columns": [{"label": lab, "json": str(p), "latents": ls} for lab, p, ls in columns], "rows": rows, "verdicts": verdicts}


def markdown(result: dict) -> str:
    labels = [c["label"] for c in result["columns"]]
    lines = [
        "# Downstream tasks: the deterministic policy (`mocap task-eval`, 64 envs x 10 s), mean ± std over seeds",
        "",
        "Primary metric per task: speed error (lower is better), targets reached (reach: hand within 0.1 m), "
        "targets knocked over (strike), goals reached (point_goal); closest: the closest approach per target.",
        "",
        "| task | " + " | ".join(labels) + "".join(f" | {name}" for name in result["verdicts"]) + " |",
        "|---" * (1 + len(labels) + len(result["verdicts"])) + "|",
    ]
    for task, row in result["rows"].items():
        verdicts = "".join(f" | {v[task]}" for v in result["verdicts"].values())
        lines.append(f"| {task} | " + " | ".join(_fmt(row[label]) for label in labels) + verdicts + " |")
    lines += ["", "Sources: " + "; ".join(f"{c['label']}: `{c['json']}` ({', '.join(c['latents'])})" for c in result["columns"]), ""]
    for name, v in result["verdicts"].items():
        wins = sum(1 for x in v.values() if x == "yes")
        lines.append(f"{name} on {wins} of {len(v)} tasks.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--column", action="append", required=True, help="LABEL=JSON:LATENT[,LATENT...] (repeatable)")
    parser.add_argument("--versus", action="append", default=[], help="A:B, column labels: does A beat B per task")
    parser.add_argument("--out", type=Path, required=True, help="output stem: writes OUT.md and OUT.json")
    args = parser.parse_args(argv)
    try:
        columns = [parse_column(text) for text in args.column]
        versus = []
        for text in args.versus:
            a, sep, b = text.partition(":")
            if not sep:
                raise ValueError(f"--versus {text!r}: expected A:B")
            versus.append((a.strip(), b.strip()))
        result = build(columns, versus)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    result["command"] = " ".join(["python", "bench/task_summary.py", *(argv if argv is not None else sys.argv[1:])])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    text = markdown(result)
    args.out.with_suffix(".md").write_text(text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
