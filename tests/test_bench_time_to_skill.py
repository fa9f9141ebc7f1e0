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


def test_eval_motions_evaluates_on_another_source_and_keeps_that_eval_apart(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A subset-trained snapshot (a curriculum phase) is evaluated on all clips with ``--motions``; its
    evaluation on the training clips (eval.json) is neither reused for it nor overwritten."""
    d = tmp_path / "snapshot_0001015808"
    d.mkdir()
    (d / "ppo.pt").write_bytes(b"not a checkpoint")
    _fake_eval(d, succeeded=1)  # the training-clip evaluation, newer than the snapshot
    calls: list[list[str]] = []

    def fake_run(cmd, **kw):
        calls.append(cmd)
        out = Path(cmd[cmd.index("--json") + 1])
        out.write_text(json.dumps({"aggregate": {"succeeded": 3, "total": 3, "mpjpe_g_succ": 70.0, "mpjpe_g": 70.0}, "clips": {}}))

    monkeypatch.setattr(tts.subprocess, "run", fake_run)
    p = tts.evaluate({"minutes": 1.0, "env_steps": 5, "path": str(d / "ppo.pt")}, tmp_path, motions="deepmimic")
    assert len(calls) == 1 and calls[0][-2:] == ["--motions", "deepmimic"]
    assert p["clips_tracked"] == 3 and (d / "eval_on_deepmimic.json").is_file()
    assert json.loads((d / "eval.json").read_text())["aggregate"]["succeeded"] == 1


def test_a_phase_after_another_is_counted_on_from_its_last_snapshot() -> None:
    prev = {"spec": "hard.yaml", "overrides": [], "points": [{"minutes": 10.0, "env_steps": 1_000_000}, {"minutes": 21.0, "env_steps": 2_000_000}]}
    points = [{"minutes": 9.5, "env_steps": 1_000_000, "clips_tracked": 12}]
    phase = {"spec": "all.yaml", "overrides": ["imitator.trainer.params.init_policy=p.pt"], "env_steps": 1_000_000}
    got, phases = tts.chain(prev, points, phase)
    assert [p["env_steps"] for p in got] == [1_000_000, 2_000_000, 3_000_000]
    assert got[-1]["minutes"] == pytest.approx(30.5) and got[-1]["clips_tracked"] == 12
    assert phases == [{"spec": "hard.yaml", "overrides": [], "env_steps": 2_000_000}, phase]
    assert points[0]["env_steps"] == 1_000_000  # the phase's own points are not changed in place
    with pytest.raises(SystemExit, match="no snapshot"):
        tts.chain({"points": []}, points, phase)


def test_after_needs_an_existing_result(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        tts.main(["--after", str(tmp_path / "missing.json"), "--env-steps", "10"])
