"""``mocap run SPEC --executor ray``: a comparison's cells as Ray tasks (optional extra ``mocap[ray]``)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest
from toy_plugins import TOY_SPEC, CountTrainer, toy

from mocap.matrix import RAY_MISSING
from mocap.testing import invoke, use_plugins

TOY_MATRIX = TOY_SPEC + "matrix:\n  seed: [0, 1]\n"


def test_executor_ray_without_ray_is_one_line_and_runs_nothing(tmp_path: Path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError, as when it is not installed
    spec = tmp_path / "cmp.yaml"
    spec.write_text(TOY_MATRIX)
    CountTrainer.calls.clear()
    with use_plugins(("toy", toy)):
        result = invoke(["run", spec, "--out", tmp_path / "runs" / "cmp", "--executor", "ray"])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == f"error: {RAY_MISSING}"
    assert RAY_MISSING == "--executor ray needs Ray: pip install 'mocap[ray]'"
    assert "Traceback" not in result.output and CountTrainer.calls == []


@pytest.mark.parametrize(
    "args, message",
    [
        (["--executor", "dask"], "--executor dask: choose one of local, ray"),
        (["--ray-address", "auto"], "--ray-address and --ray-cpus-per-cell need --executor ray"),
    ],
)
def test_bad_executor_options_are_one_line(tmp_path: Path, args, message):
    spec = tmp_path / "cmp.yaml"
    spec.write_text(TOY_MATRIX)
    CountTrainer.calls.clear()
    with use_plugins(("toy", toy)):
        result = invoke(["run", spec, "--out", tmp_path / "runs" / "cmp", *args])
    assert result.exit_code == 2 and result.stderr.strip() == f"error: {message}", result.output
    assert CountTrainer.calls == []


# a real (tiny) comparison with the installed plugins: one PPO-trained imitator shared by two eval cells
RAY_SPEC = """\
spec_version: 1
name: cmp_ray
device: cpu
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk]}}
simulator: {name: mujoco}
imitator:
  name: phc
  trainer: {name: ppo, params: {num_envs: 2, horizon: 4, total_env_steps: 8, minibatch_size: 4, epochs: 1, \
actor_hidden: [16], critic_hidden: [16], torch_threads: 1}}
eval: {trainer: {name: imitation_eval, params: {num_envs: 1, video: false}}}
matrix:
  eval.trainer.params.threshold: [0.5, 0.3]
"""


@pytest.mark.slow
def test_executor_ray_runs_cells_as_ray_tasks_and_shares_a_stage(tmp_path: Path):
    ray = pytest.importorskip("ray")
    spec = tmp_path / "cmp.yaml"
    spec.write_text(RAY_SPEC)
    out = tmp_path / "runs" / "cmp"
    t0 = time.time()
    ray.init(num_cpus=2, include_dashboard=False)  # run_cells uses the running instance
    try:
        result = invoke(["run", spec, "--out", out, "--executor", "ray", "--jobs", "2"])
    finally:
        ray.shutdown()
    print(f"ray comparison: {time.time() - t0:.1f} s")
    assert result.exit_code == 0, result.output
    cells = ["threshold-0.5", "threshold-0.3"]
    for cell in cells:
        assert f"cell {cell}: done" in result.stdout, result.output
        assert (out / cell / "cell.yaml").is_file() and (out / cell / "imitation_eval.json").is_file()
    data = json.loads((out / "comparison.json").read_text())
    assert set(data["cells"]) == set(cells)
    assert all("eval/success_rate" in data["cells"][c]["metrics"] for c in cells)
    assert (out / "comparison.md").is_file()
    # the imitator depends on neither threshold: one cell trained it, the other reused it (or waited on its lock)
    logs = [(out / cell / "run.log").read_text() for cell in cells]
    assert sum(log.count("imitator: running trainer 'ppo'") for log in logs) == 1, logs
    assert sum("imitator: reusing the trained artifact" in log for log in logs) == 1, logs
    assert len(list((out / "artifacts").glob("imitator-*"))) == 1
    stages = [json.loads((out / cell / "stages.json").read_text()) for cell in cells]
    imitator_keys = {s["key"] for st in stages for s in st if s["stage"] == "imitator"}
    assert len(imitator_keys) == 1
