"""Sample efficiency of the cells of a comparison (issue 61 item 2; PULSE Fig. 4, where a policy in a
latent space "converges faster"): per cell and seed, from the learning curve a stage logged in its
run's ``metrics.jsonl`` (default: the task stage's ``episode/normalized_return`` against
``env_steps``):

* ``steps_to_50`` / ``steps_to_80``: the first env-step count at which the curve's trailing mean over
  ``window`` logged points reaches 50% / 80% of the **best final value among all cells** (a cell's
  final value: the mean of its seeds' last ``window`` points), or None when it never does;
* ``auc``: the area under the curve up to a common budget (the fewest env steps any run logged),
  divided by that budget: the mean normalized return over training (trapezoids between logged points;
  the curve is held at its first value before its first point).

:func:`efficiency` aggregates them per cell: means, 95% bootstrap intervals over seeds (percentiles of
the resampled means, :func:`mocap.intervals.bootstrap_mean`) and, for the thresholds, how many seeds reached them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from mocap.intervals import bootstrap_mean

Curve = tuple[np.ndarray, np.ndarray]  # (env_steps, values), increasing steps


def read_curve(metrics_file: Path, stage: str = "task", key: str = "episode/normalized_return") -> Curve:
    """``(env_steps, value)`` of one stage's rows that carry ``key`` (rows cut by a crash are skipped)."""
    steps, values = [], []
    try:
        lines = Path(metrics_file).read_text(encoding="utf-8").splitlines()
    except OSError:
        lines = []
    for line in lines:
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if isinstance(row, dict) and row.get("stage") == stage and isinstance(row.get(key), (int, float)) and isinstance(row.get("env_steps"), (int, float)):
            if math.isfinite(float(row[key])):
                steps.append(float(row["env_steps"]))
                values.append(float(row[key]))
    order = np.argsort(np.asarray(steps), kind="stable")
    return np.asarray(steps)[order], np.asarray(values)[order]


def trailing_mean(values: np.ndarray, window: int) -> np.ndarray:
    """Mean of each point and the ``window - 1`` before it (fewer at the start)."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    c = np.cumsum(np.concatenate([[0.0], values]))
    idx = np.arange(1, len(values) + 1)
    lo = np.maximum(idx - window, 0)
    return (c[idx] - c[lo]) / (idx - lo)


def final_value(curve: Curve, window: int = 5) -> float:
    """Mean of the last ``window`` points (NaN for an empty curve)."""
    return float(np.mean(curve[1][-window:])) if len(curve[1]) else math.nan


def steps_to(curve: Curve, target: float, window: int = 5) -> float | None:
    """First env steps at which the trailing mean reaches ``target``; None if it never does."""
    steps, values = curve
    if not len(values):
        return None
    hit = np.nonzero(trailing_mean(values, window) >= target)[0]
    return float(steps[hit[0]]) if len(hit) else None


def auc(curve: Curve, budget: float) -> float:
    """Area under the curve on [0, budget] divided by budget (the curve held at its first value
    before its first point and at its last after its last; NaN for an empty curve)."""
    steps, values = curve
    if not len(values) or not budget > 0:
        return math.nan
    xs = np.concatenate([[0.0], steps[steps < budget], [budget]])
    ys = np.interp(xs, steps, values)  # held constant outside the logged range
    return float(np.trapezoid(ys, xs) / budget)


def efficiency(curves: dict[str, list[Curve]], window: int = 5, fractions: tuple[float, ...] = (0.5, 0.8)) -> dict[str, Any]:
    """Per cell (name -> one curve per seed): the module docstring's quantities. Returns
    ``{"best_final", "budget", "cells": {cell: {"final", "auc", "steps_to_50", ...}}}``, each an entry
    ``{"mean", "ci95": [lo, hi] | None, "n", "reached"}`` (``reached`` for thresholds only)."""
    finals = {c: float(np.mean([final_value(k, window) for k in ks])) for c, ks in curves.items() if ks}
    best = max((v for v in finals.values() if math.isfinite(v)), default=math.nan)
    lengths = [k[0][-1] for ks in curves.values() for k in ks if len(k[0])]
    budget = float(min(lengths)) if lengths else math.nan
    out: dict[str, Any] = {"best_final": best, "budget": budget, "window": window, "cells": {}}
    for cell, ks in curves.items():
        row: dict[str, Any] = {}
        row["final"] = _entry([final_value(k, window) for k in ks])
        row["auc"] = _entry([auc(k, budget) for k in ks])
        for f in fractions:
            hits = [steps_to(k, f * best, window) if math.isfinite(best) else None for k in ks]
            reached = [h for h in hits if h is not None]
            row[f"steps_to_{round(100 * f)}"] = {**_entry(reached), "reached": len(reached), "n": len(ks)}
        out["cells"][cell] = row
    return out


def _entry(values: list[float]) -> dict[str, Any]:
    vals = [v for v in values if math.isfinite(v)]
    return {"mean": float(np.mean(vals)) if vals else math.nan, "ci95": bootstrap_mean(vals), "n": len(vals)}


def render_efficiency(table: dict[str, Any]) -> str:
    """A Markdown section of :func:`efficiency` (steps in millions)."""
    if not table["cells"]:
        return ""
    keys = [k for k in next(iter(table["cells"].values())) if k.startswith("steps_to_")]
    head = ["cell", "final", "AUC", *[f"M steps to {k.removeprefix('steps_to_')}%" for k in keys]]
    lines = [
        "",
        "## Sample efficiency",
        "",
        f"Normalized return: steps to a share of the best final value among the cells ({table['best_final']:.3g}; trailing mean "
        f"of {table['window']} logged points); AUC: the mean over the first {table['budget'] / 1e6:.3g}M env steps. Mean over seeds "
        "[95% bootstrap interval]; a threshold some seeds never reached says how many did.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for cell, row in table["cells"].items():
        cells = [_show(row["final"]), _show(row["auc"])]
        for k in keys:
            e = row[k]
            if e["reached"] == 0:
                cells.append(f"never (0/{e['n']})")
            else:
                text = _show(e, scale=1e-6)
                cells.append(text if e["reached"] == e["n"] else f"{text} ({e['reached']}/{e['n']} reached)")
        lines.append("| " + " | ".join([cell, *cells]) + " |")
    return "\n".join(lines) + "\n"


def _show(e: dict[str, Any], scale: float = 1.0) -> str:
    if not math.isfinite(e["mean"]):
        return "-"
    text = f"{e['mean'] * scale:.3g}"
    if e.get("ci95"):
        lo, hi = e["ci95"]
        text += f" [{lo * scale:.3g}, {hi * scale:.3g}]"
    return text


__all__ = ["auc", "efficiency", "final_value", "read_curve", "render_efficiency", "steps_to", "trailing_mean"]
