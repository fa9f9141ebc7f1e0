"""Artifact keys of a spec's stages (torch-free, so that ``mocap validate`` prints them without
importing the training code; re-exported by :mod:`mocap.pipeline`, which documents the store).

A stage's key hashes its resolved section, the sections it depends on (humanoid, motions,
simulator, seed), the fingerprint of the motion files and the keys of the stages upstream of it;
a stage that names a ``checkpoint:`` is keyed by the file's content.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from mocap.fingerprint import file_digest, files_fingerprint
from mocap.motion.clip import MotionDataError
from mocap.plugins import PluginError, PluginSet, UnknownComponent
from mocap.roles import MotionSource
from mocap.spec import STAGES, ResolvedSpec, Spec

ARTIFACT_FORMAT = 1

#: sections every stage depends on, besides its own and its upstream stages
_CONTEXT_SECTIONS = ("humanoid", "motions", "simulator", "seed")


def _canonical(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)


def stage_keys(spec: Spec, motion_inputs: str | None = None) -> dict[str, str]:
    """Artifact key of every stage the spec names (same spec -> same keys).

    ``motion_inputs``: the fingerprint of the motion files (:func:`motion_fingerprint`); it enters
    every trained stage's key, so a clip edited in place trains the stages again.
    """
    dumped = spec.model_dump(mode="json")
    context = {name: dumped[name] for name in _CONTEXT_SECTIONS}
    if motion_inputs is not None:
        context["motion_inputs"] = motion_inputs
    keys: dict[str, str] = {}
    upstream: list[str] = []
    for stage in STAGES:
        section = dumped.get(stage)
        if section is None:
            continue
        ckpt = section.get("checkpoint") if isinstance(section, dict) else None
        if ckpt:
            path = Path(ckpt)
            content = file_digest(path) if _is_file(path) else f"missing:{path}"
            material = {"format": ARTIFACT_FORMAT, "stage": stage, "name": section["name"], "checkpoint": content}
        else:
            material = {"format": ARTIFACT_FORMAT, "stage": stage, "section": section, "context": context, "upstream": upstream}
        key = hashlib.sha256(_canonical(material).encode()).hexdigest()[:16]
        keys[stage] = key
        upstream = [*upstream, key]
    return keys


def motion_fingerprint(resolved: ResolvedSpec, plugins: PluginSet) -> str | None:
    """Fingerprint of the files the spec's motion source reads (:meth:`MotionSource.inputs`); None
    when the source cannot even list them (its own error comes when the motions are loaded)."""
    spec = resolved.spec
    try:
        source = plugins.get("motion_source", spec.motions.name).build(resolved.params.get("motions"))
    except (UnknownComponent, MotionDataError, OSError, ValueError):
        return None
    if not isinstance(source, MotionSource):
        raise PluginError(f"motion source {spec.motions.name!r} built a {type(source).__name__}, not a mocap.interfaces.MotionSource")
    try:
        return files_fingerprint(source.inputs())
    except (MotionDataError, OSError, ValueError):
        return None


def resolved_stage_keys(resolved: ResolvedSpec, plugins: PluginSet) -> dict[str, str]:
    """:func:`stage_keys` with the motion files' fingerprint: the keys every command uses."""
    return stage_keys(resolved.spec, motion_fingerprint(resolved, plugins))


def _is_file(path: Path) -> bool:
    """``path.is_file()``, False for a path the OS cannot even look up (a name over 255 bytes)."""
    try:
        return path.is_file()
    except OSError:
        return False
