"""``report.md`` of a run: the spec, what each stage did, its metrics, versions, hardware, wall-clock."""

from __future__ import annotations

import platform
from pathlib import Path
from typing import TYPE_CHECKING

from mocap.checkpoint import atomic_write_text, hardware, package_versions

if TYPE_CHECKING:  # pragma: no cover
    from mocap.pipeline import StageRecord
    from mocap.spec import ResolvedSpec


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def render_report(
    resolved: "ResolvedSpec", records: list["StageRecord"], wall_seconds: float, out_dir: Path | None = None
) -> str:
    spec = resolved.spec
    lines = [f"# {spec.name}", ""]
    if spec.description:
        lines += [spec.description, ""]
    lines += [
        f"- spec: `{resolved.source}` (resolved copy: `spec.yaml`)",
        f"- humanoid `{spec.humanoid.name}`, motions `{spec.motions.name}`, simulator `{spec.simulator.name}`, seed {spec.seed}",
        f"- wall-clock: {wall_seconds:.1f} s",
        "",
        "## Stages",
        "",
        "| stage | component | trainer | artifact | reused | seconds |",
        "|---|---|---|---|---|---|",
    ]
    for r in records:
        section = getattr(spec, r.stage)
        component = getattr(section, "name", "-")
        trainer = section.trainer.name if getattr(section, "trainer", None) is not None else "-"
        lines.append(f"| {r.stage} | {component} | {trainer} | `{r.workdir.name}` | {'yes' if r.reused else 'no'} | {r.seconds:.1f} |")
    for r in records:
        if not r.result.metrics:
            continue
        lines += ["", f"## {r.stage} metrics", "", "| metric | value |", "|---|---|"]
        lines += [f"| {k} | {_fmt(v)} |" for k, v in sorted(r.result.metrics.items())]
    if out_dir is not None:
        for table in sorted(Path(out_dir).glob("*.md")):
            if table.name != "report.md":  # stage tables (e.g. imitation_eval.md), one level down in headings
                body = table.read_text(encoding="utf-8").strip().splitlines()
                lines += ["", *[("#" + line) if line.startswith("#") else line for line in body]]
        media = sorted(p.name for p in Path(out_dir).iterdir() if p.suffix in (".mp4", ".gif", ".png"))
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
    atomic_write_text(path, render_report(resolved, records, wall_seconds, out_dir))
    return path
