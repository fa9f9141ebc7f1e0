"""A run directory's own record: ``spec.yaml``, ``stages.json`` and the files its stages published.

Written only once a run really starts a stage, so that a run which fails before (a missing
checkpoint, a failed preflight) leaves an earlier finished run's record untouched.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from mocap.checkpoint import atomic_write_json, atomic_write_text

if TYPE_CHECKING:
    from mocap.pipeline import StageRecord
    from mocap.spec import ResolvedSpec

PUBLISHED_DIR = "published"  # files a stage publishes to the run directory, kept for reuse


class RunRecord:
    """The run directory's own record (``spec.yaml``, ``stages.json``, the files reused stages
    published), written only once this run really starts a stage (a trainer is about to run) or
    finishes: a run that fails before (a missing checkpoint, a failed preflight) leaves an earlier
    finished run's record as it was."""

    def __init__(self, out_dir: Path, resolved: "ResolvedSpec", main: bool):
        self.out_dir, self.resolved, self.main = out_dir, resolved, main
        self.started = False
        self.records: list["StageRecord"] = []

    def start(self) -> None:
        """This run now owns the run directory: write its spec and what it has decided so far."""
        if self.started or not self.main:
            return
        self.started = True
        atomic_write_text(self.out_dir / "spec.yaml", self.resolved.to_yaml())
        for record in self.records:
            if record.reused:
                copy_published(record.workdir, self.out_dir)
        if self.records:
            write_stages(self.out_dir, self.records, self.resolved.spec.seed)

    def add(self, record: "StageRecord") -> None:
        self.records.append(record)
        if self.started and self.main:
            if record.reused:
                copy_published(record.workdir, self.out_dir)
            write_stages(self.out_dir, self.records, self.resolved.spec.seed)


def copy_published(workdir: Path, out_dir: Path) -> None:
    """A stage's tables and videos (its ``published/`` files) belong in the run directory."""
    published = workdir / PUBLISHED_DIR
    if published.is_dir():
        for item in published.iterdir():
            if item.is_file():
                shutil.copy2(item, out_dir / item.name)


def write_stages(out_dir: Path, records: list["StageRecord"], seed: int | None = None) -> None:
    from mocap.pipeline import derive_seed

    atomic_write_json(
        out_dir / "stages.json",
        [
            {
                "stage": r.stage,
                "key": r.key,
                "seed": derive_seed(seed, r.stage) if seed is not None else None,
                "artifact_dir": str(r.workdir),
                "checkpoint": str(r.result.checkpoint) if r.result.checkpoint else None,
                "metrics": r.result.metrics,
                "reused": r.reused,
                "seconds": round(r.seconds, 2),
                "trained_seconds": round(r.trained_seconds, 2) if r.trained_seconds is not None else None,
                **({"retrained_because": r.why} if r.why else {}),
            }
            for r in records
        ],
    )
