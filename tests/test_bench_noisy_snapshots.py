"""bench/noisy_snapshots.py: the per-snapshot summary of `mocap eval-noisy` and its input checks."""

from __future__ import annotations

import json

import pytest
from conftest import load_bench


@pytest.fixture(scope="module")
def ns():
    return load_bench("noisy_snapshots")


def _level(clips: dict[str, bool], mpjpe: float = 120.0) -> dict:
    return {
        "level": 1,
        "aggregate": {"succeeded": sum(clips.values()), "total": len(clips), "mpjpe_g": mpjpe},
        "clips": {name: {"success": ok, "mpjpe_g": mpjpe} for name, ok in clips.items()},
    }


def test_summarize_names_the_tracked_clips(ns):
    out = ns.summarize({"levels": [_level({"walk": True, "spin": False, "run": True}, 99.5)]})
    assert out == {"succeeded": 2, "total": 3, "mpjpe_g_mm": 99.5, "tracked": ["run", "walk"]}


def test_summarize_refuses_several_levels_and_inconsistent_counts(ns):
    with pytest.raises(ValueError, match="one noise level"):
        ns.summarize({"levels": [_level({"walk": True}), _level({"walk": False})]})
    bad = _level({"walk": True, "run": False})
    bad["aggregate"]["succeeded"] = 2
    with pytest.raises(ValueError, match="aggregate says 2"):
        ns.summarize({"levels": [bad]})


def test_an_arm_without_snapshots_is_one_error_line(ns, tmp_path):
    with pytest.raises(SystemExit, match="snapshots.json: not found"):
        ns.main(["--arm", f"a={tmp_path}", "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="expected LABEL=WORKDIR"):
        ns.main(["--arm", str(tmp_path), "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="at least one --arm or --checkpoint"):
        ns.main(["--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="at least one noise seed"):
        ns.main(["--arm", f"a={tmp_path}", "--seeds", "", "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="expected integers"):
        ns.main(["--arm", f"a={tmp_path}", "--seeds", "0,x", "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="must be in"):
        ns.main(["--arm", f"a={tmp_path}", "--smooth", "1,0", "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="missing.pt: not found"):
        ns.main(["--checkpoint", f"a={tmp_path / 'missing.pt'}", "--out", str(tmp_path / "x")])
    (tmp_path / "snapshots.json").write_text(json.dumps({"snapshots": []}))
    ns.main(["--arm", f"a={tmp_path}", "--out", str(tmp_path / "x")])
    assert json.loads((tmp_path / "x.json").read_text())["arms"][0]["points"] == []


def test_replot_draws_a_committed_result(ns, tmp_path):
    point = {"env_steps": 1_000_000, "noisy": [{"smooth": 1.0, "succeeded": s} for s in (5, 7)], "clean": {"succeeded": 14}}
    result = {"level": "1", "seeds": [0, 1], "smooth": [1.0], "arms": [{"label": "a", "points": [point]}]}
    src = tmp_path / "r.json"
    src.write_text(json.dumps(result))
    assert ns.main(["--replot", str(src), "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r.png").stat().st_size > 1000
    with pytest.raises(SystemExit, match="not found"):
        ns.main(["--replot", str(tmp_path / "none.json"), "--out", str(tmp_path / "r")])
