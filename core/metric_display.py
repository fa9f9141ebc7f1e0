"""How reports show a metric: a display name, a unit, and an interval over seeds only when there is
more than one.

Metric keys in ``metrics.jsonl`` are paths (``eval/imitation/mpjpe_g``); the last component names
the metric. :data:`METRIC_DISPLAY` maps it to ``(display name, unit)`` (units as the evaluation
protocols report them: mm, mm/frame, degrees, s, m, m/s; an empty unit for rates and counts).

Over several runs (seeds) a cell shows ``mean ± h (n)`` with ``h`` the half-width of the 95%
confidence interval of the mean, ``t_{0.975, n-1} s / sqrt(n)`` (Student's t, ``s`` the sample
standard deviation, ddof 1); a single run shows its value alone (no ± 0, no n = 1).
"""

from __future__ import annotations

import math

#: metric name (last key component) -> (display name, unit)
METRIC_DISPLAY: dict[str, tuple[str, str]] = {
    "success_rate": ("success rate", ""),
    "succeeded": ("clips tracked", ""),
    "mpjpe_g": ("MPJPE-g", "mm"),
    "mpjpe_g_succ": ("MPJPE-g (tracked)", "mm"),
    "mpjpe_l": ("MPJPE-l", "mm"),
    "mpjpe_l_succ": ("MPJPE-l (tracked)", "mm"),
    "pa_mpjpe": ("PA-MPJPE", "mm"),
    "vel_err": ("velocity error", "mm/frame"),
    "acc_err": ("acceleration error", "mm/frame²"),
    "rot_err": ("rotation error", "°"),
    "tracked_s": ("tracked time", "s"),
    "fall_rate": ("fall rate", ""),
    "time_to_fall_s": ("time to fall", "s"),
    "diversity_m": ("diversity", "m"),
    "normalized_return": ("normalized return", ""),
    "return": ("return", ""),
    "length": ("episode length", "steps"),
    "speed_error": ("speed error", "m/s"),
    "distance_m": ("distance", "m"),
}

# two-sided 95% critical values of Student's t for 1..30 degrees of freedom
_T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
         2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)  # fmt: skip


def metric_label(key: str) -> str:
    """``"MPJPE-g (mm)"`` for ``eval/imitation/mpjpe_g``; a known name with its unit, else the key
    itself (the stage prefix kept where it tells two metrics apart: ``task/`` vs ``eval/``)."""
    parts = key.split("/")
    name = parts[-1]
    if name not in METRIC_DISPLAY:
        return key
    display, unit = METRIC_DISPLAY[name]
    group = parts[-2] if len(parts) >= 2 and parts[-2] not in ("eval", "episode") else ""
    text = f"{group} {display}" if group else display
    return f"{text} ({unit})" if unit else text


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
    """``"12.3"`` for one run, ``"12.3 ± 1.4 (n=3)"`` for several."""
    if half is None or n < 2:
        return f"{mean:.3g}"
    return f"{mean:.3g} ± {half:.2g} (n={n})"


__all__ = ["METRIC_DISPLAY", "format_cell", "mean_ci95", "metric_label", "t_critical_95"]
