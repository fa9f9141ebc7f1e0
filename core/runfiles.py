"""Reading a run directory's or a checkpoint's own metadata (``spec.yaml``, ``stages.json``, an
embedded spec) with one clear error when it is corrupt, instead of a traceback: these files can be
edited, truncated or come from someone else."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from mocap import safe_yaml
from mocap.errors import UserError


def yaml_mapping(text: Any, source: str) -> dict[str, Any]:
    """The mapping a spec text holds; :class:`UserError` naming ``source`` for bad YAML or another type
    (``text`` too may be anything: a checkpoint's embedded spec is what the file says it is)."""
    if not isinstance(text, str):
        raise UserError(f"{source}: not a valid spec (a {type(text).__name__}, not YAML text)")
    try:
        doc = safe_yaml.load(text)
    except (yaml.YAMLError, RecursionError, ValueError) as exc:  # ValueError: e.g. an integer of 4,301 digits
        raise UserError(f"{source}: not a valid spec (YAML error: {str(exc).splitlines()[0][:200]})") from None
    if not isinstance(doc, dict):
        raise UserError(f"{source}: not a valid spec (it holds a {type(doc).__name__}, not a mapping)")
    return doc


def read_spec_file(path: Path) -> dict[str, Any]:
    """A run's resolved ``spec.yaml`` as a mapping (:func:`yaml_mapping`)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: unreadable ({exc})") from None
    return yaml_mapping(text, str(path))


def read_stages(path: Path) -> list[dict[str, Any]]:
    """A run's ``stages.json``: a list of records, each with at least a ``stage`` name."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise UserError(f"{path}: corrupt run record (not JSON: {str(exc)[:200]}); rerun the spec to rewrite it") from None
    if not isinstance(data, list) or not all(isinstance(s, dict) and isinstance(s.get("stage"), str) for s in data):
        raise UserError(f"{path}: corrupt run record (expected a list of stages, each with a 'stage' name); rerun the spec to rewrite it")
    return data


__all__ = ["read_spec_file", "read_stages", "yaml_mapping"]
