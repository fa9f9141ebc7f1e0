"""Every committed checkpoint's embedded spec names files that exist: its teacher, the decoder it acts through
and the checkpoint it started from (``checkpoint:``, ``init_latent:``, ``init_policy:``, relative to the file).
Evaluating a ``latent.pt`` or a task policy loads its teacher and decoder through these paths, so a renamed or
removed checkpoint directory must take the embedded specs that name it along."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from mocap.checkpoint import load_checkpoint

ROOT = Path(__file__).resolve().parents[1]
LINK_KEYS = ("checkpoint", "init_latent", "init_policy")


def links(doc, where: str = ""):
    """(where, path) of every string under a key of ``LINK_KEYS`` in a parsed spec."""
    if isinstance(doc, dict):
        for key, value in doc.items():
            if key in LINK_KEYS and isinstance(value, str):
                yield f"{where}.{key}", value
            else:
                yield from links(value, f"{where}.{key}")
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            yield from links(value, f"{where}[{i}]")


def test_links_finds_nested_paths_and_skips_nulls():
    doc = {"imitator": {"checkpoint": "../a/policy.pt"}, "latent": {"checkpoint": None, "trainer": {"params": {"init_latent": "../b/latent.pt"}}}}
    assert sorted(links(doc)) == [(".imitator.checkpoint", "../a/policy.pt"), (".latent.trainer.params.init_latent", "../b/latent.pt")]


@pytest.mark.parametrize("path", sorted((ROOT / "checkpoints").glob("*/*.pt")), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_file_an_embedded_spec_names_exists(path: Path):
    from mocap.realism import JUDGE_FORMAT

    data = load_checkpoint(path)
    if data.get("format") == JUDGE_FORMAT:  # the realism judge is no pipeline model: its card names its command
        assert (path.parent / "MODEL_CARD.md").is_file()
        return
    spec = data.get("spec")
    assert isinstance(spec, str), f"{path}: no embedded spec"
    missing = [(where, p) for where, p in links(yaml.safe_load(spec)) if not (Path(p) if Path(p).is_absolute() else path.parent / p).exists()]
    assert not missing, f"{path.relative_to(ROOT)} names files that are not there: {missing}"
