"""Does a checkpoint's humanoid match the spec's? Name *and* parameters.

A policy acts through its humanoid's joints, gains and ranges: a teacher trained on the ``amp``
humanoid with ``shoulder_turns: 8`` drives a ±180° humanoid into clamped targets without any error,
and a latent space distilled that way learns the clamped motion. :func:`check_humanoid_params`
rebuilds the humanoid named in the spec embedded in a checkpoint (its ``humanoid:`` section, through
the installed plugin, so defaults compare equal to omitted values) and compares it with the spec's
skeleton. The humanoid's *name* is checked by :func:`mocap.eval_targets.check_trained_humanoid`,
which calls this one when the names agree.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mocap.skeleton import Skeleton

__all__ = ["check_humanoid_params", "embedded_humanoid_params", "skeleton_difference"]


def embedded_humanoid_params(data: dict[str, Any]) -> dict[str, Any] | None:
    """The ``humanoid.params`` of the spec embedded in a checkpoint (``{}`` when it names none;
    None without an embedded spec or a humanoid section)."""
    from mocap.checkpoint import embedded_humanoid_section

    humanoid = embedded_humanoid_section(data)
    if isinstance(humanoid, str):
        return {}
    if not isinstance(humanoid, dict):
        return None
    params = humanoid.get("params")
    return dict(params) if isinstance(params, dict) else {}


def skeleton_difference(trained: Skeleton, current: Skeleton, limit: int = 3) -> str:
    """What differs between two skeletons of the same humanoid, in words (at most ``limit`` items);
    empty when they are equal."""
    if trained == current:
        return ""
    out: list[str] = []
    for a, b in zip(trained.hinges, current.hinges):
        for field in ("range", "kp", "kd", "torque_limit", "armature"):
            va, vb = getattr(a, field), getattr(b, field)
            if va != vb:
                out.append(f"{a.name}.{field} {_fmt(va)} (trained) vs {_fmt(vb)}")
                break
    if trained.friction != current.friction:
        out.append(f"friction {trained.friction:g} (trained) vs {current.friction:g}")
    if len(trained.hinges) != len(current.hinges):
        out.append(f"{len(trained.hinges)} hinges (trained) vs {len(current.hinges)}")
    if not out:
        out.append("bodies or geometry")
    more = f" and {len(out) - limit} more" if len(out) > limit else ""
    return "; ".join(out[:limit]) + more


def _fmt(v: Any) -> str:
    if isinstance(v, tuple):
        return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def check_humanoid_params(path: Path, data: dict[str, Any], skeleton: Skeleton, plugins: Any, stage: str) -> None:
    """Raise :class:`~mocap.checkpoint.CheckpointError` when checkpoint ``path`` (loaded as ``data``)
    was trained on the same-named humanoid with other parameters than ``skeleton``'s. A checkpoint
    without an embedded spec, or whose humanoid this install cannot build, is not judged here."""
    from mocap.checkpoint import CheckpointError

    params = embedded_humanoid_params(data)
    if params is None:
        return
    try:
        trained = plugins.get("humanoid", skeleton.name).build(params)
    except Exception:  # noqa: BLE001 - params this version does not know: the name check already passed
        return
    diff = skeleton_difference(trained, skeleton)
    if diff:
        shown = ", ".join(f"{k}: {v}" for k, v in sorted(params.items())) or "the defaults"
        raise CheckpointError(
            f"{path}: this {stage} checkpoint was trained on humanoid {skeleton.name} with params {{{shown}}}, which "
            f"differs from the spec's humanoid ({diff}); set the spec's humanoid.params to the checkpoint's"
        )
