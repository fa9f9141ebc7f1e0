"""Every spec shipped in specs/ (and the example plugin's, where its plugin is installed) validates.

Files whose name starts with ``_`` are partial bases (e.g. specs/tasks/_pulse.yaml): they hold what a
group of specs shares and are only meant to be extended, so they are not validated on their own;
each must be extended by at least one shipped spec."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from mocap.matrix import load_cells
from mocap.plugins import get_plugins

ROOT = Path(__file__).resolve().parents[1]
ALL_YAML = sorted((ROOT / "specs").rglob("*.yaml"))
SPECS = [p for p in ALL_YAML if not p.name.startswith("_")]
BASES = [p for p in ALL_YAML if p.name.startswith("_")]


def test_there_are_specs():
    assert {p.name for p in SPECS} >= {"quickstart.yaml", "amp_bundled.yaml", "phc_smpl.yaml"}


@pytest.mark.parametrize("path", SPECS, ids=[str(p.relative_to(ROOT)) for p in SPECS])
def test_shipped_spec_validates(path: Path):
    cells = load_cells(path, get_plugins())  # every cell of a comparison spec
    assert cells and all(resolved.spec.name for _, resolved in cells)
    for _, resolved in cells:  # stage checkpoints a shipped spec names are committed
        for stage in ("imitator", "latent", "task"):
            section = getattr(resolved.spec, stage)
            if section is not None and section.checkpoint is not None:
                assert Path(section.checkpoint).is_file(), f"{path}: {stage}.checkpoint {section.checkpoint} is missing"


def _extends_chain(path: Path) -> list[Path]:
    """The files ``path`` extends, nearest first (``extends:`` is relative to the file that names it)."""
    chain: list[Path] = []
    while True:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        parent = doc.get("extends") if isinstance(doc, dict) else None
        if not isinstance(parent, str):
            return chain
        path = (path.parent / parent).resolve()
        if path in chain:
            return chain
        chain.append(path)


def test_every_partial_base_is_extended():
    """An orphan ``_*.yaml`` base (no shipped spec extends it, directly or through another base) is dead."""
    assert BASES, "expected the partial bases of specs/tasks/"
    used = {base for spec in SPECS for base in _extends_chain(spec)}
    orphans = [str(p.relative_to(ROOT)) for p in BASES if p.resolve() not in used]
    assert not orphans, f"partial bases no shipped spec extends: {orphans}"


def test_partial_bases_are_not_runnable_alone():
    """A base lacks task.name (or another required field), so it cannot be run by mistake."""
    from mocap.spec import SpecError

    for path in BASES:
        with pytest.raises(SpecError):
            load_cells(path, get_plugins())
