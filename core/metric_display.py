"""How reports show a metric: a display name, a unit, and an interval over seeds only when there is
more than one.

Metric keys in ``metrics.jsonl`` are paths (``eval/imitation/mpjpe_g``); the last component names
the metric. The component that produces a metric declares how it is shown: ``register(...,
metrics={"mpjpe_g": MetricInfo("MPJPE-g", "mm")})`` in its registration hook (a
:class:`~mocap.interfaces.Metric` also carries ``display`` and ``unit``). :func:`declared_metrics`
collects every component's declarations; :func:`metric_label` turns a key into ``"MPJPE-g (mm)"``,
and a key nobody declared is shown as it is.

Over several runs (seeds) a cell shows ``mean ± h (n)`` with ``h`` the half-width of the 95%
confidence interval of the mean, ``t_{0.975, n-1} s / sqrt(n)`` (Student's t, ``s`` the sample
standard deviation, ddof 1); a single run shows its value alone (no ± 0, no n = 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping

if TYPE_CHECKING:  # pragma: no cover
    from mocap.plugins import PluginSet


@dataclass(frozen=True)
class MetricInfo:
    """How a metric is shown: its display name and unit (``""`` for rates, shares and counts)."""

    display: str
    unit: str = ""

    @classmethod
    def coerce(cls, value: Any, key: str) -> "MetricInfo":
        """``MetricInfo``, ``(display, unit)`` or ``display`` -> ``MetricInfo`` (else a ValueError naming ``key``)."""
        if isinstance(value, MetricInfo):
            return value
        if isinstance(value, str) and value:
            return cls(value)
        if isinstance(value, tuple) and len(value) == 2 and all(isinstance(v, str) for v in value) and value[0]:
            return cls(value[0], value[1])
        raise ValueError(f"metric {key!r}: declare MetricInfo(display, unit), (display, unit) or a display name, got {value!r}")


#: display names and units of the rows ``mocap task-eval`` adds to a task's own metrics
#: (:mod:`mocap.task_eval`), the naturalness measurements among them (:mod:`mocap.naturalness`)
TASK_EVAL_INFO: dict[str, MetricInfo] = {
    "episodes_ended": MetricInfo("episodes ended in the window"),
    "terminated_share": MetricInfo("share of ended episodes that terminated (falls)"),
    "envs_never_terminated": MetricInfo("share of envs never terminated"),
    "episode_return": MetricInfo("episode return (ended episodes)"),
    "episode_length": MetricInfo("episode length (ended episodes)", "control steps"),
    "env_steps": MetricInfo("env steps"),
    "seconds": MetricInfo("simulated time per env", "s"),
    "num_envs": MetricInfo("envs"),
    "mm_distance": MetricInfo("motion-matching distance per feature", "std²"),
    "mm_within": MetricInfo("share of transitions within the matching threshold"),
    "foot_skating": MetricInfo("foot skating in contact", "m/s"),
    "root_jerk": MetricInfo("root jerk", "m/s³"),
    "crouch_share": MetricInfo("share of frames crouched (pelvis low)"),
    "realism": MetricInfo("realism (fixed judge's score, 1 = like the data)"),
}


def declared_metrics(plugins: "PluginSet | None" = None) -> dict[str, MetricInfo]:
    """Every registered component's metric declarations (``plugins``: the process-wide set when None);
    the first declaration of a name wins (core registers first)."""
    if plugins is None:
        from mocap.plugins import get_plugins

        plugins = get_plugins()
    out: dict[str, MetricInfo] = {}
    for kind in plugins.components:
        for comp in plugins.components[kind].values():
            for name, info in comp.metrics.items():
                out.setdefault(name, info)
    return out


# two-sided 95% critical values of Student's t for 1..30 degrees of freedom
_T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
         2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)  # fmt: skip


def metric_label(key: str, declared: Mapping[str, MetricInfo] | None = None) -> str:
    """``"MPJPE-g (mm)"`` for ``eval/imitation/mpjpe_g``; a declared name with its unit, else the key
    itself (the stage prefix kept where it tells two metrics apart: ``task/`` vs ``eval/``).
    ``declared``: :func:`declared_metrics` of the process-wide plugins when None."""
    parts = key.split("/")
    name = parts[-1]
    table = {**TASK_EVAL_INFO, **(declared_metrics() if declared is None else declared)}
    if name not in table:
        return key
    info = table[name]
    group = parts[-2] if len(parts) >= 2 and parts[-2] not in ("eval", "episode") else ""
    text = f"{group} {info.display}" if group else info.display
    return f"{text} ({info.unit})" if info.unit else text


def t_critical_95(dof: int) -> float:
    """Two-sided 95% critical value of Student's t with ``dof`` >= 1 degrees of freedom (1.96 beyond 30)."""
    if dof < 1:
        raise ValueError("a confidence interval needs at least 2 values")
    return _T975[dof - 1] if dof <= len(_T975) else 1.96


def mean_ci95(values: list[float]) -> tuple[float, float | None]:
    """``(mean, half-width of its 95% interval)``; the half-width is None for a single value."""
    n = len(values)
    if n == 0:
        raise ValueError("no values")
    mean = sum(values) / n
    if n == 1:
        return mean, None
    s = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1))
    return mean, t_critical_95(n - 1) * s / math.sqrt(n)


def format_cell(mean: float, half: float | None, n: int) -> str:
    """``"12.3"`` for one run, ``"12.3 ± 1.4 (n=3)"`` for several; ``"-"`` for NaN (nothing to measure,
    e.g. the time to fall of rollouts that never fell)."""
    if math.isnan(mean):
        return "-"
    if half is None or n < 2:
        return f"{mean:.3g}"
    return f"{mean:.3g} ± {half:.2g} (n={n})"


__all__ = ["MetricInfo", "declared_metrics", "format_cell", "mean_ci95", "metric_label", "t_critical_95"]
