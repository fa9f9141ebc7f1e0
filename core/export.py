"""``mocap export RUN_DIR DEST``: a finished run's trained stages as a self-contained checkpoint directory.

``DEST`` (e.g. ``checkpoints/pulse_amp/``) receives the trained stages' files (``policy.pt`` for an
imitator, ``latent.pt`` for a latent space) and a ``spec.yaml`` in which every stage names its
``checkpoint:`` relative to ``DEST``, with no trainer (``task_policy.pt`` for a trained ``task`` stage).
A stage that the run took from an existing checkpoint file (a committed teacher) is referenced where
it lies, by a relative path, instead of being copied; when that file lies in another checkout of
the repository (a run made in a git worktree, exported into the main one) and the same file, byte
for byte, is at the same place in ``DEST``'s checkout, that one is referenced. ``mocap eval DEST``,
``mocap generate DEST`` and (a task) ``mocap task-eval DEST`` then work from any clone.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any

import typer
import yaml

from mocap.hooks import hookimpl

EXPORTED_NAMES = {"imitator": "policy.pt", "latent": "latent.pt", "task": "task_policy.pt"}


def _checkout_root(path: Path) -> Path | None:
    """The nearest folder above ``path`` holding ``.git`` (a clone's folder or a worktree's file)."""
    for parent in Path(path).resolve().parents:
        if (parent / ".git").exists():
            return parent
    return None


def same_file_in_checkout(src: Path, dest: Path) -> Path:
    """``src``, or the identical file at the same place in ``dest``'s checkout when ``src`` lies in
    another checkout (module docstring): an export then names no path of the other checkout."""
    src_root, dest_root = _checkout_root(src), _checkout_root(dest)
    if src_root is None or dest_root is None or src_root == dest_root:
        return src
    twin = dest_root / Path(src).resolve().relative_to(src_root)
    if twin.is_file() and twin.stat().st_size == Path(src).stat().st_size and twin.read_bytes() == Path(src).read_bytes():
        return twin
    return src


def export_run(run_dir: Path, dest: Path) -> Path:
    """Write ``dest/spec.yaml`` and copy the trained stages' files (module docstring); returns the spec path."""
    from mocap.checkpoint import atomic_write_bytes, atomic_write_text
    from mocap.errors import UserError
    from mocap.paths import check_output_dir

    run_dir, dest = Path(run_dir), Path(dest)
    spec_file, stages_file = run_dir / "spec.yaml", run_dir / "stages.json"
    if not (spec_file.is_file() and stages_file.is_file()):
        raise UserError(f"{run_dir}: not a finished run directory (spec.yaml + stages.json)")
    from mocap.runfiles import read_spec_file, read_stages

    doc: dict[str, Any] = read_spec_file(spec_file)
    stages = {s["stage"]: s for s in read_stages(stages_file)}
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
            target = same_file_in_checkout(src, dest)
        else:
            target = dest / name
            # the copy's embedded spec names its dependencies relative to DEST (a run's own spec
            # holds absolute paths of this machine); a full disk leaves no half-copied file
            atomic_write_bytes(target, with_relative_embedded_paths(src, dest))
        section["checkpoint"] = os.path.relpath(target.resolve(), dest.resolve())
        section.pop("trainer", None)
        exported.append(stage)
    if not exported:
        raise UserError(f"{run_dir}: no trained imitator, latent or task stage to export")
    out = dest / "spec.yaml"
    header = f"# Exported from the run {run_dir.name} by `mocap export`; checkpoint paths are relative to this file.\n"
    atomic_write_text(out, header + yaml.safe_dump(doc, sort_keys=False))
    return out


STAGE_SECTIONS = ("imitator", "latent", "task")


def resolve_embedded_paths(doc: Any, base: Path) -> Any:
    """A checkpoint's embedded spec with its stages' relative ``checkpoint:`` paths resolved
    against ``base`` (the checkpoint file's folder); absolute paths are kept."""
    if not isinstance(doc, dict):
        return doc
    for stage in STAGE_SECTIONS:
        section = doc.get(stage)
        if not isinstance(section, dict):
            continue
        ck = section.get("checkpoint")
        if isinstance(ck, str) and ck and not Path(ck).is_absolute():
            section["checkpoint"] = str(Path(base) / ck)
    return doc


def relative_spec_text(spec_yaml: str, dest: Path, *, root_map: tuple[str, str] | None = None) -> str:
    """``spec_yaml`` with every stage's ``checkpoint:`` and its trainer's ``init_policy`` or ``init_latent``
    (the weights a continued run started from) relative to ``dest``. ``root_map`` = ``(old prefix, new prefix)``
    rewrites absolute paths of another machine (or checkout) first."""
    from mocap import safe_yaml
    from mocap.errors import UserError

    try:
        doc = safe_yaml.load(spec_yaml)
    except (yaml.YAMLError, ValueError) as exc:
        raise UserError(f"{dest}: the embedded spec to export is not valid YAML ({str(exc).splitlines()[0][:200]})") from None
    if not isinstance(doc, dict):
        return spec_yaml

    def rel(path: str) -> str:
        if root_map is not None and path.startswith(root_map[0]):
            path = root_map[1] + path[len(root_map[0]) :]
        if Path(path).is_absolute() and Path(path).is_file():
            path = str(same_file_in_checkout(Path(path), dest))
        return os.path.relpath(Path(path).resolve(), Path(dest).resolve()) if Path(path).is_absolute() else path

    for stage in STAGE_SECTIONS:
        section = doc.get(stage)
        if not isinstance(section, dict):
            continue
        ck = section.get("checkpoint")
        if isinstance(ck, str) and ck:
            section["checkpoint"] = rel(ck)
        trainer = section.get("trainer")
        params = trainer.get("params") if isinstance(trainer, dict) else None
        for key in ("init_policy", "init_latent"):  # the weights a continued run started from
            if isinstance(params, dict) and isinstance(params.get(key), str) and params[key]:
                params[key] = rel(params[key])
    return yaml.safe_dump(doc, sort_keys=False)


def with_relative_embedded_paths(src: Path, dest: Path, *, root_map: tuple[str, str] | None = None) -> bytes:
    """The bytes of checkpoint ``src`` re-saved with its embedded spec's paths relative to ``dest``
    (:func:`relative_spec_text`); loaded and saved without running any code."""
    import io

    import torch

    from mocap.checkpoint import load_checkpoint

    data = load_checkpoint(src)
    if isinstance(data.get("spec"), str):
        data["spec"] = relative_spec_text(data["spec"], dest, root_map=root_map)
    buffer = io.BytesIO()
    torch.save(data, buffer)
    return buffer.getvalue()


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


__all__ = ["export_run", "same_file_in_checkout"]
