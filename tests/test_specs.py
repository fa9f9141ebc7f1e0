"""Every spec shipped in specs/ (and the example plugin's, where its plugin is installed) validates."""

from __future__ import annotations

from pathlib import Path

import pytest

from mocap.matrix import load_cells
from mocap.plugins import get_plugins

ROOT = Path(__file__).resolve().parents[1]
SPECS = sorted((ROOT / "specs").rglob("*.yaml"))


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
