"""Issue 23's "Done when", as issue 63 words it: `mocap eval` and `mocap generate` of each canonical
checkpoint reproduce the numbers its model card quotes (the committed ``eval.json`` /
``generation.json`` beside it) **within their intervals**.

Physics is chaotic: another CPU's float path gives other trajectories, so a re-run elsewhere lands near
the committed numbers, not on their digits. Each committed file carries ``ci95``: the 95% interval of
every aggregate over the clips (Wilson for the success rate, bootstrap for the mean errors) or the
rollouts (Wilson for shares, bootstrap for times and diversity, mean ± 1.96 std / √rollouts for the match
distance). The test passes when every fresh aggregate lies inside the committed interval and the
protocol fields (clip set, counts, parameters, start clips) are the same; per-clip and per-rollout
numbers (single episodes) are not compared. ``MOCAP_CARDS_EXACT=1`` also demands every digit: what the
same machine and build give (bit-exact).

Slow (about 80 s on 2 idle cores): it runs the CLI the card names, as a user would, into a temporary
directory."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mocap.intervals import inside

ROOT = Path(__file__).resolve().parents[1]

# (command, checkpoint argument, committed JSON): the commands the model cards print
CARDS = [
    ("eval", "checkpoints/imitator/policy.pt", "checkpoints/imitator/eval.json"),
    ("eval", "checkpoints/pulse", "checkpoints/pulse/eval.json"),
    ("eval", "checkpoints/hybrid_rvq", "checkpoints/hybrid_rvq/eval.json"),
    ("eval", "checkpoints/vmp", "checkpoints/vmp/eval.json"),
    ("generate", "checkpoints/pulse", "checkpoints/pulse/generation.json"),
    ("generate", "checkpoints/hybrid_rvq", "checkpoints/hybrid_rvq/generation.json"),
    ("generate", "checkpoints/vmp", "checkpoints/vmp/generation.json"),
]

# keys that name where or when a file was written, not what was measured
UNMEASURED = {"checkpoint", "video", "wall_s", "command"}


def numbers(node: object, path: str = "") -> dict[str, float]:
    """Every number in a JSON tree, keyed by its path (``a/b/3``); booleans count as 0/1."""
    out: dict[str, float] = {}
    if isinstance(node, dict):
        for key, value in node.items():
            if key not in UNMEASURED:
                out.update(numbers(value, f"{path}/{key}"))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out.update(numbers(value, f"{path}/{i}"))
    elif isinstance(node, (int, float)):
        out[path] = float(node)
    return out


def differences(fresh: object, committed: object, rel: float = 1e-4) -> list[str]:
    """Sorted paths whose numbers differ beyond ``rel`` or exist on one side only."""
    a, b = numbers(fresh), numbers(committed)
    out = [f"{k}: missing from the fresh run" for k in b if k not in a]
    out += [f"{k}: not in the committed file" for k in a if k not in b]
    for k in b.keys() & a.keys():
        x, y = a[k], b[k]
        if not (math.isnan(x) and math.isnan(y)) and not math.isclose(x, y, rel_tol=rel, abs_tol=1e-9):
            out.append(f"{k}: {x!r} now, {y!r} committed")
    return sorted(out)


#: fields that describe the protocol, not a measurement: equal on every machine
PROTOCOL_FIELDS = ("protocol", "fps", "horizon", "units", "num_rollouts", "seconds", "params", "start_clips", "dataset_transitions", "generated_transitions")


def outside(fresh: dict, committed: dict, where: str = "") -> list[str]:
    """What of ``fresh`` does not reproduce ``committed`` within its intervals (module docstring)."""
    out = []
    for key in PROTOCOL_FIELDS:
        if key in committed and fresh.get(key) != committed[key]:
            out.append(f"{where}/{key}: {str(fresh.get(key))[:80]!r} now, {str(committed[key])[:80]!r} committed (protocol)")
    if "clips" in committed and sorted(fresh.get("clips", {})) != sorted(committed["clips"]):
        out.append(f"{where}/clips: another clip set")
    values, old = fresh.get("aggregate", fresh), committed.get("aggregate", committed)
    if "total" in old and values.get("total") != old["total"]:
        out.append(f"{where}/aggregate/total: {values.get('total')} now, {old['total']} committed")
    for key, interval in sorted(committed.get("ci95", {}).items()):
        value = values.get(key)
        if not isinstance(value, (int, float)) or not inside(float(value), interval):
            out.append(f"{where}/{key}: {value!r} now, outside the committed 95% interval [{interval[0]:.6g}, {interval[1]:.6g}] (committed {old.get(key)!r})")
    if "imitator" in committed and isinstance(committed["imitator"], dict):
        out += outside(fresh.get("imitator") or {}, committed["imitator"], f"{where}/imitator")
    return sorted(out)


def test_outside_passes_a_rerun_inside_the_intervals_and_fails_one_outside():
    committed = {
        "protocol": "p",
        "aggregate": {"success_rate": 14 / 15, "succeeded": 14, "total": 15, "mpjpe_g": 101.1},
        "ci95": {"success_rate": [0.70, 0.99], "mpjpe_g": [81.0, 121.0]},
        "clips": {"walk": {"mpjpe_g": 43.9}, "run": {"mpjpe_g": 50.0}},
    }
    drifted = {**committed, "aggregate": {**committed["aggregate"], "mpjpe_g": 100.2, "success_rate": 13 / 15, "succeeded": 13}}
    drifted["clips"] = {"walk": {"mpjpe_g": 40.0}, "run": {"mpjpe_g": 61.0}}  # single episodes: not compared
    assert outside(drifted, committed) == []
    far = {**committed, "aggregate": {**committed["aggregate"], "mpjpe_g": 140.0}}
    assert outside(far, committed) == ["/mpjpe_g: 140.0 now, outside the committed 95% interval [81, 121] (committed 101.1)"]
    few = {**committed, "aggregate": {**committed["aggregate"], "success_rate": 9 / 15, "succeeded": 9}}
    assert [line.split(":")[0] for line in outside(few, committed)] == ["/success_rate"]
    assert outside({**committed, "protocol": "q"}, committed)[0].startswith("/protocol:")
    assert outside({**committed, "clips": {"walk": {}}}, committed) == ["/clips: another clip set"]
    lost = {k: v for k, v in committed.items() if k != "aggregate"}
    assert len(outside(lost, committed)) == 3  # total, mpjpe_g and success_rate are gone


def test_the_committed_cards_carry_intervals_around_their_own_numbers():
    for _, _, committed in CARDS:
        data = json.loads((ROOT / committed).read_text())
        assert data.get("ci95"), committed
        assert outside(data, data) == [], committed


def test_differences_sees_a_changed_number_a_lost_key_and_ignores_paths():
    committed = {"aggregate": {"success": 0.9, "clips": [1, 2]}, "checkpoint": "/a/b", "fall_rate": 0.5}
    assert differences(committed, committed) == []
    assert differences({**committed, "checkpoint": "/elsewhere"}, committed) == []
    assert differences({**committed, "fall_rate": 0.6}, committed) == ["/fall_rate: 0.6 now, 0.5 committed"]
    lost = {"aggregate": {"success": 0.9, "clips": [1]}, "fall_rate": 0.5}
    assert differences(lost, committed) == ["/aggregate/clips/1: missing from the fresh run"]


@pytest.mark.slow
@pytest.mark.parametrize(("command", "target", "committed"), CARDS, ids=[f"{c}-{Path(j).parent.name}" for c, _, j in CARDS])
def test_a_canonical_checkpoint_reproduces_its_card(tmp_path: Path, command: str, target: str, committed: str):
    out = tmp_path / "fresh.json"
    env = {**os.environ, "OMP_NUM_THREADS": "2", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.run(
        [sys.executable, "-m", "mocap", command, target, "--json", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    fresh, card = json.loads(out.read_text()), json.loads((ROOT / committed).read_text())
    problems = outside(fresh, card)
    assert not problems, f"{target}: `mocap {command}` lands outside {committed}'s intervals:\n" + "\n".join(problems[:20])
    if os.environ.get("MOCAP_CARDS_EXACT") == "1":  # the same machine and build: every digit
        diff = differences(fresh, card)
        assert not diff, f"{target}: `mocap {command}` no longer gives {committed} bit-exactly:\n" + "\n".join(diff[:20])
