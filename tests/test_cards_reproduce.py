"""Issue 23's "Done when": `mocap eval` and `mocap generate` of each canonical checkpoint reproduce the
numbers its model card quotes, which are the committed ``eval.json`` / ``generation.json`` beside it.

Slow (about 80 s on 2 idle cores): it runs the CLI the card names, as a user would, into a temporary
directory, and compares every number of the fresh JSON with the committed one. A retrained or edited
checkpoint whose files were not regenerated fails here, naming up to 20 of the numbers that differ."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

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
    diff = differences(json.loads(out.read_text()), json.loads((ROOT / committed).read_text()))
    assert not diff, f"{target}: `mocap {command}` no longer gives {committed}:\n" + "\n".join(diff[:20])
