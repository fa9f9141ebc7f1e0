"""bench/time_to_skill.py keeps what an interrupted run produced: the snapshot list is written as
each snapshot is taken, and an evaluation already next to a snapshot is reused, not redone."""

from __future__ import annotations

import importlib.util
import json
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load():
    spec = importlib.util.spec_from_file_location("time_to_skill", ROOT / "bench" / "time_to_skill.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["time_to_skill"] = mod
    spec.loader.exec_module(mod)
    return mod


tts = _load()


def test_snapshot_list_round_trips_and_says_whether_training_finished(tmp_path: Path) -> None:
    snaps = [{"minutes": 10.2, "env_steps": 1_015_808, "path": str(tmp_path / "snapshot_0001015808" / "ppo.pt")}]
    tts.save_snapshots(tmp_path, snaps, finished=False)
    assert tts.load_snapshots(tmp_path) == (snaps, False)
    tts.save_snapshots(tmp_path, [*snaps, {"minutes": 19.6, "env_steps": 2_031_616, "path": "x"}], finished=True)
    got, finished = tts.load_snapshots(tmp_path)
    assert finished and [s["env_steps"] for s in got] == [1_015_808, 2_031_616]
    assert not (tmp_path / "snapshots.json.tmp").exists()


def _fake_eval(d: Path, succeeded: int) -> None:
    clips = {f"c{i}": {"success": i < succeeded} for i in range(3)}
    (d / "eval.json").write_text(json.dumps({"aggregate": {"succeeded": succeeded, "total": 3, "mpjpe_g_succ": 80.0, "mpjpe_g": 90.0}, "clips": clips}))


def test_evaluate_reuses_an_eval_newer_than_its_snapshot(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    d = tmp_path / "snapshot_0001015808"
    d.mkdir()
    (d / "ppo.pt").write_bytes(b"not a checkpoint")
    _fake_eval(d, succeeded=2)
    calls: list[list[str]] = []
    monkeypatch.setattr(tts.subprocess, "run", lambda cmd, **kw: calls.append(cmd))
    p = tts.evaluate({"minutes": 10.2, "env_steps": 1_015_808, "path": str(d / "ppo.pt")}, tmp_path)
    assert calls == [] and p["clips_tracked"] == 2 and p["tracked"] == ["c0", "c1"] and p["minutes"] == 10.2


def test_evaluate_reruns_when_the_snapshot_is_newer_than_its_eval(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    d = tmp_path / "snapshot_0001015808"
    d.mkdir()
    _fake_eval(d, succeeded=1)
    (d / "ppo.pt").write_bytes(b"not a checkpoint")
    old = (d / "eval.json").stat().st_mtime - 100
    os.utime(d / "eval.json", (old, old))

    def fake_run(cmd, **kw):
        _fake_eval(d, succeeded=3)

    monkeypatch.setattr(tts.subprocess, "run", fake_run)
    p = tts.evaluate({"minutes": 1.0, "env_steps": 5, "path": str(d / "ppo.pt")}, tmp_path)
    assert p["clips_tracked"] == 3


def test_evaluate_only_needs_a_workdir_with_a_snapshot_list(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        tts.main(["--evaluate-only", "--workdir", str(tmp_path)])
