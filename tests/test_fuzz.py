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
