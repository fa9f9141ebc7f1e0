"""Comparison specs (``matrix:``): expansion, validation errors, shared stages trained once (also
with parallel cells), and the comparison table."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from toy_plugins import TOY_SPEC, CountTrainer, toy

from mocap.matrix import expand, load_cells
from mocap.spec import SpecError
from mocap.testing import invoke, use_plugins

MATRIX = (
    TOY_SPEC
    + """\
matrix:
  latent:
    - {name: toy_latent, trainer: {name: count, params: {iterations: 2}}}
    - {name: toy_latent_b, trainer: {name: count, params: {iterations: 4}}}
  seed: [0, 1]
"""
)


def test_expand_is_the_cartesian_product_with_readable_names(tmp_path):
    doc = {
        "name": "x",
        "latent": {"name": "a"},
        "matrix": {"latent": [{"name": "a"}, {"name": "b", "checkpoint": "ck/l.pt"}], "task.name": ["speed", "reach"], "seed": [0, 1, 2]},
    }
    cells = expand(doc, tmp_path)
    assert len(cells) == 12 and len({c.name for c in cells}) == 12
    first = cells[0]
    assert first.name == "latent-a_name-speed_seed-0" and first.labels == {"latent": "a", "task.name": "speed", "seed": "0"}
    b = next(c for c in cells if c.labels["latent"] == "b")
    assert b.doc["latent"] == {"name": "b", "checkpoint": str((tmp_path / "ck" / "l.pt").resolve())}  # relative to the spec
    assert b.doc["task"] == {"name": b.labels["task.name"]} and "matrix" not in b.doc
    assert expand({"name": "x"}, tmp_path)[0].name == ""


def test_a_zipped_axis_sets_its_paths_together(tmp_path):
    doc = {
        "name": "x",
        "task": {"name": "speed"},
        "matrix": {
            "latent, task.checkpoint": [[{"name": "scratch"}, "ck/s.pt"], [{"name": "pulse", "checkpoint": "ck/l.pt"}, "ck/p.pt"]],
            "seed": [0, 1],
        },
    }
    cells = expand(doc, tmp_path)
    assert len(cells) == 4  # 2 zipped values x 2 seeds, not 2 x 2 x 2
    pulse = [c for c in cells if c.labels["latent, task.checkpoint"] == "pulse"]
    assert [c.name for c in pulse] == ["latent-pulse_seed-0", "latent-pulse_seed-1"]
    assert pulse[0].doc["latent"] == {"name": "pulse", "checkpoint": str((tmp_path / "ck" / "l.pt").resolve())}
    assert pulse[0].doc["task"] == {"name": "speed", "checkpoint": str((tmp_path / "ck" / "p.pt").resolve())}  # with its own policy
    scratch = next(c for c in cells if c.labels["latent, task.checkpoint"] == "scratch")
    assert scratch.doc["task"]["checkpoint"] == str((tmp_path / "ck" / "s.pt").resolve()) and scratch.doc["latent"] == {"name": "scratch"}


@pytest.mark.parametrize(
    "matrix, message",
    [
        ({"seed": []}, "non-empty list"),
        ({"": [1]}, "bad field path"),
        ({"latent": [{"name": "a"}, {"name": "a"}]}, "same name"),
        ({"latent, seed": [[{"name": "a"}, 0], [{"name": "b"}]]}, "list of 2 entries"),
        ({"latent, seed": [{"name": "a"}]}, "list of 2 entries"),
        ({"latent, ": [[1, 2]]}, "bad field path"),
    ],
)
def test_bad_matrices_are_clear_errors(tmp_path, matrix, message):
    with pytest.raises(SpecError, match=message):
        expand({"name": "x", "matrix": matrix}, tmp_path)


def test_matrix_runs_cells_shares_stages_and_writes_a_comparison(tmp_path: Path):
    spec = tmp_path / "cmp.yaml"
    spec.write_text(MATRIX)
    CountTrainer.calls.clear()
    with use_plugins(("toy", toy)) as pset:
        cells = load_cells(spec, pset)
        assert [c.name for c, _ in cells] == [
            "latent-toy_latent_seed-0",
            "latent-toy_latent_seed-1",
            "latent-toy_latent_b_seed-0",
            "latent-toy_latent_b_seed-1",
        ]
        result = invoke(["run", spec, "--out", tmp_path / "runs" / "cmp"])
        assert invoke(["validate", spec]).stdout.count("ok:") == 4
    assert result.exit_code == 0, result.output
    # the imitator stage depends on the seed only: trained once per seed, shared by both latents
    assert CountTrainer.calls.count("imitator") == 2 and CountTrainer.calls.count("latent") == 4
    data = json.loads((tmp_path / "runs" / "cmp" / "comparison.json").read_text())
    assert set(data["groups"]) == {"latent=toy_latent", "latent=toy_latent_b"}
    assert data["groups"]["latent=toy_latent_b"]["latent/iterations"] == {"mean": 4.0, "std": 0.0, "ci95": 0.0, "n": 2}
    assert "latent=toy_latent_b" in (tmp_path / "runs" / "cmp" / "comparison.md").read_text()


def test_jobs_run_cells_in_parallel_processes(tmp_path: Path):
    """``--jobs 2`` with the installed plugins: PD replay evaluated on one clip for two seeds."""
    spec = tmp_path / "cmp.yaml"
    spec.write_text(
        "spec_version: 1\nname: cmp\nmotions: {name: deepmimic, params: {clips: [walk]}}\nimitator: {name: pd_replay}\n"
        "eval: {trainer: {name: imitation_eval, params: {video: false}}}\nmatrix:\n  seed: [0, 1]\n"
    )
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "cmp", "--jobs", "2"])
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "runs" / "cmp" / "comparison.json").read_text())
    assert data["groups"]["all"]["eval/success_rate"]["n"] == 2
    assert (tmp_path / "runs" / "cmp" / "seed-1" / "imitation_eval.json").is_file()


def test_parallel_cells_train_a_shared_stage_once(tmp_path: Path):
    """Two processes running cells that share the imitator stage: one trains it, the other waits
    on the artifact lock and reuses it."""
    import os
    import subprocess
    import sys

    spec = tmp_path / "cmp.yaml"
    spec.write_text(TOY_SPEC + "matrix:\n  latent.params.hidden: [3, 5]\n")
    runner = (
        "import sys; sys.path.insert(0, {tests!r})\n"
        "from toy_plugins import toy\nfrom mocap.testing import use_plugins\nfrom mocap.cli import main\n"
        "with use_plugins(('toy', toy)):\n    sys.exit(main(['run', {spec!r}, '--out', {out!r}, '--store', {store!r}]))\n"
    )
    procs = []
    store = tmp_path / "runs" / "artifacts"
    # each process runs the whole matrix sequentially into its own run directory (one run per run
    # directory: a second run into the same one is refused) and the two race on every shared stage
    for i in range(2):
        out = tmp_path / "runs" / f"cmp{i}"
        code = runner.format(tests=str(Path(__file__).parent), spec=str(spec), out=str(out), store=str(store))
        procs.append(
            subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env={**os.environ, "OMP_NUM_THREADS": "1"})
        )
    outputs = [p.communicate(timeout=300)[0].decode() for p in procs]
    assert all(p.returncode == 0 for p in procs), outputs
    text = "\n".join(outputs)
    assert text.count("running trainer 'count'") == 3, text  # 1 imitator + 2 latents, each trained once in total
