"""Plugin code in the stage keys (issue 66): editing a plugin's source, or installing another version
of it, trains again exactly the stages that use it; the run says why; checkpoints record the code.

The plugin under test is a temporary *editable install*: its source folder on ``sys.path`` beside a
``.dist-info`` whose ``direct_url.json`` marks it editable and whose entry point registers it in the
``mocap`` group, which is what ``pip install -e`` of a plugin package leaves behind.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from rich.console import Console
from toy_plugins import TOY_SPEC, CountTrainer, toy

from mocap.checkpoint import load_checkpoint
from mocap.fingerprint import forget_package_digests, package_digest
from mocap.pipeline import run_pipeline
from mocap.plugins import PluginSet, load_plugins, set_plugins
from mocap.spec import load_spec_text

PLUGIN_SOURCE = '''\
"""A latent space in a package of its own (the test edits this file)."""
from pydantic import BaseModel, ConfigDict

from mocap.hooks import hookimpl


class EditedParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    hidden: int = 8


class EditedLatent:
    def __init__(self, params=None, **kwargs):
        self.params = params


@hookimpl
def register_latent_spaces(register):
    register("edited_latent", EditedLatent, params=EditedParams)
'''


def _install(root: Path, version: str) -> Path:
    """An editable install of ``mocap_edited`` ``version`` under ``root`` (put ``root`` on sys.path)."""
    pkg = root / "src" / "mocap_edited"
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / "__init__.py").write_text("")
    if not (pkg / "plugin.py").exists():
        (pkg / "plugin.py").write_text(PLUGIN_SOURCE)
    info = root / "src" / "mocap_edited-0.dist-info"
    for old in (root / "src").glob("mocap_edited-*.dist-info"):
        for f in old.iterdir():
            f.unlink()
        old.rmdir()
    info = root / "src" / f"mocap_edited-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: mocap-edited\nVersion: {version}\n")
    (info / "entry_points.txt").write_text("[mocap]\nedited = mocap_edited.plugin\n")
    (info / "direct_url.json").write_text(json.dumps({"url": (root / "src").as_uri(), "dir_info": {"editable": True}}))
    return pkg / "plugin.py"


def _plugins() -> PluginSet:
    """What a new ``mocap`` process sees: fresh code digests, the entry points on sys.path."""
    forget_package_digests()
    for name in [m for m in sys.modules if m == "mocap_edited" or m.startswith("mocap_edited.")]:
        del sys.modules[name]
    pset = load_plugins([("toy", toy)])
    assert "edited_latent" in pset.components["latent"], [f.line() for f in pset.failures]
    set_plugins(pset)  # the process-wide set, as in `mocap run` (checkpoints record its provenance)
    return pset


def _run(out: Path, pset: PluginSet) -> list:
    CountTrainer.calls.clear()
    spec = load_spec_text(TOY_SPEC.replace("name: toy_latent", "name: edited_latent"), pset)
    return run_pipeline(spec, pset, out, console=Console(file=open("/dev/null", "w")))


@pytest.fixture
def editable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.syspath_prepend(str(tmp_path / "src"))
    yield tmp_path
    set_plugins(None)  # the next get_plugins() loads the installed plugins again
    forget_package_digests()
    for name in [m for m in sys.modules if m.startswith("mocap_edited")]:
        del sys.modules[name]


def test_editing_a_plugins_source_retrains_exactly_the_stages_that_use_it(editable: Path) -> None:
    source = _install(editable, "1.0")
    out = editable / "runs" / "r"
    first = _run(out, _plugins())
    assert [r.reused for r in first] == [False, False] and CountTrainer.calls == ["imitator", "latent"]
    assert _run(out, _plugins()) and CountTrainer.calls == []  # nothing changed: everything reused

    source.write_text(source.read_text() + "\n# the author edits the latent space\n")
    edited = _run(out, _plugins())
    assert CountTrainer.calls == ["latent"]  # the imitator does not use the plugin
    assert edited[0].key == first[0].key and edited[1].key != first[1].key
    assert edited[1].why and "the code of latent:edited_latent changed (mocap-edited==1.0" in edited[1].why
    assert "latent trained again: the code of latent:edited_latent changed" in (out / "report.md").read_text()
    assert json.loads((out / "stages.json").read_text())[1]["retrained_because"] == edited[1].why
    # the trained checkpoint records the plugin's code, as every checkpoint does
    recorded = load_checkpoint(edited[1].result.checkpoint)["components"]["latent:edited_latent"]
    assert recorded["package"] == "mocap-edited" and recorded["version"] == "1.0" and len(recorded["code"]) == 16

    _install(editable, "1.1")  # a version bump, same source
    bumped = _run(out, _plugins())
    assert CountTrainer.calls == ["latent"] and bumped[0].key == first[0].key
    assert bumped[1].why and "mocap-edited==1.0" in bumped[1].why and "mocap-edited==1.1" in bumped[1].why


def test_package_digest_follows_the_source_files_not_their_byte_code(editable: Path) -> None:
    source = _install(editable, "1.0")
    before = package_digest("mocap_edited")
    cache = source.parent / "__pycache__"
    cache.mkdir()
    (cache / "plugin.cpython-311.pyc").write_bytes(b"\0" * 16)
    forget_package_digests()
    assert package_digest("mocap_edited") == before
    (source.parent / "extra.py").write_text("X = 1\n")
    forget_package_digests()
    assert package_digest("mocap_edited") != before
    assert package_digest("no_such_package_here") == "unlocated"


def test_eval_of_a_checkpoint_says_in_one_line_when_other_code_made_it(tmp_path: Path) -> None:
    """``mocap eval`` loads targets through :func:`load_evaluation_target` and prints its ``code_note``
    after its results: a committed checkpoint from before fingerprints still loads and says it has
    none; a recorded fingerprint that matches the installed code gives no note; one that differs
    names the component."""
    from mocap.checkpoint import save_checkpoint
    from mocap.eval_targets import code_difference, load_evaluation_target
    from mocap.plugins import get_plugins

    root = Path(__file__).resolve().parents[1]
    committed = root / "checkpoints" / "imitator" / "policy.pt"
    target = load_evaluation_target(committed, get_plugins())  # loads: the fingerprint may be absent
    assert target.imitator_checkpoint == committed
    assert target.code_note is not None and "records no plugin code fingerprint" in target.code_note

    data = dict(load_checkpoint(committed))
    data.pop("components", None)
    data.pop("versions", None)
    same = tmp_path / "same.pt"
    save_checkpoint(same, data)  # records the installed code now
    assert load_evaluation_target(same, get_plugins()).code_note is None

    recorded = load_checkpoint(same)["components"]
    recorded["imitator:phc"] = {**recorded["imitator:phc"], "code": "0123456789abcdef"}
    line = code_difference(recorded, target.resolved, get_plugins())
    assert line is not None and "imitator:phc" in line and "0123456789abcdef" in line and "\n" not in line
    assert code_difference(load_checkpoint(same)["components"], target.resolved, get_plugins()) is None


def test_mocap_eval_prints_the_note_after_its_results(tmp_path: Path) -> None:
    """The whole command on a committed checkpoint, 15 clips, about 5 s: results, then one note line."""
    from mocap.testing import invoke

    result = invoke(["eval", str(Path(__file__).resolve().parents[1] / "checkpoints" / "imitator" / "policy.pt")])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("note:")]
    assert len(lines) == 1 and "records no plugin code fingerprint" in lines[0]
