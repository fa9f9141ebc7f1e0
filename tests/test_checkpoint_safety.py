"""Loading a checkpoint never runs code from it (issue 25): every path that reads a checkpoint goes
through :func:`mocap.checkpoint.load_checkpoint`'s restricted load, a crafted pickle payload is
refused with one ``error:`` line, and older checkpoints convert once with an explicit command."""

from __future__ import annotations

import os
import random
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from committed import committed_files

from mocap.checkpoint import CheckpointError, convert_checkpoint, load_checkpoint, save_checkpoint
from mocap.cli import main
from mocap.rng import rng_state, set_rng_state

REPO = Path(__file__).resolve().parents[1]


class _Payload:
    """Unpickling this object runs ``exec``: it writes ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):  # noqa: D105
        return (exec, (f"open({str(self.marker)!r}, 'w').write('pwned')",))


def _evil(tmp_path: Path, name: str = "policy.pt") -> tuple[Path, Path]:
    marker = tmp_path / "PWNED"
    path = tmp_path / "evil" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"format": "mocap.rl.policy/1", "model": {}, "payload": _Payload(marker)}, path)
    return path, marker


def test_the_payload_would_run_on_an_unrestricted_load(tmp_path):
    """The test's own premise: without the restriction the payload does run."""
    path, marker = _evil(tmp_path)
    torch.load(path, weights_only=False)
    assert marker.read_text() == "pwned"


def test_load_checkpoint_refuses_a_pickle_payload(tmp_path):
    path, marker = _evil(tmp_path)
    with pytest.raises(CheckpointError, match=r"refused: the checkpoint names the global \w+\.exec, which mocap does not load") as err:
        load_checkpoint(path)
    assert "convert" not in str(err.value)  # converting would run it: no such advice
    assert not marker.exists()


class _Call:
    """Unpickling this object calls ``func(*args)``."""

    def __init__(self, func, *args):
        self.func, self.args = func, args

    def __reduce__(self):  # noqa: D105
        return (self.func, self.args)


@pytest.mark.parametrize("protocol", [2, 4, 5])
@pytest.mark.parametrize("func, named", [(print, "print"), (os.system, "system")], ids=["print", "os.system"])
def test_a_refused_global_is_named_not_called_corrupt_and_no_torch_warning_shows(tmp_path, capsys, protocol, func, named):
    """Issue 63, newcomer 8 / fuzz 6: a pickle of protocol 4 or 5 fails in torch's restricted
    unpickler before it names the global (``Unsupported operand 149``) and warns about the protocol;
    the user gets "refused" naming the global, and no warning."""
    path = tmp_path / "policy.pt"
    torch.save({"format": "mocap.rl.policy/1", "x": _Call(func, "echo hi")}, path, pickle_protocol=protocol)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(CheckpointError, match=rf"refused: the checkpoint names the global \w+\.{named}, which mocap does not load") as err:
            load_checkpoint(path)
    assert "corrupt" not in str(err.value)
    assert main(["eval", str(path)]) == 2
    stderr = capsys.readouterr().err
    assert "refused: the checkpoint names the global" in stderr and "Warning" not in stderr


def test_converting_an_already_safe_checkpoint_leaves_it_byte_identical(tmp_path, capsys):
    """Issue 63, newcomer 6: ``convert --trust`` of a file that already loads safely says so."""
    path = tmp_path / "policy.pt"
    save_checkpoint(path, {"format": "x/1", "w": torch.arange(3.0)})
    before = path.read_bytes()
    assert main(["checkpoint", "convert", str(path), "--trust"]) == 0
    assert "already loads without running code" in capsys.readouterr().out
    assert path.read_bytes() == before
    assert convert_checkpoint(path) == path and path.read_bytes() == before
    assert main(["checkpoint", "convert", str(path), "--out", str(tmp_path / "copy.pt")]) == 0
    assert (tmp_path / "copy.pt").read_bytes() == before


@pytest.mark.parametrize(
    "argv",
    [
        ["eval", "{ckpt}"],
        ["generate", "{ckpt}"],
        ["export", "{ckpt}", "{tmp}/exported"],
        ["render", "{ckpt}", "--out", "{tmp}/x.mp4"],
        ["recover", "{ckpt}"],
        ["eval-noisy", "{ckpt}"],
    ],
    ids=lambda a: a[0],
)
def test_commands_given_a_crafted_checkpoint_never_run_it(tmp_path, capsys, argv, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path, marker = _evil(tmp_path, "latent.pt" if argv[0] == "generate" else "policy.pt")
    rc = main([a.format(ckpt=path, tmp=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert not marker.exists()
    assert "Traceback" not in err and "error:" in err


def test_a_spec_naming_a_crafted_checkpoint_never_runs_it(tmp_path, capsys):
    path, marker = _evil(tmp_path)
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"extends: {REPO / 'specs/imitator/amp_bundled.yaml'}\nname: evil\nimitator:\n  checkpoint: {path}\n  trainer: null\n")
    rc = main(["eval", str(spec)])
    assert rc == 2 and not marker.exists()
    assert "refused" in capsys.readouterr().err


def test_rng_state_round_trips_and_loads_safely(tmp_path):
    torch.manual_seed(1), np.random.seed(2), random.seed(3)
    state = rng_state()
    first = (torch.rand(3), np.random.rand(3), random.random(), np.random.randn())
    torch.save({"rng": state}, tmp_path / "r.pt")
    loaded = torch.load(tmp_path / "r.pt", weights_only=True)["rng"]
    set_rng_state(loaded)
    again = (torch.rand(3), np.random.rand(3), random.random(), np.random.randn())
    assert torch.equal(first[0], again[0]) and np.array_equal(first[1], again[1])
    assert first[2] == again[2] and first[3] == again[3]


def test_an_older_checkpoint_converts_once_with_trust(tmp_path, capsys):
    """A trainer checkpoint of the previous format (NumPy RNG state inside) is refused with the
    convert hint; `mocap checkpoint convert` needs --trust, then the file loads safely and its
    RNG state restores NumPy's generator exactly."""
    np.random.seed(5)
    old = {"format": "mocap.rl.ppo/1", "rng": {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()},
           "window": np.arange(3.0), "count": np.int64(7)}  # fmt: skip
    expect = np.random.rand(4)
    path = tmp_path / "ppo.pt"
    torch.save(old, path)
    with pytest.raises(CheckpointError, match="mocap checkpoint convert"):
        load_checkpoint(path)
    assert main(["checkpoint", "convert", str(path)]) == 2
    assert "--trust" in capsys.readouterr().err
    assert main(["checkpoint", "convert", str(path), "--trust"]) == 0
    data = load_checkpoint(path)
    assert torch.equal(data["window"], torch.arange(3.0, dtype=torch.float64)) and data["count"] == 7
    set_rng_state(data["rng"])
    assert np.array_equal(np.random.rand(4), expect)


def test_convert_refuses_what_it_cannot_make_safe(tmp_path):
    path = tmp_path / "odd.pt"
    torch.save({"format": "x/1", "obj": Path("somewhere")}, path)
    with pytest.raises(CheckpointError, match="cannot convert"):
        convert_checkpoint(path, tmp_path / "out.pt")
    assert not (tmp_path / "out.pt").exists()


def test_every_committed_checkpoint_loads_safely():
    files = committed_files("checkpoints", "*/*.pt")
    assert files
    for f in files:
        assert isinstance(load_checkpoint(f), dict)


def test_committed_checkpoints_name_their_dependencies_by_relative_path():
    """No committed checkpoint embeds a path of the machine it was trained on; a latent's teacher
    resolves next to it (issue 25: pulse_amp named /work/train/...)."""
    import yaml

    from mocap.eval_targets import load_evaluation_target
    from mocap.plugins import get_plugins

    inside = (REPO / "checkpoints").resolve()
    specs = [(f, load_checkpoint(f).get("spec") or "{}") for f in committed_files("checkpoints", "*/*.pt")]
    specs += [(f, f.read_text()) for f in committed_files("checkpoints", "*/spec.yaml")]
    for f, text in specs:
        doc = yaml.safe_load(text) or {}
        for stage in ("imitator", "latent", "task"):
            ck = (doc.get(stage) or {}).get("checkpoint")
            assert ck is None or not Path(ck).is_absolute(), (f, ck)
            if ck is not None:  # relative to the checkpoint's folder, and inside the repository's checkpoints/
                # (pulse_amp_v4 was first exported from another worktree and named ../../../dist/checkpoints/...)
                resolved = (f.parent / ck).resolve()
                assert resolved.is_relative_to(inside) and resolved.is_file(), (f, ck)
            params = ((doc.get(stage) or {}).get("trainer") or {}).get("params") or {}
            for init in (params.get("init_policy"), params.get("init_latent")):
                if init is not None:  # a continued run names the committed weights it started from
                    resolved = (f.parent / init).resolve()
                    assert not Path(init).is_absolute() and resolved.is_relative_to(inside) and resolved.is_file(), (f, init)
    target = load_evaluation_target(REPO / "checkpoints/pulse_amp_v2/latent.pt", get_plugins())
    assert Path(target.imitator_checkpoint).resolve() == (REPO / "checkpoints/imitator_amp_v2/policy.pt").resolve()


def test_export_rewrites_the_copied_checkpoints_embedded_paths(tmp_path):
    from mocap.export import relative_spec_text

    text = "imitator:\n  name: phc\n  checkpoint: /abs/x/checkpoints/imitator/policy.pt\nlatent:\n  name: pulse\n"
    out = relative_spec_text(text, tmp_path / "dest", root_map=("/abs/x/", str(tmp_path) + "/"))
    assert "checkpoint: ../checkpoints/imitator/policy.pt" in out
    # a continued run's starting policy too (imitator_amp_v5 was trained in another worktree)
    text = "imitator:\n  name: phc\n  trainer:\n    name: ppo\n    params:\n      init_policy: /abs/x/checkpoints/v4/policy.pt\n"
    out = relative_spec_text(text, tmp_path / "dest", root_map=("/abs/x/", str(tmp_path) + "/"))
    assert "init_policy: ../checkpoints/v4/policy.pt" in out


def test_a_checkpoint_names_the_package_of_a_missing_plugin(tmp_path, capsys):
    """Checkpoints record which package registered each component; evaluating one whose imitator's
    plugin is not installed says which package to install, in one line."""
    from mocap.checkpoint import save_checkpoint

    ck = load_checkpoint(Path(__file__).resolve().parents[1] / "checkpoints" / "imitator_amp_v3" / "policy.pt")
    save_checkpoint(tmp_path / "mine.pt", {"format": ck["format"], "x": torch.zeros(1)})
    recorded = load_checkpoint(tmp_path / "mine.pt")["components"]
    assert recorded["imitator:phc"]["package"] == "mocap" and recorded["trainer:ppo"]["plugin"] == "rl"
    foreign = dict(ck)
    foreign["spec"] = ck["spec"].replace("name: phc", "name: phc_foo", 1)
    foreign["components"] = {"imitator:phc_foo": {"plugin": "foo", "package": "mocap-foo", "version": "1.2.0"}}
    save_checkpoint(tmp_path / "foreign.pt", foreign)
    assert main(["eval", str(tmp_path / "foreign.pt")]) != 0
    err = capsys.readouterr().err
    assert "unknown imitator 'phc_foo'" in err and "pip install mocap-foo" in err and "Traceback" not in err
