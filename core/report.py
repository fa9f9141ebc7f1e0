"""``report.md`` of a run: the spec, what each stage did, its metrics, versions, hardware, wall-clock,
and PNG plots of its learning curves.

Plots (matplotlib, Agg canvas, no display; optional: without matplotlib the report says so):

* ``learning_curves.png`` in a run directory: per stage (one row each) the curves of
  :data:`CURVE_KEYS` that the stage logged to ``metrics.jsonl`` (x = ``env_steps``, else ``step``);
* for a comparison (:mod:`mocap.matrix`), ``comparison_curves.png``: per cell group the mean curve
  over its seeds with a band of ± one std (:func:`seed_band`: every seed's curve linearly
  interpolated onto the union of their x values inside the x range all seeds cover; std over seeds
  with ddof 0, as in ``comparison.json``), and ``comparison_final.png``: the final metrics as bars
  with ± std error bars.
"""

from __future__ import annotations

import json
import math
import platform
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence, TypeGuard

from mocap.checkpoint import atomic_write_text, hardware, package_versions
from mocap.metric_display import metric_label
from mocap.runfiles import read_stages

if TYPE_CHECKING:  # pragma: no cover
    from mocap.matrix import MetricSummary
    from mocap.pipeline import StageRecord
    from mocap.spec import ResolvedSpec


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


#: metric names printed at the end of a run, in this order (those a run has)
HEADLINE = ("succeeded", "success_rate", "mpjpe_g_succ", "mpjpe_g", "fall_rate", "time_to_fall_s", "normalized_return", "speed_error")


def headline(records: list["StageRecord"], limit: int = 6) -> list[str]:
    """The run's headline numbers as ``"eval: MPJPE-g (tracked) (mm) 87"`` lines (at most ``limit``)."""
    from mocap.metric_display import metric_label

    out: list[str] = []
    for name in HEADLINE:
        for r in records:
            for key, value in (r.result.metrics or {}).items():
                if key.split("/")[-1] == name and isinstance(value, (int, float)):
                    out.append(f"{r.stage}: {metric_label(key)} {value:.4g}")
    return out[:limit]


def _reused_note(records: list["StageRecord"]) -> str:
    """``" (2 stages reused from earlier runs; their training took 1234.5 s)"`` or ""."""
    reused = [r for r in records if r.reused and getattr(r, "trained_seconds", None) is not None]
    if not reused:
        return ""
    total = sum(float(r.trained_seconds or 0.0) for r in reused)
    what = "1 stage" if len(reused) == 1 else f"{len(reused)} stages"
    return f" ({what} reused from earlier runs; their training took {total:.1f} s)"


def render_report(
    resolved: "ResolvedSpec", records: list["StageRecord"], wall_seconds: float, out_dir: Path | None = None, plot_note: str | None = None
) -> str:
    spec = resolved.spec
    lines = [f"# {spec.name}", ""]
    if spec.description:
        lines += [spec.description, ""]
    lines += [
        f"- spec: `{resolved.source}` (resolved copy: `spec.yaml`)",
        f"- humanoid `{spec.humanoid.name}`, motions `{spec.motions.name}`, simulator `{spec.simulator.name}`, seed {spec.seed}",
        f"- wall-clock of this run: {wall_seconds:.1f} s" + _reused_note(records),
        "",
        "## Stages",
        "",
        "| stage | component | trainer | artifact | reused | seconds (this run) | training time |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in records:
        section = getattr(spec, r.stage)
        component = getattr(section, "name", "-")
        trainer = section.trainer.name if getattr(section, "trainer", None) is not None else "-"
        trained = r.trained_seconds if r.reused else (r.seconds if trainer != "-" else None)
        shown = f"{trained:.1f} s" if trained is not None else "-"
        lines.append(f"| {r.stage} | {component} | {trainer} | `{r.workdir.name}` | {'yes' if r.reused else 'no'} | {r.seconds:.1f} | {shown} |")
    retrained = [r for r in records if r.why]
    if retrained:
        lines += [""] + [f"- {r.stage} trained again: {r.why}" for r in retrained]
    for r in records:
        if not r.result.metrics:
            continue
        lines += ["", f"## {r.stage} metrics", "", "| metric | key | value |", "|---|---|---|"]
        lines += [f"| {metric_label(k)} | `{k}` | {_fmt(v)} |" for k, v in sorted(r.result.metrics.items())]
    if out_dir is not None and (Path(out_dir) / LEARNING_CURVES).is_file():
        lines += ["", "## Learning curves", "", f"![learning curves]({LEARNING_CURVES})"]
    elif plot_note:
        lines += ["", "## Learning curves", "", plot_note]
    if out_dir is not None:
        for table in sorted(Path(out_dir).glob("*.md")):
            if table.name != "report.md":  # stage tables (e.g. imitation_eval.md), one level down in headings
                body = table.read_text(encoding="utf-8").strip().splitlines()
                lines += ["", *[("#" + line) if line.startswith("#") else line for line in body]]
        media = sorted(p.name for p in Path(out_dir).iterdir() if p.suffix in (".mp4", ".gif", ".png") and p.name != LEARNING_CURVES)
        if media:
            lines += ["", "## Videos and plots", "", *[f"- [{name}]({name})" for name in media]]
    versions = package_versions()
    hw = hardware()
    lines += [
        "",
        "## Environment",
        "",
        "| | |",
        "|---|---|",
        *[f"| {k} | {v} |" for k, v in versions.items()],
        *[f"| {k} | {v} |" for k, v in hw.items()],
        f"| node | {platform.node()} |",
        "",
    ]
    return "\n".join(lines)


def write_report(out_dir: Path, resolved: "ResolvedSpec", records: list["StageRecord"], wall_seconds: float) -> Path:
    path = Path(out_dir) / "report.md"
    note = None
    try:
        write_learning_curves(Path(out_dir) / "metrics.jsonl", Path(out_dir) / LEARNING_CURVES)
    except PlotsUnavailable as exc:
        note = str(exc)
    except Exception as exc:  # noqa: BLE001 - a plot must never fail a finished run
        note = f"plots skipped: {type(exc).__name__}: {exc}"
    atomic_write_text(path, render_report(resolved, records, wall_seconds, out_dir, plot_note=note))
    return path


# ------------------------------------------------------------------------------------ plots
LEARNING_CURVES = "learning_curves.png"
COMPARISON_CURVES = "comparison_curves.png"
COMPARISON_FINAL = "comparison_final.png"

#: metrics drawn as learning curves, when a stage logs them (the loss: the first of LOSS_KEYS it logs)
CURVE_KEYS = ("episode/return", "episode/normalized_return", "episode/success")
LOSS_KEYS = ("loss/total", "loss", "loss/action", "loss/policy")


class PlotsUnavailable(RuntimeError):
    """matplotlib is not installed: plots are skipped (the message says so and how to get them)."""


def _figure(width: float, height: float) -> Any:
    """A matplotlib Figure on an Agg canvas (no pyplot, no global backend, no display)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise PlotsUnavailable("plots skipped: matplotlib is not installed (pip install matplotlib)") from None
    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """The records of a ``metrics.jsonl`` (lines cut by a crash are skipped; missing file: [])."""
    path = Path(path)
    if not path.is_file():
        return []
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(rec, dict):
            out.append(rec)
    return out


def _finite(v: Any) -> TypeGuard[float]:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))


def learning_curves(records: list[dict[str, Any]]) -> dict[str, dict[str, tuple[list[float], list[float]]]]:
    """stage -> metric -> (x, y) of the :data:`CURVE_KEYS` and the stage's loss (first of
    :data:`LOSS_KEYS`), x = ``env_steps`` (else ``step``); only curves with at least two points."""
    by_stage: dict[str, list[dict[str, Any]]] = {}
    for rec in records:
        by_stage.setdefault(str(rec.get("stage", "?")), []).append(rec)
    out: dict[str, dict[str, tuple[list[float], list[float]]]] = {}
    for stage, recs in by_stage.items():
        logged = set().union(*(r.keys() for r in recs))
        loss = next((k for k in LOSS_KEYS if k in logged), None)
        curves: dict[str, tuple[list[float], list[float]]] = {}
        for key in [*(k for k in CURVE_KEYS if k in logged), *([loss] if loss else [])]:
            xs, ys = [], []
            for r in recs:
                x = r.get("env_steps", r.get("step"))
                if _finite(x) and _finite(r.get(key)):
                    xs.append(float(x))
                    ys.append(float(r[key]))
            if len(xs) >= 2:
                order = sorted(range(len(xs)), key=xs.__getitem__)
                curves[key] = ([xs[i] for i in order], [ys[i] for i in order])
        if curves:
            out[stage] = curves
    return out


def _x_label(records: list[dict[str, Any]]) -> str:
    return "env steps" if any("env_steps" in r for r in records) else "step"


def write_learning_curves(metrics_path: Path, out_path: Path) -> Path | None:
    """``learning_curves.png`` of a run (one row per stage); None when nothing has two points.

    Raises :class:`PlotsUnavailable` without matplotlib."""
    records = read_metrics(metrics_path)
    curves = learning_curves(records)
    if not curves:
        return None
    cols = max(len(c) for c in curves.values())
    fig = _figure(4.0 * cols, 2.8 * len(curves))
    for row, (stage, metrics) in enumerate(curves.items()):
        for col, (key, (xs, ys)) in enumerate(metrics.items()):
            ax = fig.add_subplot(len(curves), cols, row * cols + col + 1)
            ax.plot(xs, ys, lw=1.2)
            ax.set_title(f"{stage}: {key}", fontsize=9)
            ax.set_xlabel(_x_label(records), fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
    fig.tight_layout()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, format="png")
    return out_path


def seed_band(series: Sequence[tuple[Sequence[float], Sequence[float]]]) -> tuple[list[float], list[float], list[float]]:
    """Mean and std over seeds of curves with possibly different x values.

    Every curve ``(x, y)`` (x increasing) is linearly interpolated onto the union of all curves' x
    values inside ``[max of the first x, min of the last x]`` (the range every seed covers); returns
    ``(x, mean, std)`` with the std over seeds of ddof 0 (0 for a single seed). Empty lists when the
    curves do not overlap."""
    import numpy as np

    curves = [(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)) for x, y in series if len(x)]
    if not curves:
        return [], [], []
    lo = max(float(x[0]) for x, _ in curves)
    hi = min(float(x[-1]) for x, _ in curves)
    if lo > hi:
        return [], [], []
    grid = np.unique(np.concatenate([x[(x >= lo) & (x <= hi)] for x, _ in curves]))
    ys = np.stack([np.interp(grid, x, y) for x, y in curves])
    return grid.tolist(), ys.mean(0).tolist(), ys.std(0).tolist()


def write_comparison_plots(groups: dict[str, list[Path]], summary: dict[str, dict[str, MetricSummary]], metrics: Sequence[str], out_dir: Path) -> list[Path]:
    """``comparison_curves.png`` (per group: mean ± std over its cells' seeds of every learning
    curve) and ``comparison_final.png`` (``metrics`` of ``summary`` as bars with std error bars).

    Args:
        groups: group label -> the run directories of its cells (one per seed).
        summary: group label -> metric -> {"mean", "std", "n"} (``comparison.json``'s ``groups``).
        metrics: the final metrics to draw as bars.
    Raises :class:`PlotsUnavailable` without matplotlib. Returns the files written."""
    written: list[Path] = []
    per_group: dict[str, list[dict[str, dict[str, tuple[list[float], list[float]]]]]] = {
        g: [learning_curves(read_metrics(Path(d) / "metrics.jsonl")) for d in dirs] for g, dirs in groups.items()
    }
    panels: list[tuple[str, str]] = []
    for runs in per_group.values():
        for curves in runs:
            for stage, keys in curves.items():
                panels += [(stage, k) for k in keys if (stage, k) not in panels]
    if panels:
        cols = min(3, len(panels))
        rows = math.ceil(len(panels) / cols)
        fig = _figure(4.5 * cols, 3.0 * rows + 0.5)
        handles: dict[str, Any] = {}
        for i, (stage, key) in enumerate(panels):
            ax = fig.add_subplot(rows, cols, i + 1)
            for gi, (g, runs) in enumerate(per_group.items()):
                series = [c[stage][key] for c in runs if stage in c and key in c[stage]]
                x, mean, std = seed_band(series)
                if not x:
                    continue
                color = f"C{gi % 10}"  # one colour per group in every panel
                (line,) = ax.plot(x, mean, lw=1.2, color=color)
                handles.setdefault(g, line)
                lower = [m - s for m, s in zip(mean, std)]
                upper = [m + s for m, s in zip(mean, std)]
                ax.fill_between(x, lower, upper, color=color, alpha=0.2, lw=0)
            ax.set_title(f"{stage}: {key}", fontsize=9)
            ax.set_xlabel("env steps", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        labels = [f"{g} (n={len(per_group[g])})" for g in handles]
        fig.legend(list(handles.values()), labels, loc="upper center", ncol=min(4, max(1, len(labels))), fontsize=8, frameon=False)
        fig.tight_layout(rect=(0, 0, 1, 1 - 0.45 / (3.0 * rows + 0.5)))
        path = Path(out_dir) / COMPARISON_CURVES
        fig.savefig(path, format="png")
        written.append(path)
    bars = [m for m in metrics if any(m in s for s in summary.values())]
    if bars:
        cols = min(3, len(bars))
        rows = math.ceil(len(bars) / cols)
        labels = list(summary)
        fig = _figure(max(4.5, 1.2 * len(labels)) * cols, 3.2 * rows)
        for i, m in enumerate(bars):
            ax = fig.add_subplot(rows, cols, i + 1)
            means = [summary[g][m]["mean"] if m in summary[g] else float("nan") for g in labels]
            # a 95% interval of the mean where a group has several seeds; no error bar for a single run
            half = [summary[g][m].get("ci95") if m in summary[g] else None for g in labels]
            yerr = [h if h is not None else 0.0 for h in half] if any(h is not None for h in half) else None
            ax.bar(range(len(labels)), means, yerr=yerr, capsize=4, color=[f"C{j % 10}" for j in range(len(labels))])
            ax.set_xticks(range(len(labels)))
            ax.set_xticklabels(labels, rotation=20, ha="right", fontsize=7)
            ax.set_title(metric_label(m), fontsize=9)
            ax.tick_params(axis="y", labelsize=7)
            ax.grid(axis="y", alpha=0.3)
        fig.tight_layout()
        path = Path(out_dir) / COMPARISON_FINAL
        fig.savefig(path, format="png")
        written.append(path)
    return written


# ------------------------------------------------------------------------------ mocap report
def rebuild_report(run_dir: Path) -> list[Path]:
    """Rewrite the reports of ``run_dir`` from what it holds: ``report.md`` (+ learning curves) of a
    run directory (``spec.yaml`` + ``stages.json``), and ``comparison.md`` (+ plots) of a comparison
    directory (``comparison.json``: its cells' runs are below it). Returns the files written."""
    from mocap.errors import UserError

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserError(f"{run_dir}: not a directory (give a run directory, e.g. runs/<name> or runs/<name>/<cell>)")
    written: list[Path] = []
    comparison_file = run_dir / "comparison.json"
    if comparison_file.is_file():
        from mocap.matrix import Cell, comparison

        data = json.loads(comparison_file.read_text(encoding="utf-8"))
        cells = [Cell(name, dict(row.get("labels") or {}), {}) for name, row in data.get("cells", {}).items()]
        for cell in cells:
            if (run_dir / cell.name / "stages.json").is_file():
                written += rebuild_report(run_dir / cell.name)
        comparison(cells, run_dir)
        written.append(run_dir / "comparison.md")
    elif (run_dir / "stages.json").is_file() and (run_dir / "spec.yaml").is_file():
        from mocap.interfaces import StageResult
        from mocap.pipeline import StageRecord
        from mocap.plugins import get_plugins
        from mocap.spec import load_spec

        resolved = load_spec(run_dir / "spec.yaml", get_plugins())
        records = []
        for s in read_stages(run_dir / "stages.json"):
            ckpt = s.get("checkpoint")
            result = StageResult(checkpoint=Path(ckpt) if ckpt else None, metrics=dict(s.get("metrics") or {}))
            records.append(
                StageRecord(s["stage"], s.get("key", ""), Path(s.get("artifact_dir", "")), result, bool(s.get("reused")), float(s.get("seconds", 0.0)))
            )
        written.append(write_report(run_dir, resolved, records, wall_seconds=sum(r.seconds for r in records)))
    else:
        raise UserError(f"{run_dir}: neither a run directory (spec.yaml + stages.json) nor a comparison (comparison.json)")
    return written


def report_command(
    run_dir: Path,
) -> None:
    """Rewrite report.md (and its plots) of a run directory, or comparison.md of a comparison."""
    for path in rebuild_report(run_dir):
        print(f"wrote {path}")
