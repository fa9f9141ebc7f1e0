"""Comparison specs: a ``matrix:`` of spec fields that ``mocap run`` expands into one run per cell.

A spec may carry, next to its usual fields::

    matrix:
      latent:                      # a dotted field path -> the values it takes
        - {name: scratch}
        - {name: pulse, params: {...}, checkpoint: ../../checkpoints/pulse_amp/latent.pt}
      task.name: [speed, reach]
      seed: [0, 1, 2]

Each cell is the spec with every path set to one of its values (the cartesian product; a value
replaces what is at the path, like ``--set``; relative ``checkpoint:`` paths inside values are
relative to the spec file). An axis may set several paths together (a *zipped* axis): its key
joins the paths with commas and each value is a list with one entry per path, e.g. a latent space
with the task policy trained through it::

      latent, task.checkpoint:
        - [{name: scratch}, ../checkpoints/speed_scratch/task_policy.pt]
        - [{name: pulse, checkpoint: ...}, ../checkpoints/speed_pulse/task_policy.pt]

A zipped value is labelled by its first entry. Cells run one after another, or ``--jobs K`` at a time in separate
processes, under ``runs/<name>/<cell>/`` with one artifact store ``runs/<name>/artifacts``, so a
stage that several cells share (the same section and upstream) is trained once: a per-artifact
lock makes parallel cells wait for each other instead of training it twice.

``--executor ray`` runs the same per-cell command (``python -m mocap.cli run <cell>/cell.yaml``) as a
Ray task instead of a local process (optional extra ``mocap[ray]``): on a local Ray instance by
default, or on an existing cluster (``--ray-address auto``), at most ``--jobs`` cells at a time. The
artifact lock is a file lock, so on a cluster with several nodes the run directory and the artifact
store must be on a filesystem every node shares (and mocap installed on every node).

A cell's name joins ``<last path part>-<label>`` for every axis, where a value's label is its
``name`` (mappings) or the value itself (scalars), e.g. ``latent-pulse_name-speed_seed-0``.
``runs/<name>/comparison.md`` / ``.json`` tabulate every cell's final stage metrics and, over the
``seed`` axis, their mean ± std; ``comparison.md`` embeds ``comparison_curves.png`` (learning curves,
mean ± std over seeds) and ``comparison_final.png`` (final metrics with error bars), see
:func:`mocap.report.write_comparison_plots`.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
import os
import re
import signal
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

from mocap.metric_display import format_cell, mean_ci95, metric_label
from mocap.safe_yaml import count_values
from mocap.spec import SpecError, SpecIssue, _rebase_paths, apply_overrides, extends_hints, load_document, validate_document


@dataclass
class Cell:
    name: str  # directory-safe cell name
    labels: dict[str, str]  # axis path -> label of this cell's value
    doc: dict[str, Any]  # the cell's spec document (no matrix)


def _label(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, dict):
        return str(value.get("name", "x"))
    return str(value)


def _axis_name(path: str) -> str:
    """An axis's short name: the last part of its (first) path."""
    return path.split(",")[0].strip().split(".")[-1]


def _fmt(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", text).strip("_") or "x"


#: the longest cell name (a folder name: at most 255 bytes, and a run dir's paths grow below it)
MAX_CELL_NAME = 100


def _short(name: str) -> str:
    """``name`` itself, or, when longer than :data:`MAX_CELL_NAME`, its start and a hash of all of it."""
    import hashlib

    if len(name) <= MAX_CELL_NAME:
        return name
    return name[: MAX_CELL_NAME - 13] + "-" + hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:12]


def _set(doc: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    parts = path.split(".")
    node = doc
    for part in parts[:-1]:
        nxt = node.get(part)
        if not isinstance(nxt, dict):
            nxt = node[part] = {}
        node = nxt
    node[parts[-1]] = copy.deepcopy(value)
    return doc


#: most cells one comparison spec may expand to (each cell is a training run)
MAX_CELLS = 1000
#: most values (scalars, lists, mappings) of all the cells' documents together
MAX_CELL_VALUES = 2_000_000


def expand(doc: dict[str, Any], base_dir: Path, source: str = "<spec>") -> list[Cell]:
    """The cells of a spec document (one cell named ``""`` when it has no ``matrix``)."""
    doc = copy.deepcopy(doc)
    matrix = doc.pop("matrix", None)
    if matrix is None:
        return [Cell("", {}, doc)]
    if not isinstance(matrix, dict) or not matrix:
        raise SpecError(source, [SpecIssue("matrix", "must be a mapping of field paths to lists of values")])
    axes = []
    for path, values in matrix.items():
        paths = [q.strip() for q in path.split(",")] if isinstance(path, str) else []
        if not paths or any(not q or any(not part for part in q.split(".")) for q in paths):
            raise SpecError(source, [SpecIssue("matrix", f"bad field path {path!r} (use dotted names, e.g. task.name)")])
        if not isinstance(values, list) or not values:
            raise SpecError(source, [SpecIssue(f"matrix.{path}", "must be a non-empty list of values")])
        for v in values if len(paths) > 1 else ():
            if not isinstance(v, list) or len(v) != len(paths):
                raise SpecError(source, [SpecIssue(f"matrix.{path}", f"each value must be a list of {len(paths)} entries, one per path (got {_fmt(v)})")])
        axes.append((path, values))
    count = math.prod(len(values) for _, values in axes)
    if count > MAX_CELLS:
        sizes = " x ".join(str(len(v)) for _, v in axes)
        raise SpecError(source, [SpecIssue("matrix", f"{sizes} = {count:,} cells; a comparison runs at most {MAX_CELLS:,} (split it into several specs)")])
    per_cell = count_values(doc, MAX_CELL_VALUES) + sum(max(count_values(v, MAX_CELL_VALUES) for v in values) for _, values in axes)
    if count * per_cell > MAX_CELL_VALUES:
        raise SpecError(
            source,
            [SpecIssue("matrix", f"{count:,} cells of up to {per_cell:,} values each exceed {MAX_CELL_VALUES:,} values in all (split it into several specs)")],
        )
    cells = []
    for combo in itertools.product(*(values for _, values in axes)):
        cell_doc = copy.deepcopy(doc)
        labels = {}
        for (path, _), value in zip(axes, combo):
            paths = [q.strip() for q in path.split(",")]
            if len(paths) == 1:
                _set(cell_doc, path, value)
                labels[path] = _label(value)
            else:  # a zipped axis: one entry per path, labelled by the first
                for q, v in zip(paths, value):
                    _set(cell_doc, q, v)
                labels[path] = _label(value[0])
        _rebase_paths(cell_doc, base_dir)
        labels = {path: _short(label) for path, label in labels.items()}
        name = _short("_".join(_safe(f"{_axis_name(path)}-{labels[path]}") for path, _ in axes))
        cells.append(Cell(name, labels, cell_doc))
    names = [c.name for c in cells]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise SpecError(source, [SpecIssue("matrix", f"two cells get the same name {dup}: give mapping values distinct `name`s")])
    return cells


def load_cells(path: Path, plugins: Any, overrides: list[str] | None = None) -> list[tuple[Cell, Any]]:
    """Expand and validate every cell of a spec file: ``[(cell, ResolvedSpec)]``."""
    replaced: list[tuple[str, Any, Any]] = []
    doc = load_document(Path(path), replaced=replaced)
    if overrides:
        doc = apply_overrides(doc, overrides)
    out = []
    for cell in expand(doc, Path(path).resolve().parent, str(path)):
        source = f"{path} (cell {cell.name})" if cell.name else str(path)
        try:
            out.append((cell, validate_document(cell.doc, plugins, source=source, base_dir=Path(path).resolve().parent)))
        except SpecError as exc:
            raise extends_hints(exc, replaced) from None
    return out


# ---------------------------------------------------------------------------------- running
EXECUTORS = ("local", "ray")
RAY_MISSING = "--executor ray needs Ray: pip install 'mocap[ray]'"


class ExecutorError(Exception):
    """An executor that cannot be used (Ray missing, a cluster that cannot be reached): one line."""


def import_ray() -> Any:
    """The ``ray`` module, or :class:`ExecutorError` with the install line when it is missing."""
    try:
        import ray
    except ImportError:
        raise ExecutorError(RAY_MISSING) from None
    return ray


def _write_cell_spec(cell: Cell, resolved: Any, out_dir: Path) -> tuple[Path, Path]:
    """``(cell dir, cell.yaml)``: the cell's resolved spec, the file its process runs."""
    cell_dir = out_dir / cell.name
    cell_dir.mkdir(parents=True, exist_ok=True)
    spec_file = cell_dir / "cell.yaml"
    spec_file.write_text(resolved.to_yaml())
    return cell_dir, spec_file


def cell_command(spec_file: str | Path, cell_dir: str | Path, store: str | Path, python: str | None = None) -> list[str]:
    """The command that runs one cell in its own process (``--jobs`` and ``--executor ray``)."""
    return [python or sys.executable, "-m", "mocap.cli", "run", str(spec_file), "--out", str(cell_dir), "--store", str(store)]


def _outcome(returncode: int, cell_dir: str | Path) -> str:
    return "done" if returncode == 0 else f"failed (exit {returncode}; see {Path(cell_dir) / 'run.log'})"


def _ray_cell(spec_file: str, cell_dir: str, store: str, cwd: str) -> str:
    """A Ray task: run one cell's command with this worker's Python, output in ``<cell>/run.log``.
    Cancelled (Ctrl-C in the driver), it passes SIGINT on so the cell saves its checkpoint."""
    with (Path(cell_dir) / "run.log").open("w") as log:
        proc = subprocess.Popen(cell_command(spec_file, cell_dir, store), stdout=log, stderr=subprocess.STDOUT, cwd=cwd if os.path.isdir(cwd) else None)
        try:
            return _outcome(proc.wait(), cell_dir)
        except BaseException:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=120)
            except BaseException:  # noqa: BLE001 - never leave the cell's process behind
                proc.kill()
            raise


def _run_cells_ray(
    cells: list[tuple[Cell, Any]],
    out_dir: Path,
    console: Any,
    jobs: int,
    store: Path,
    address: str | None,
    cpus_per_cell: float,
) -> dict[str, str]:
    ray = import_ray()
    started = False
    if not ray.is_initialized():  # a caller (or a test) may have started Ray itself: use that one
        try:
            if address:
                ray.init(address=address)
            else:
                ray.init(include_dashboard=False)
        except Exception as exc:  # noqa: BLE001 - no cluster at that address, a port in use, ...
            first = (str(exc).strip().splitlines() or [""])[0]
            where = f"--ray-address {address}" if address else "a local Ray instance"
            raise ExecutorError(f"--executor ray: cannot start or join {where}: {type(exc).__name__}: {first}") from None
        started = True
    try:
        cpus = float(ray.cluster_resources().get("CPU", 0.0))
        if cpus_per_cell > cpus:
            raise ExecutorError(f"--ray-cpus-per-cell {cpus_per_cell:g}: the Ray cluster has {cpus:g} CPUs in all; ask for at most that")
        console.print(f"ray: {cpus:g} CPUs, {cpus_per_cell:g} per cell, at most {jobs} cell(s) at a time", highlight=False)
        task = ray.remote(_ray_cell).options(num_cpus=cpus_per_cell, max_retries=0)
        cwd = str(Path.cwd())
        status: dict[str, str] = {}
        pending = list(cells)
        running: dict[Any, str] = {}
        try:
            while pending or running:
                while pending and len(running) < jobs:
                    cell, resolved = pending.pop(0)
                    cell_dir, spec_file = _write_cell_spec(cell, resolved, out_dir)
                    running[task.remote(str(spec_file), str(cell_dir), str(store), cwd)] = cell.name
                done, _ = ray.wait(list(running), num_returns=1)
                for ref in done:
                    name = running.pop(ref)
                    try:
                        result = ray.get(ref)
                    except Exception as exc:  # noqa: BLE001 - the worker died, the task was cancelled, ...
                        first = (str(exc).strip().splitlines() or [""])[0]
                        result = f"failed (ray: {type(exc).__name__}: {first}; see {out_dir / name / 'run.log'})"
                    console.print(f"cell {name}: {result}", highlight=False)
                    status[name] = result
        except KeyboardInterrupt:
            for ref in running:  # the cells get SIGINT and save their checkpoints
                ray.cancel(ref)
            if running:
                ray.wait(list(running), num_returns=len(running), timeout=150)
            raise
        return status
    finally:
        if started:
            ray.shutdown()


def run_cells(
    cells: list[tuple[Cell, Any]],
    plugins: Any,
    out_dir: Path,
    console: Any,
    jobs: int = 1,
    store: Path | None = None,
    executor: str = "local",
    ray_address: str | None = None,
    cpus_per_cell: float = 1.0,
) -> dict[str, str]:
    """Run every cell (sequentially, ``jobs`` processes at a time, or with ``executor="ray"`` as Ray
    tasks, ``jobs`` at a time); returns cell -> "done" / error text."""
    from mocap.pipeline import run_pipeline

    if executor not in EXECUTORS:
        raise ExecutorError(f"--executor {executor}: choose one of {', '.join(EXECUTORS)}")
    store = store or out_dir / "artifacts"
    if executor == "ray":
        # absolute paths: a Ray worker need not share this process's working directory
        return _run_cells_ray(cells, Path(out_dir).resolve(), console, jobs, Path(store).resolve(), ray_address, cpus_per_cell)
    status: dict[str, str] = {}
    if jobs <= 1:
        for i, (cell, resolved) in enumerate(cells, 1):
            console.print(f"[bold]cell {i}/{len(cells)}[/]: {cell.name}")
            run_pipeline(resolved, plugins, out_dir / cell.name, store=store, console=console)
            status[cell.name] = "done"
        return status

    def one(item: tuple[Cell, Any]) -> tuple[str, str]:
        cell, resolved = item
        cell_dir, spec_file = _write_cell_spec(cell, resolved, out_dir)
        with (cell_dir / "run.log").open("w") as log:
            proc = subprocess.run(cell_command(spec_file, cell_dir, store), check=False, stdout=log, stderr=subprocess.STDOUT)
        return cell.name, _outcome(proc.returncode, cell_dir)

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        for name, result in pool.map(one, cells):
            console.print(f"cell {name}: {result}")
            status[name] = result
    return status


# ---------------------------------------------------------------------------------- reports
def _stage_metrics(cell_dir: Path) -> dict[str, float]:
    stages_file = cell_dir / "stages.json"
    if not stages_file.is_file():
        return {}
    out: dict[str, float] = {}
    for stage in json.loads(stages_file.read_text()):
        for key, value in (stage.get("metrics") or {}).items():
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                out[f"{stage['stage']}/{key}"] = float(value)
    return out


class MetricSummary(TypedDict):
    """One metric of a comparison group (``comparison.json``'s ``groups``): mean over the group's runs,
    sample std and 95% half-width of the mean (None for a single run), number of runs."""

    mean: float
    std: float | None
    ci95: float | None
    n: int


def comparison(cells: list[Cell], out_dir: Path, seed_axis: str = "seed") -> dict[str, Any]:
    """Per-cell final metrics and, grouped over ``seed_axis``, mean and std (written as JSON + markdown)."""
    metrics = {c.name: _stage_metrics(out_dir / c.name) for c in cells}
    rows = {c.name: {"labels": c.labels, "metrics": metrics[c.name]} for c in cells}
    groups: dict[str, list[str]] = {}
    for c in cells:
        key = ", ".join(f"{_axis_name(p)}={v}" for p, v in c.labels.items() if p != seed_axis) or "all"
        groups.setdefault(key, []).append(c.name)
    summary: dict[str, dict[str, MetricSummary]] = {}
    for key, names in groups.items():
        metric_names = sorted(set().union(*(metrics[n].keys() for n in names)))
        summary[key] = {}
        for m in metric_names:
            vals = [metrics[n][m] for n in names if m in metrics[n]]
            mean, half = mean_ci95(vals)
            std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else None
            summary[key][m] = {"mean": mean, "std": std, "ci95": half, "n": len(vals)}
    data: dict[str, Any] = {"cells": rows, "groups": summary}
    plots = _plots(groups, summary, out_dir)
    data["plots"] = [name for name, _ in plots if name]
    from mocap.sample_efficiency import efficiency, read_curve, render_efficiency

    curves = {key: [read_curve(out_dir / n / "metrics.jsonl") for n in names] for key, names in groups.items()}
    curves = {key: [c for c in cs if len(c[0])] for key, cs in curves.items()}
    section = ""
    if any(curves.values()):  # a task stage logged its normalized return: PULSE Fig. 4's quantities
        data["efficiency"] = efficiency({k: cs for k, cs in curves.items() if cs})
        section = render_efficiency(data["efficiency"])
    (out_dir / "comparison.json").write_text(json.dumps(data, indent=2) + "\n")
    (out_dir / "comparison.md").write_text(render(summary) + section + render_plots(plots))
    return data


def _plots(groups: dict[str, list[str]], summary: dict[str, dict[str, MetricSummary]], out_dir: Path) -> list[tuple[str, str]]:
    """Learning curves with a seed band and final-metric bars (:func:`mocap.report.write_comparison_plots`):
    ``[(file name, caption)]``, or ``[("", note)]`` when plots cannot be made."""
    from mocap.report import COMPARISON_CURVES, PlotsUnavailable, write_comparison_plots

    present = [m for m in KEY_METRICS if any(m in g for g in summary.values())]
    try:
        written = write_comparison_plots({k: [out_dir / n for n in names] for k, names in groups.items()}, summary, present, out_dir)
    except PlotsUnavailable as exc:
        return [("", str(exc))]
    except Exception as exc:  # noqa: BLE001 - a plot must never fail a finished comparison
        return [("", f"plots skipped: {type(exc).__name__}: {exc}")]
    captions = {COMPARISON_CURVES: "learning curves: mean ± std over seeds (a band only where a cell has several seeds)"}
    return [(p.name, captions.get(p.name, "final metrics: mean, with a 95% interval where a cell has several seeds")) for p in written]


def render_plots(plots: list[tuple[str, str]]) -> str:
    """The markdown that embeds the comparison plots (or says why there are none)."""
    if not plots:
        return ""
    lines = ["", "## Plots", ""]
    for name, caption in plots:
        lines += [f"![{caption}]({name})" if name else caption, ""]
    return "\n".join(lines)


#: metrics shown in the markdown table when present (all are in comparison.json)
KEY_METRICS = (
    "task/episode/normalized_return",
    "task/episode/return",
    "task/episode/length",
    "eval/success_rate",
    "eval/succeeded",
    "eval/mpjpe_g",
    "eval/mpjpe_g_succ",
    "eval/mpjpe_l",
    "eval/rot_err",
    "eval/fall_rate",
    "eval/diversity_m",
    # eval_suite (mocap.suite): imitation and generation side by side
    "eval/imitation/success_rate",
    "eval/imitation/mpjpe_g",
    "eval/imitation/mpjpe_g_succ",
    "eval/generation/fall_rate",
    "eval/generation/time_to_fall_s",
    "eval/generation/diversity_m",
    # eval_suite's task part: the task policy with its deterministic action (mocap.task_eval)
    "eval/task_eval/speed_error",
    "eval/task_eval/heading_error",
    "eval/task_eval/success_rate",
    "eval/task_eval/distance",
    "eval/task_eval/hit_rate",
    "eval/task_eval/envs_never_terminated",
    # how natural the task policy moves (mocap.naturalness)
    "eval/task_eval/mm_distance",
    "eval/task_eval/mm_within",
    "eval/task_eval/foot_skating",
    "eval/task_eval/crouch_share",
    "eval/task_eval/realism",
)


def _success_count(metrics: dict[str, MetricSummary], key: str) -> str | None:
    """``"14/15"`` for a success rate whose stage also recorded the count and the total (``succeeded``,
    ``total``); ``"13.7/15 ± 0.8 (n=3)"`` over several seeds; None where they are missing."""
    if not key.endswith("success_rate"):
        return None
    base = key[: -len("success_rate")]
    succeeded, total = metrics.get(base + "succeeded"), metrics.get(base + "total")
    if succeeded is None or total is None:
        return None
    if succeeded["ci95"] is None or succeeded["n"] < 2:
        return f"{succeeded['mean']:.0f}/{total['mean']:.0f}"
    return f"{succeeded['mean']:.3g}/{total['mean']:.0f} ± {succeeded['ci95']:.2g} (n={succeeded['n']})"


def render(summary: dict[str, dict[str, MetricSummary]]) -> str:
    present = [m for m in KEY_METRICS if any(m in g for g in summary.values())]
    if not present:
        present = sorted(set().union(*(g.keys() for g in summary.values())))[:8]
    # a success rate is shown as the count it comes from (14/15): its separate count column goes
    present = [m for m in present if not (m.endswith("/succeeded") and m[: -len("succeeded")] + "success_rate" in present)]
    head = ["cell", *(metric_label(m) for m in present)]
    several = any(v.get("n", 1) > 1 for g in summary.values() for v in g.values())
    note = (
        "final stage metrics per cell; where a cell has several runs (seeds): mean ± half-width of the 95% confidence "
        "interval of the mean (Student's t), with n"
        if several
        else "final stage metrics per cell (one run each)"
    )
    lines = ["# Comparison", "", note, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, metrics in summary.items():
        cells = []
        for m in present:
            v = metrics.get(m)
            count = _success_count(metrics, m)
            cells.append(count if count is not None else "" if v is None else format_cell(v["mean"], v.get("ci95"), int(v.get("n", 1))))
        lines.append("| " + " | ".join([key, *cells]) + " |")
    return "\n".join(lines) + "\n"


__all__ = ["EXECUTORS", "RAY_MISSING", "Cell", "ExecutorError", "cell_command", "comparison", "expand", "import_ray", "load_cells", "render", "run_cells"]
