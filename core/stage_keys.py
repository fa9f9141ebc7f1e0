"""Artifact keys of a spec's stages (torch-free, so that ``mocap validate`` prints them without
importing the training code; re-exported by :mod:`mocap.pipeline`, which documents the store).

A stage's key hashes its resolved section, the sections it depends on (humanoid, motions,
simulator, seed), the fingerprint of the motion files, the **code** of every component it uses
(:func:`stage_code`: distribution, version and a hash of the plugin package's source files) and the
keys of the stages upstream of it; a stage that names a ``checkpoint:`` is keyed by the file's
content. So editing a plugin's code trains again the stages that use it (and those downstream of
them), and nothing else; editing ``mocap`` itself (the framework every stage runs in) trains every
stage again. :func:`key_change` says in words why a stage's key moved.
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
from mocap.spec import STAGES, ResolvedSpec, Spec, iter_components

ARTIFACT_FORMAT = 1
KEY_FILE = "key.json"  # beside a trained artifact: what its key hashes (:func:`stage_materials`)

#: sections every stage depends on, besides its own and its upstream stages
_CONTEXT_SECTIONS = ("humanoid", "motions", "simulator", "seed")


def _canonical(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)


def stage_keys(spec: Spec, motion_inputs: str | None = None, code: dict[str, dict[str, str]] | None = None) -> dict[str, str]:
    """Artifact key of every stage the spec names (same spec -> same keys).

    ``motion_inputs``: the fingerprint of the motion files (:func:`motion_fingerprint`); it enters
    every trained stage's key, so a clip edited in place trains the stages again. ``code``: each
    stage's code fingerprint (:func:`stage_code`), likewise.
    """
    return {stage: material_key(material) for stage, material in stage_materials(spec, motion_inputs, code).items()}


def material_key(material: dict[str, Any]) -> str:
    """The artifact key of one stage's material (:func:`stage_materials`)."""
    return hashlib.sha256(_canonical(material).encode()).hexdigest()[:16]


def stage_materials(spec: Spec, motion_inputs: str | None = None, code: dict[str, dict[str, str]] | None = None) -> dict[str, dict[str, Any]]:
    """What each stage's key hashes (:func:`stage_keys`): written beside a trained artifact
    (``key.json``) so that :func:`key_change` can say what differs."""
    dumped = spec.model_dump(mode="json")
    context = {name: dumped[name] for name in _CONTEXT_SECTIONS}
    if motion_inputs is not None:
        context["motion_inputs"] = motion_inputs
    materials: dict[str, dict[str, Any]] = {}
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
            if code is not None:
                material["code"] = code.get(stage, {})
        materials[stage] = material
        upstream = [*upstream, material_key(material)]
    return materials


_CONTEXT_ROLES = ("humanoid", "motions", "simulator")


def stage_code(spec: Spec, plugins: PluginSet) -> dict[str, dict[str, str]]:
    """Per stage, the code fingerprint of every component it uses (the humanoid, motion source and
    simulator, its own component and trainer, an eval stage's metrics): ``{"<kind>:<name>":
    "<distribution>==<version> <code hash>"}`` (:meth:`mocap.plugins.PluginSet.code_of`), plus
    ``"framework"``: the hash of ``mocap`` itself. A component no plugin registers is ``"unknown"``
    (validation reports it first)."""
    from mocap.fingerprint import package_digest

    uses: dict[str, dict[str, str]] = {stage: {} for stage in STAGES}
    for path, kind, ref in iter_components(spec):
        try:
            info = plugins.code_of(kind, ref.name)
            text = f"{info['package']}=={info['version']} {info['code']}"
        except (UnknownComponent, PluginError):
            text = "unknown"
        role = path.split(".", 1)[0]
        for stage in STAGES if role in _CONTEXT_ROLES else (role,):
            uses[stage][f"{kind}:{ref.name}"] = text
    framework = package_digest("mocap")[:16]
    return {stage: {**found, "framework": framework} for stage, found in uses.items()}


def key_change(old: dict[str, Any], new: dict[str, Any]) -> str:
    """Why a stage's key moved, in words, from the ``key.json`` of its earlier artifact and its
    material now (:func:`stage_materials`): e.g. ``"the code of latent:pulse changed (mocap 0.1.0
    1a2b… -> 3c4d…)"``."""
    reasons: list[str] = []
    if old.get("section") != new.get("section"):
        reasons.append("its spec section changed")
    old_ctx, new_ctx = old.get("context") or {}, new.get("context") or {}
    for name in sorted(set(old_ctx) | set(new_ctx)):
        if old_ctx.get(name) != new_ctx.get(name):
            reasons.append("the motion files changed" if name == "motion_inputs" else f"the {name} section changed")
    old_code, new_code = old.get("code") or {}, new.get("code") or {}
    for name in sorted(set(old_code) | set(new_code)):
        a, b = old_code.get(name), new_code.get(name)
        if a != b:
            what = "mocap itself" if name == "framework" else name
            reasons.append(f"the code of {what} changed ({a or 'not recorded'} -> {b or 'not used'})")
    if old.get("upstream") != new.get("upstream"):
        reasons.append("a stage upstream of it changed")
    return "; ".join(reasons) or "its key format changed"


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
    """:func:`stage_keys` with the motion files' and the code's fingerprints: the keys every command uses."""
    return stage_keys(resolved.spec, motion_fingerprint(resolved, plugins), stage_code(resolved.spec, plugins))


def resolved_stage_materials(resolved: ResolvedSpec, plugins: PluginSet) -> dict[str, dict[str, Any]]:
    """What :func:`resolved_stage_keys` hashes, per stage."""
    return stage_materials(resolved.spec, motion_fingerprint(resolved, plugins), stage_code(resolved.spec, plugins))


def _is_file(path: Path) -> bool:
    """``path.is_file()``, False for a path the OS cannot even look up (a name over 255 bytes)."""
    try:
        return path.is_file()
    except OSError:
        return False


def earlier_keys(out_dir: Path) -> dict[str, str]:
    """The stage keys of this run directory's earlier run (its ``stages.json``; {} when none or unreadable)."""
    try:
        data = json.loads((out_dir / "stages.json").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return {}
    if not isinstance(data, list):
        return {}
    return {str(r["stage"]): str(r["key"]) for r in data if isinstance(r, dict) and isinstance(r.get("stage"), str) and isinstance(r.get("key"), str)}


def why_new_key(store: Path, stage: str, old_key: str | None, material: dict[str, Any]) -> str:
    """:func:`key_change` against the ``key.json`` of the stage's earlier artifact."""
    try:
        old = json.loads((store / f"{stage}-{old_key}" / KEY_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return f"its key changed ({old_key} -> {material_key(material)}; the earlier artifact records no {KEY_FILE})"
    return key_change(old if isinstance(old, dict) else {}, material)
