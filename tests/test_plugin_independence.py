"""Plugins stand alone (issue 24): no built-in plugin imports another plugin; what two plugins
share lives in core. The AST of every module under plugins/ is walked, lazy imports included."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: cross-plugin imports still to be moved into core (each a named, open item of issue 24)
KNOWN = {
    # mujoco_warp builds the mujoco plugin's MJCF, params and renderer: the MJCF builder, the terrain
    # helpers and the renderer move to core together
    ("mocap_sim_mujoco_warp", "mocap_sim_mujoco"),
    # the terrain task reads the mujoco plugin's TerrainParams and height_map (terrain helpers -> core)
    ("mocap_tasks", "mocap_sim_mujoco"),
}


def _packages() -> dict[str, str]:
    dirs = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    return {name: folder for name, folder in dirs.items() if folder.startswith("plugins/")}


def cross_plugin_imports() -> set[tuple[str, str, str]]:
    packages = _packages()
    found = set()
    for name, folder in packages.items():
        for path in (REPO / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                targets = []
                if isinstance(node, ast.Import):
                    targets = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    targets = [node.module]
                for t in targets:
                    top = t.split(".")[0]
                    if top in packages and top != name:
                        found.add((name, top, str(path.relative_to(REPO))))
    return found


def test_no_plugin_imports_another_plugin():
    found = cross_plugin_imports()
    unexpected = sorted(f for f in found if (f[0], f[1]) not in KNOWN)
    assert not unexpected, f"cross-plugin imports (move the shared piece into core): {unexpected}"


def test_the_known_exceptions_are_still_real():
    """An exception that no longer occurs must leave KNOWN (so the list cannot go stale)."""
    pairs = {(a, b) for a, b, _ in cross_plugin_imports()}
    assert KNOWN <= pairs, f"remove from KNOWN: {sorted(KNOWN - pairs)}"


def test_core_never_imports_a_plugin():
    packages = _packages()
    for path in (REPO / "core").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            mods = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            for m in mods:
                assert m.split(".")[0] not in packages, f"{path.relative_to(REPO)} imports {m}"


def test_every_built_in_task_factory_takes_the_documented_signature(amp):
    """register_tasks' docstring is the contract: factory(params, *, skeleton, num_envs, device[, motions])."""
    import inspect

    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins

    plugins = get_plugins()
    lib = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk", "kick"])).load(amp), amp)
    names = plugins.names("task")
    assert {"speed", "reach", "strike", "vr_tracking", "motion_tracking"} <= set(names)
    for name in names:
        comp = plugins.get("task", name)
        accepts_motions = "motions" in inspect.signature(comp.resolved_factory()).parameters
        extra = {"motions": lib} if accepts_motions else {}
        task = comp.build(comp.validate_params({}), skeleton=amp, num_envs=2, device="cpu", **extra)
        assert task is not None, name
