"""The README's "Using it" block as a newcomer runs it, top to bottom, on tiny budgets.

Every command of the block must be listed in :data:`TINY` (so the README cannot gain a command this
walk skips); each runs in a scratch directory that links the repository's ``specs/`` and
``checkpoints/``, with ``--set`` overrides that shrink training to seconds, and must exit 0 with
no traceback. ``mocap play`` needs a display: without one it must fail with one ``error:`` line.
The walk is slow (several minutes): ``python -m pytest -m slow tests/test_readme.py``.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: every command of the block -> the extra arguments that make it fast (None: run it as written)
TINY: dict[str, list[str] | None] = {
    "mocap plugins": None,
    "mocap validate specs/quickstart.yaml --set seed=3": None,
    "mocap schema --out mocap.schema.json": None,
    "mocap run specs/quickstart.yaml": [
        "--set",
        "task.trainer.params.total_env_steps=1024",
        "--set",
        "motions.params.clips=[walk, run, backflip]",  # the quickstart starts generation in walk and run frames
        "--set",
        "eval.trainer.params.generation.num_rollouts=2",
        "--set",
        "eval.trainer.params.generation.seconds=0.5",
        "--set",
        "eval.trainer.params.generation.video_rollouts=1",
        "--set",
        "eval.trainer.params.generation.video_seconds=0.3",
        "--set",
        "eval.trainer.params.imitation.video_seconds=0.3",
    ],
    "mocap motions list": None,
    "mocap render --motion walk --out walk.mp4": ["--seconds", "0.5"],
    "mocap play checkpoints/pulse": None,  # needs a display: one error line without one
    "mocap render checkpoints/pulse --clip backflip --seconds 2.5 --out pulse_backflip.mp4": ["--seconds", "0.5"],
    "mocap render checkpoints/pulse --generate --out gen.mp4": ["--seconds", "0.5"],
    "mocap run specs/reproduce/bundled.yaml": [
        "--set",
        "matrix.latent=[null]",
        "--set",
        "imitator.trainer.params.num_envs=4",
        "--set",
        "imitator.trainer.params.horizon=8",
        "--set",
        "imitator.trainer.params.total_env_steps=64",
        "--set",
        "imitator.trainer.params.minibatch_size=16",
        "--set",
        "motions.params.clips=[walk]",
        "--set",
        "eval.trainer.params.video=false",
    ],
    "mocap run specs/imitator/amp_bundled.yaml": [
        "--set",
        "imitator.trainer.params.num_envs=4",
        "--set",
        "imitator.trainer.params.horizon=8",
        "--set",
        "imitator.trainer.params.total_env_steps=64",
        "--set",
        "imitator.trainer.params.minibatch_size=16",
        "--set",
        "motions.params.clips=[walk, run]",
        "--set",
        "eval.trainer.params.video_seconds=0.3",
    ],
    "mocap eval runs/imitator-amp-bundled --json eval.json --video videos/": None,
    "mocap run specs/latent/pulse_amp_v20.yaml": [
        "--set",
        "latent.trainer.params.num_envs=16",
        "--set",
        "latent.trainer.params.horizon=8",
        "--set",
        "latent.trainer.params.total_env_steps=128",
        "--set",
        "motions.params.clips=[walk]",
        "--set",
        "eval=null",
    ],
    "mocap eval checkpoints/imitator": None,
    "mocap eval-noisy checkpoints/imitator": None,
    "mocap generate runs/pulse-amp-v20 --video gen.mp4": None,
    "mocap export runs/pulse-amp-v20 checkpoints/my_pulse": None,
    "mocap run specs/tasks/speed_pulse_v20.yaml": [
        "--set",
        "task.trainer.params.num_envs=4",
        "--set",
        "task.trainer.params.horizon=8",
        "--set",
        "task.trainer.params.total_env_steps=64",
        "--set",
        "task.trainer.params.minibatch_size=16",
        "--set",
        "motions.params.clips=[walk]",
        "--set",
        "eval=null",
    ],
    "mocap render runs/speed-pulse-v20 --out speed.mp4": ["--seconds", "0.5"],
    "mocap task-eval runs/speed-pulse-v20 --json speed_eval.json": ["--envs", "2", "--seconds", "0.5"],
    "mocap task-eval checkpoints/speed_pulse_v20": ["--envs", "2", "--seconds", "0.5"],
    "mocap task-eval checkpoints/speed_pulse_v20 --start-clips walk,run": ["--envs", "2", "--seconds", "0.5"],
    "mocap render checkpoints/speed_pulse_v20 --out speed_pulse.mp4": ["--seconds", "0.5"],
    "mocap switches": None,
    "mocap checkpoint convert OLD.pt --trust": None,  # OLD.pt: a stand-in written by the test
}


def readme_commands() -> list[str]:
    """The commands of the README's "Using it" code block, comments stripped."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Using it\s+```bash\n(.*?)```", text, re.S)
    assert block, "README.md has no bash block under '## Using it'"
    return [line.split("#", 1)[0].strip() for line in block.group(1).splitlines() if line.split("#", 1)[0].strip()]


def test_every_readme_command_is_walked():
    assert readme_commands() == list(TINY), "README's 'Using it' block and TINY differ: update TINY"


@pytest.mark.slow
def test_readme_walk(tmp_path: Path):
    work = tmp_path / "newcomer"
    work.mkdir()
    (work / "specs").symlink_to(ROOT / "specs")
    (work / "checkpoints").mkdir()
    for item in (ROOT / "checkpoints").iterdir():  # `mocap export` writes a new checkpoints/my_pulse here
        (work / "checkpoints" / item.name).symlink_to(item)
    (work / "OLD.pt").write_bytes((ROOT / "checkpoints" / "imitator_amp" / "policy.pt").read_bytes())
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "DISPLAY": "", "OMP_NUM_THREADS": "2"}
    failures = []
    for command in readme_commands():
        extra = TINY[command] or []
        argv = [sys.executable, "-m", "mocap", *shlex.split(command)[1:], *extra]
        proc = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=900)
        out = proc.stdout + proc.stderr
        if "Traceback" in out:
            failures.append(f"{command}: a traceback\n{out[-2000:]}")
        elif command.startswith("mocap play"):
            errors = [line for line in out.splitlines() if line.startswith("error:")]
            if proc.returncode == 0 or len(errors) != 1:
                failures.append(f"{command}: expected one error line without a display (rc {proc.returncode})\n{out[-1000:]}")
        elif proc.returncode != 0:
            failures.append(f"{command}: exit code {proc.returncode}\n{out[-2000:]}")
    assert not failures, "\n\n".join(failures)
