"""Fuzzing what users hand to mocap (issue 25): every shipped spec mutated, DeepMimic motion files
and checkpoints with damaged bytes. Only two outcomes are allowed: a valid result, or one clean
error (exit code 2 / the documented error class) with no traceback. The default profile is short;
``pytest -m slow tests/test_fuzz.py`` runs the long one (``FUZZ_EXAMPLES``, default 2000 per test)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap.cli import main

REPO = Path(__file__).resolve().parents[1]
SPECS = sorted(p for p in REPO.glob("specs/**/*.yaml"))
QUICK = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
LONG = settings(
    max_examples=int(os.environ.get("FUZZ_EXAMPLES", "2000")),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

NASTY: list[Any] = [None, -1, 0, 1e308, -1e308, float("nan"), 10**400, "x" * 300, "../../etc", [], {}, True, [[[]]], {"name": "nope"}]


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:3]):
            out += _paths(v, prefix + (i,))
    return out


def _set(doc: Any, path: tuple, value: Any, delete: bool) -> Any:
    if not path:
        return value
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    if delete and isinstance(parent, dict):
        parent.pop(path[-1], None)
    else:
        parent[path[-1]] = value
    return doc


def _mutated_spec(data: st.DataObject, tmp_path: Path) -> Path:
    src = data.draw(st.sampled_from(SPECS), label="spec")
    doc = yaml.safe_load(src.read_text())
    if isinstance(doc, dict) and isinstance(doc.get("extends"), str):
        doc["extends"] = str((src.parent / doc["extends"]).resolve())
    path = data.draw(st.sampled_from(_paths(doc)), label="path")
    kind = data.draw(st.sampled_from(["value", "delete", "unknown", "deep"]), label="kind")
    if kind == "unknown" and isinstance(doc, dict):
        doc["totally_unknown_" + data.draw(st.text("abc", min_size=1, max_size=3))] = 1
    elif kind == "deep":
        deep: Any = 1
        for _ in range(data.draw(st.integers(40, 80))):
            deep = [deep]
        doc = _set(doc, path, deep, False)
    else:
        doc = _set(doc, path, data.draw(st.sampled_from(NASTY), label="value"), kind == "delete")
    out = tmp_path / "mutated.yaml"
    try:
        out.write_text(yaml.safe_dump(doc, sort_keys=False))
    except RecursionError:
        out.write_text("spec_version: 1\nname: x\n")
    return out


def _validate_cleanly(path: Path, capsys: Any) -> None:
    rc = main(["validate", str(path)])
    err = capsys.readouterr().err
    assert rc in (0, 2), err
    assert "Traceback" not in err


@QUICK
@given(data=st.data())
def test_mutated_shipped_specs_validate_or_fail_cleanly(data, tmp_path, capsys):
    _validate_cleanly(_mutated_spec(data, tmp_path), capsys)


@pytest.mark.slow
@LONG
@given(data=st.data())
def test_mutated_shipped_specs_long(data, tmp_path, capsys):
    _validate_cleanly(_mutated_spec(data, tmp_path), capsys)


def _damaged(data: st.DataObject, raw: bytes) -> bytes:
    kind = data.draw(st.sampled_from(["truncate", "flip", "insert", "zero"]))
    n = len(raw)
    i = data.draw(st.integers(0, max(0, n - 1)))
    if kind == "truncate":
        return raw[:i]
    if kind == "flip":
        return raw[:i] + bytes([raw[i] ^ data.draw(st.integers(1, 255))]) + raw[i + 1 :] if n else raw
    if kind == "insert":
        return raw[:i] + data.draw(st.binary(min_size=1, max_size=64)) + raw[i:]
    return raw[:i] + b"\x00" * min(64, n - i) + raw[i + 64 :]


@QUICK
@given(data=st.data())
def test_damaged_motion_files_load_or_fail_cleanly(data, tmp_path, amp):
    from mocap.motion.clip import MotionDataError
    from mocap.motion.deepmimic import default_data_dir, load_deepmimic_file

    raw = (Path(default_data_dir()) / "humanoid3d_walk.txt").read_bytes()
    path = tmp_path / "walk.txt"
    path.write_bytes(_damaged(data, raw))
    try:
        clip = load_deepmimic_file(path, amp)
    except MotionDataError:
        return
    assert clip.num_frames >= 2


@QUICK
@given(data=st.data())
def test_damaged_checkpoints_load_or_fail_cleanly(data, tmp_path):
    from mocap.checkpoint import CheckpointError, load_checkpoint

    raw = (REPO / "checkpoints" / "pulse_amp" / "latent.pt").read_bytes()
    path = tmp_path / "latent.pt"
    path.write_bytes(_damaged(data, raw))
    try:
        out = load_checkpoint(path)
    except CheckpointError:
        return
    assert isinstance(out, dict)


# ------------------------------------------------------------------ issue 63: checkpoints, motion files and CLI options
#: outcomes per family (exit code or "clip" / "refused"), printed at the end of the module (``-s``)
OUTCOMES: dict[str, dict[Any, int]] = {}


def _tally(family: str, outcome: Any) -> None:
    counts = OUTCOMES.setdefault(family, {})
    counts[outcome] = counts.get(outcome, 0) + 1


@pytest.fixture(scope="module", autouse=True)
def _report_outcomes():
    yield
    for family, counts in sorted(OUTCOMES.items()):
        print(f"\nfuzz {family}: {sum(counts.values())} examples, outcomes {dict(sorted(counts.items(), key=str))}")


class _Reached(Exception):
    """Raised by the stubbed evaluation: every check before it passed."""


@pytest.fixture(scope="module")
def amp_policy_file(tmp_path_factory) -> Path:
    from test_bad_input import _amp_policy

    return _amp_policy(tmp_path_factory.mktemp("fuzz_policy") / "policy.pt")


def _stub_evaluation(monkeypatch: Any) -> None:
    """``mocap eval`` stops where the rollouts would start (a user error, exit 2, with a known text)."""
    import mocap.imitation_eval
    from mocap.errors import UserError

    def reached(*args: Any, **kwargs: Any) -> None:
        raise UserError("fuzz: reached the evaluation")

    monkeypatch.setattr(mocap.imitation_eval, "evaluate_imitator", reached)


def _run_cleanly(argv: list[str], capsys: Any, family: str) -> None:
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc in (0, 2), err
    assert "Traceback" not in err
    _tally(family, "evaluated" if "fuzz: reached the evaluation" in err else rc)


def _nasty_tensor(data: st.DataObject, like: Any) -> Any:
    import torch

    kind = data.draw(st.sampled_from(["nan", "inf", "huge", "bool", "complex", "int", "shape", "empty", "negative"]), label="tensor")
    if kind == "bool":
        return like.to(torch.bool)
    if kind == "complex":
        return like.to(torch.complex64)
    if kind == "int":
        return like.to(torch.int64)
    if kind == "shape":
        return torch.zeros(data.draw(st.integers(0, 5)), data.draw(st.integers(1, 5)))
    if kind == "empty":
        return torch.zeros(0)
    value = {"nan": float("nan"), "inf": float("inf"), "huge": 1e38, "negative": -1.0}[kind]
    return like.clone().fill_(value)


def _mutated_policy(data: st.DataObject, source: Path, tmp_path: Path) -> Path:
    import torch

    policy = torch.load(source, weights_only=True)
    where = data.draw(st.sampled_from(["top", "config", "state_dict", "space"]), label="where")
    if where == "top":
        key = data.draw(st.sampled_from([*policy, "unknown"]), label="key")
        if data.draw(st.booleans(), label="delete"):
            policy.pop(key, None)
        else:
            policy[key] = data.draw(st.sampled_from(NASTY), label="value")
    elif where == "config":
        config = dict(policy["config"])
        config[data.draw(st.sampled_from([*config, "unknown"]), label="key")] = data.draw(st.sampled_from(NASTY), label="value")
        policy["config"] = config
    elif where == "space":
        space = dict(policy["config"]["action_space"])
        space[data.draw(st.sampled_from([*space, "unknown"]), label="key")] = data.draw(st.sampled_from(NASTY), label="value")
        policy["config"] = {**policy["config"], "action_space": space}
    else:
        state = dict(policy["state_dict"])
        key = data.draw(st.sampled_from(sorted(k for k, v in state.items() if isinstance(v, torch.Tensor))), label="key")
        state[key] = _nasty_tensor(data, state[key])
        policy["state_dict"] = state
    path = tmp_path / "policy.pt"
    torch.save(policy, path)
    return path


@pytest.mark.slow
@LONG
@given(data=st.data())
def test_mutated_policy_files_evaluate_or_fail_cleanly(data, tmp_path, capsys, monkeypatch, amp_policy_file):
    _stub_evaluation(monkeypatch)
    _run_cleanly(["eval", _mutated_policy(data, amp_policy_file, tmp_path), "--num-envs", "2"], capsys, "policy files")


def _amass_file(data: st.DataObject, tmp_path: Path) -> Path:
    import numpy as np

    frames = data.draw(st.sampled_from([0, 1, 2, 8]), label="frames")
    arrays: dict[str, Any] = {"poses": np.zeros((frames, 72)), "trans": np.zeros((frames, 3)), "mocap_framerate": np.array(120.0), "betas": np.zeros(16)}
    key = data.draw(st.sampled_from([*arrays, "mocap_frame_rate"]), label="array")
    kind = data.draw(st.sampled_from(["value", "dtype", "shape", "delete"]), label="kind")
    if kind == "delete":
        arrays.pop(key, None)
    elif kind == "dtype":
        dtype = data.draw(st.sampled_from(["float32", "int64", "bool", "complex128", "U3", "uint8"]), label="dtype")
        arrays[key] = np.asarray(arrays.get(key, np.array(120.0))).astype(dtype)
    elif kind == "shape":
        arrays[key] = np.zeros(tuple(data.draw(st.lists(st.integers(0, 80), max_size=3), label="shape")))
    else:
        value = data.draw(st.sampled_from([float("nan"), float("inf"), 1e300, -1e300, 1e-300, 0.0, 1e12, -5.0]), label="value")
        arrays[key] = np.full(np.shape(arrays.get(key, np.array(0.0))), value)
    path = tmp_path / "clip.npz"
    (np.savez_compressed if data.draw(st.booleans(), label="compressed") else np.savez)(path, **arrays)
    if data.draw(st.booleans(), label="damaged"):
        path.write_bytes(_damaged(data, path.read_bytes()))
    return path


def _deepmimic_file(data: st.DataObject, tmp_path: Path) -> Path:
    import json

    from mocap.motion.deepmimic import default_data_dir

    doc = json.loads((Path(default_data_dir()) / "humanoid3d_walk.txt").read_text())
    value = data.draw(st.sampled_from([*NASTY, "0.0333", 1e-12, 1e12, 1e300, float("inf")]), label="value")
    where = data.draw(st.sampled_from(["cell", "column", "frames", "loop", "row"]), label="where")
    frames = doc["Frames"]
    if where == "cell":
        frames[data.draw(st.integers(0, len(frames) - 1))][data.draw(st.integers(0, 43))] = value
    elif where == "column":
        col = data.draw(st.integers(0, 43), label="column")
        for row in frames:
            row[col] = value
    elif where == "frames":
        doc["Frames"] = value
    elif where == "loop":
        doc["Loop"] = value
    else:
        frames[data.draw(st.integers(0, len(frames) - 1))] = value
    path = tmp_path / "humanoid3d_fuzz.txt"
    path.write_text(json.dumps(doc, allow_nan=True))
    return path


def _load_motion_cleanly(data: st.DataObject, tmp_path: Path, amp: Any, smpl: Any) -> None:
    from mocap.motion.amass import load_amass_file
    from mocap.motion.clip import MotionDataError
    from mocap.motion.deepmimic import load_deepmimic_file

    amass = data.draw(st.booleans(), label="amass")
    try:
        clip = load_amass_file(_amass_file(data, tmp_path), smpl) if amass else load_deepmimic_file(_deepmimic_file(data, tmp_path), amp)
    except MotionDataError:
        _tally("motion files", "refused")
        return
    _tally("motion files", "clip")
    assert clip.num_frames >= 2


@QUICK
@given(data=st.data())
def test_odd_motion_files_load_or_fail_cleanly(data, tmp_path, amp, smpl):
    _load_motion_cleanly(data, tmp_path, amp, smpl)


@pytest.mark.slow
@LONG
@given(data=st.data())
def test_odd_motion_files_long(data, tmp_path, amp, smpl):
    _load_motion_cleanly(data, tmp_path, amp, smpl)


OPTION_VALUES = ["0", "-3", "1", "nan", "inf", "-inf", "1e308", "", "x" * 300, "../..", "/dev/full", "/proc/x.json", "a,b", "walk,runn", "\udcff"]


@pytest.mark.slow
@LONG
@given(data=st.data())
def test_cli_options_run_or_fail_cleanly(data, tmp_path, capsys, monkeypatch, amp_policy_file):
    _stub_evaluation(monkeypatch)
    value = data.draw(st.sampled_from(OPTION_VALUES), label="value")
    command = data.draw(st.sampled_from(["eval", "validate", "motions"]), label="command")
    if command == "eval":
        option = data.draw(st.sampled_from(["--num-envs", "--loop", "--json", "--video", "--motions"]), label="option")
        argv = ["eval", amp_policy_file, option, value if option != "--json" else tmp_path / value if value and "/" not in value else value]
    elif command == "validate":
        spec = data.draw(st.sampled_from(SPECS), label="spec")
        keys = ["seed", "name", "imitator.trainer.params.horizon", "simulator.params.num_envs", "a." * 70 + "b", "motions.params.clips"]
        key = data.draw(st.sampled_from(keys), label="key")
        argv = ["validate", spec, "--set", f"{key}={value}"]
    else:
        option = data.draw(st.sampled_from(["--source", "--clip", "--path", "--humanoid"]), label="option")
        argv = ["motions", "list", option, value]
    _run_cleanly(argv, capsys, "cli options")
