"""``mocap export RUN_DIR DEST``: a finished run's trained stages as a self-contained checkpoint directory.

``DEST`` (e.g. ``checkpoints/pulse_amp/``) receives the trained stages' files (``policy.pt`` for an
imitator, ``latent.pt`` for a latent space) and a ``spec.yaml`` in which every stage names its
``checkpoint:`` relative to ``DEST``, with no trainer. A stage that the run took from an existing
checkpoint file (a committed teacher) is referenced where it lies, by a relative path, instead of
being copied. ``mocap eval DEST`` and ``mocap generate DEST`` then work from any clone.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated, Any

import typer
import yaml

from mocap.hooks import hookimpl

EXPORTED_NAMES = {"imitator": "policy.pt", "latent": "latent.pt"}


def export_run(run_dir: Path, dest: Path) -> Path:
    """Write ``dest/spec.yaml`` and copy the trained stages' files (module docstring); returns the spec path."""
    from mocap.checkpoint import atomic_write_bytes, atomic_write_text
    from mocap.cli import UserError, check_output_dir

    run_dir, dest = Path(run_dir), Path(dest)
    spec_file, stages_file = run_dir / "spec.yaml", run_dir / "stages.json"
    if not (spec_file.is_file() and stages_file.is_file()):
        raise UserError(f"{run_dir}: not a finished run directory (spec.yaml + stages.json)")
    doc: dict[str, Any] = yaml.safe_load(spec_file.read_text())
    stages = {s["stage"]: s for s in json.loads(stages_file.read_text())}
    check_output_dir(dest, "DEST")  # a file, or not writable: one clear error before anything is copied
    exported = []
    for stage, name in EXPORTED_NAMES.items():
        section = doc.get(stage)
        record = stages.get(stage)
        if not isinstance(section, dict) or record is None or not record.get("checkpoint"):
            continue
        src = Path(record["checkpoint"]).resolve()
        if not src.is_file():
            raise UserError(f"{run_dir}: the {stage} checkpoint {src} is missing")
        if section.get("checkpoint"):  # taken from an existing file: reference it where it lies
            target = src
        else:
            target = dest / name
            atomic_write_bytes(target, src.read_bytes())  # a full disk leaves no half-copied file
        section["checkpoint"] = os.path.relpath(target.resolve(), dest.resolve())
        section.pop("trainer", None)
        exported.append(stage)
    if not exported:
        raise UserError(f"{run_dir}: no trained imitator or latent stage to export")
    out = dest / "spec.yaml"
    header = f"# Exported from the run {run_dir.name} by `mocap export`; checkpoint paths are relative to this file.\n"
    atomic_write_text(out, header + yaml.safe_dump(doc, sort_keys=False))
    return out


@hookimpl
def register_commands(app):  # type: ignore[no-untyped-def]
    @app.command("export")
    def export_command(
        run_dir: Annotated[Path, typer.Argument(help="a finished run directory (runs/<name>)")],
        dest: Annotated[Path, typer.Argument(help="the checkpoint directory to write (e.g. checkpoints/<name>)")],
    ) -> None:
        """Copy a run's trained stages into a self-contained checkpoint directory (spec.yaml + files)."""
        spec = export_run(run_dir, dest)
        print(f"wrote {spec}; evaluate it with `mocap eval {dest}`")


__all__ = ["export_run"]
