"""The quickstart's cells agree with each other: every latent checkpoint was distilled from the very
imitator the quickstart names (its scratch row) and trained on the quickstart's humanoid, so the
comparison in comparison.md is between latent spaces of one teacher; every committed task policy a
cell loads was trained for the cell's task through the cell's own latent space."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import yaml

from mocap.checkpoint import load_checkpoint
from mocap.humanoid_match import embedded_humanoid_params
from mocap.matrix import load_cells
from mocap.plugins import get_plugins

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "specs" / "quickstart.yaml"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def cells():
    return load_cells(QUICKSTART, get_plugins())


def test_every_latent_cell_was_distilled_from_the_quickstarts_imitator(cells):
    latents = 0
    for cell, resolved in cells:
        spec = resolved.spec
        teacher = Path(spec.imitator.checkpoint)
        assert teacher.is_file(), f"{cell.name}: no imitator checkpoint {teacher}"
        if spec.latent.name == "scratch":
            continue
        latents += 1
        latent = Path(spec.latent.checkpoint)
        data = load_checkpoint(latent)
        embedded = yaml.safe_load(data["spec"])
        distilled_from = (latent.parent / embedded["imitator"]["checkpoint"]).resolve()
        assert _sha(distilled_from) == _sha(teacher), f"{cell.name}: {latent} was distilled from {distilled_from}, not {teacher}"
    assert latents >= 2


def test_every_checkpoint_was_trained_on_the_quickstarts_humanoid(cells):
    for cell, resolved in cells:
        spec = resolved.spec
        params = dict(spec.humanoid.params or {}) if not isinstance(spec.humanoid, str) else {}
        files = [Path(spec.imitator.checkpoint)] + ([Path(spec.latent.checkpoint)] if spec.latent.name != "scratch" else [])
        files += [Path(spec.task.checkpoint)] if spec.task.checkpoint is not None else []
        for path in files:
            trained = embedded_humanoid_params(load_checkpoint(path))
            assert trained is not None, f"{cell.name}: {path} embeds no spec"
            assert {k: float(v) if isinstance(v, int | float) else v for k, v in trained.items()} == {
                k: float(v) if isinstance(v, int | float) else v for k, v in params.items()
            }, f"{cell.name}: {path} was trained on humanoid params {trained}, the quickstart runs {params}"


def test_every_committed_task_policy_was_trained_through_its_cells_latent_space(cells):
    policies = 0
    for cell, resolved in cells:
        spec = resolved.spec
        if spec.task.checkpoint is None:  # this cell trains its task policy
            assert spec.task.trainer is not None, f"{cell.name}: neither a task checkpoint nor a trainer"
            continue
        policies += 1
        path = Path(spec.task.checkpoint)
        embedded = yaml.safe_load(load_checkpoint(path)["spec"])
        assert embedded["task"]["name"] == spec.task.name, f"{cell.name}: {path} was trained for {embedded['task']['name']}"
        assert embedded["latent"]["name"] == spec.latent.name, f"{cell.name}: {path} acts through {embedded['latent']['name']}"
        trained_params = embedded["latent"].get("params") or {}
        for key, value in dict(spec.latent.params or {}).items():  # what the cell sets, the policy was trained with
            assert trained_params.get(key) == value, f"{cell.name}: {path} was trained with latent {key}={trained_params.get(key)!r}"
        if spec.latent.name != "scratch":
            through = (path.parent / embedded["latent"]["checkpoint"]).resolve()
            assert _sha(through) == _sha(Path(spec.latent.checkpoint)), f"{cell.name}: {path} was trained through {through}"
    assert policies >= 2
