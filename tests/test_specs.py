"""Every spec shipped in specs/ (and the example plugin's, where its plugin is installed) validates."""

from __future__ import annotations

from pathlib import Path

import pytest

from mocap.plugins import get_plugins
from mocap.spec import load_spec

ROOT = Path(__file__).resolve().parents[1]
SPECS = sorted((ROOT / "specs").rglob("*.yaml"))


def test_there_are_specs():
    assert {p.name for p in SPECS} >= {"quickstart.yaml", "amp_bundled.yaml", "phc_plus_smpl.yaml"}


@pytest.mark.parametrize("path", SPECS, ids=[str(p.relative_to(ROOT)) for p in SPECS])
def test_shipped_spec_validates(path: Path):
    resolved = load_spec(path, get_plugins())
    assert resolved.spec.name
