"""Data-parallel training (mocap.distributed): the exact normalizer merge, the helpers' single-process
behaviour, and real 2-process runs under ``python -m torch.distributed.run ... -m mocap run``
(``ppo`` on the toy point task, ``distill`` with a tiny teacher) that must end with identical
weights on both ranks and the output structure of a single-process run."""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap import distributed as dist
from mocap.checkpoint import load_checkpoint
from mocap.rl.normalizer import RunningNormalizer, batch_moments, combine_moments, empty_moments

TESTS = Path(__file__).parent


# ------------------------------------------------------------------------------ normalizer merge
@settings(max_examples=40, deadline=None)
@given(
    sizes=st.lists(st.integers(0, 40), min_size=1, max_size=5),
    prior=st.integers(0, 30),
    dim=st.integers(1, 4),
    seed=st.integers(0, 2**16),
    scale=st.floats(1e-3, 1e3),
)
def test_merging_per_rank_moments_equals_the_concatenated_data(sizes, prior, dim, seed, scale):
    """Each 'rank' holds a batch (sizes may be 0); merging their moments in rank order gives the
    count/mean/var of the concatenation, and folding that into a running normalizer equals feeding
    it all the data at once."""
    gen = torch.Generator().manual_seed(seed)
    batches = [torch.randn(n, dim, generator=gen, dtype=torch.float64) * scale + 3.0 for n in sizes]
    merged = combine_moments([batch_moments(b, (dim,)) for b in batches])
    data = torch.cat(batches)
    assert float(merged.count) == data.shape[0]
    if data.shape[0]:
        assert torch.allclose(merged.mean, data.mean(0), rtol=1e-9, atol=1e-9 * scale)
        assert torch.allclose(merged.var, data.var(0, unbiased=False), rtol=1e-8, atol=1e-9 * scale**2)

    history = torch.randn(prior, dim, generator=gen, dtype=torch.float64) * scale
    a, b = RunningNormalizer(dim), RunningNormalizer(dim)
    a.update(history)
    b.update(history)
    a.update_moments(merged)  # what every rank applies after the exchange
    b.update(data)  # one process that saw every rank's batch
    assert float(a.count) == float(b.count) == prior + data.shape[0]
    assert torch.allclose(a.mean, b.mean, rtol=1e-9, atol=1e-9 * scale)
    assert torch.allclose(a.var, b.var, rtol=1e-8, atol=1e-9 * scale**2)


def test_capture_records_moments_and_leaves_the_statistics_alone():
    norm = RunningNormalizer(3)
    norm.update(torch.ones(4, 3))
    before = (norm.count.clone(), norm.mean.clone(), norm.var.clone())
    x = torch.arange(12.0).reshape(4, 3)
    with norm.capture() as captured:
        norm.update(x)
        norm.update(x[:0])  # empty batches are not recorded
    assert len(captured) == 1 and float(captured[0].count) == 4
    assert torch.equal(captured[0].mean, x.double().mean(0))
    assert all(torch.equal(u, v) for u, v in zip(before, (norm.count, norm.mean, norm.var)))
    norm.update(x)  # outside the block updates apply again
    assert float(norm.count) == 8
    frozen = RunningNormalizer(3).freeze()
    with frozen.capture() as captured:
        frozen.update(x)
    assert captured == [] and float(frozen.count) == 0
    assert float(combine_moments([empty_moments((3,)), batch_moments(x, (3,))]).count) == 4


def test_helpers_without_torchrun_are_the_single_process_path(monkeypatch):
    monkeypatch.delenv("WORLD_SIZE", raising=False)
    assert not dist.launched() and not dist.active() and dist.world_size() == 1 and dist.is_main()
    assert dist.init() == torch.device("cpu")  # no process group is created
    net = torch.nn.Linear(2, 1)
    net(torch.ones(3, 2)).sum().backward()
    grad = net.weight.grad.clone()
    loss = torch.tensor(2.5)
    assert dist.average_gradients(list(net.parameters()), loss) == (loss,)
    assert torch.equal(net.weight.grad, grad)
    norm = RunningNormalizer(2)
    dist.sync_normalizers(norm, lambda: norm.update(torch.ones(5, 2)))
    assert float(norm.count) == 5
    assert dist.any_true(True) and not dist.any_true(False)
    assert dist.broadcast_object({"a": 1}) == {"a": 1} and dist.gather_object(3) == [3]
    assert dist.rank_seed(123, 0) == 123 and dist.rank_seed(123, 1) != dist.rank_seed(123, 2) != 123
    assert dist.state_digest(net) == dist.state_digest(net.state_dict())
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "1")
    assert dist.launched() and not dist.is_main() and dist.world_size() == 2
    with dist.solo():
        assert dist.is_main() and dist.world_size() == 1


def test_incomplete_torchrun_environment_is_one_clear_error(monkeypatch):
    from mocap.pipeline import StageFailed

    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "0")
    monkeypatch.delenv("MASTER_ADDR", raising=False)
    monkeypatch.delenv("MASTER_PORT", raising=False)
    with pytest.raises(StageFailed, match="MASTER_ADDR, MASTER_PORT not set: launch with torchrun"):
        dist.init()


# ------------------------------------------------------------------------------ 2-process runs
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _torchrun(args: list[str], tmp: Path, extra_path: list[Path] = (), **extra_env: str) -> subprocess.CompletedProcess:
    env = {
        **os.environ,
        **extra_env,
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "MOCAP_DIST_DEBUG_DIR": str(tmp / "digests"),
        "PYTHONPATH": os.pathsep.join([*map(str, extra_path), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
    }
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--master_port", str(_free_port()), "-m", "mocap", *args]
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


def _digests(tmp: Path, what: str) -> list[str]:
    return [(tmp / "digests" / f"{what}-rank{r}.txt").read_text().strip() for r in range(2)]


def _steps(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]


POINT_SPEC = """\
spec_version: 1
name: point
humanoid: {name: toy_body}
motions: {name: toy_motions}
simulator: {name: toy_sim}
task:
  name: point
  trainer:
    name: ppo
    params: {num_envs: 16, horizon: 16, total_env_steps: 2048, minibatch_size: 64, epochs: 2, normalize_value: true,
             lr_schedule: adaptive, actor_hidden: [16], critic_hidden: [16], checkpoint_every: 2, torch_threads: 1}
"""


def _toy_entry_points(tmp: Path) -> Path:
    """A directory on PYTHONPATH that publishes the test plugins (toy components, the point task)
    under the ``mocap`` entry-point group, so that the real ``-m mocap`` finds them."""
    info = tmp / "entry_points" / "mocap_dist_toy-0.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: mocap-dist-toy\nVersion: 0.0\n")
    (info / "entry_points.txt").write_text("[mocap]\ntoy = toy_plugins:toy\npoint = test_ppo:point_plugin\n")
    return info.parent


def test_ppo_two_processes(tmp_path: Path):
    spec = tmp_path / "point.yaml"
    spec.write_text(POINT_SPEC)
    run = tmp_path / "runs" / "point"
    path = [TESTS, _toy_entry_points(tmp_path)]
    proc = _torchrun(["run", str(spec), "--out", str(run)], tmp_path, path, MOCAP_LOAD_PLUGINS="rl,toy,point")
    assert proc.stdout.count("done: 1 stage(s)") == 1, proc.stdout  # rank 1 prints nothing
    assert proc.stdout.count("data-parallel: 2 processes") == 1, proc.stdout

    # the structure of a single-process run
    assert {p.name for p in run.iterdir()} >= {"spec.yaml", "metrics.jsonl", "stages.json", "report.md"}
    (stage,) = json.loads((run / "stages.json").read_text())
    art = Path(stage["artifact_dir"])
    assert {"ppo.pt", "policy.pt", "DONE.json", "spec.yaml"} <= {p.name for p in art.iterdir()}
    assert not list(art.glob(".*.tmp")) and not list(run.glob(".*.tmp"))
    # each iteration logged once; the budget and env_steps count both ranks' samples
    iterations = math.ceil(2048 / (16 * 16 * 2))
    rows = _steps(run)
    assert [r["step"] for r in rows] == list(range(1, iterations + 1))
    assert [r["env_steps"] for r in rows] == [16 * 16 * 2 * i for i in range(1, iterations + 1)]
    assert all(r["episodes_finished"] >= 32 for r in rows[1:])  # every env's 20-step episode ends: both ranks' sum
    ck = load_checkpoint(art / "ppo.pt")
    assert ck["iteration"] == iterations and ck["env_steps"] == 2048 and ck["world_size"] == 2
    assert set(ck["rank_states"]) == {1} and not torch.equal(ck["rank_states"][1]["obs"], ck["obs"])  # own envs
    # both ranks ended with the weights (and normalizers) of the checkpoint, bit for bit
    a, b = _digests(tmp_path, "ppo")
    assert a == b == dist.state_digest(ck["model"])
    assert float(ck["model"]["obs_norm.count"]) == 2 * 16 * (1 + 16 * iterations)  # both ranks' samples


@pytest.mark.slow
def test_two_processes_resume_exactly_and_agree_on_reuse(tmp_path: Path):
    """A 2-process run resumed from a mid-run checkpoint (each rank its own stream from
    ``rank_states``) ends with the weights of an uninterrupted one; a later run reuses the artifact."""
    import shutil

    spec = tmp_path / "point.yaml"
    spec.write_text(POINT_SPEC)
    path = [TESTS, _toy_entry_points(tmp_path)]
    straight = tmp_path / "a" / "runs" / "point"
    _torchrun(["run", str(spec), "--out", str(straight)], tmp_path, path)
    (stage,) = json.loads((straight / "stages.json").read_text())
    # the first half of the budget, in another store: its final checkpoint is the straight run's at iteration 2
    half = tmp_path / "b" / "runs" / "point"
    _torchrun(["run", str(spec), "--out", str(half), "--set", "task.trainer.params.total_env_steps=1024"], tmp_path, path)
    (half_stage,) = json.loads((half / "stages.json").read_text())
    resumed_dir = tmp_path / "c" / "runs" / "artifacts" / Path(stage["artifact_dir"]).name
    resumed_dir.mkdir(parents=True)
    shutil.copy2(Path(half_stage["artifact_dir"]) / "ppo.pt", resumed_dir / "ppo.pt")
    resumed = tmp_path / "c" / "runs" / "point"
    proc = _torchrun(["run", str(spec), "--out", str(resumed)], tmp_path, path)
    assert proc.stdout.count("ppo: resuming at iteration 2") == 1, proc.stdout
    a, b = load_checkpoint(Path(stage["artifact_dir"]) / "ppo.pt"), load_checkpoint(resumed_dir / "ppo.pt")
    assert a["iteration"] == b["iteration"] == 4
    assert dist.state_digest(a["model"]) == dist.state_digest(b["model"])
    assert torch.equal(a["rank_states"][1]["obs"], b["rank_states"][1]["obs"])
    assert [r["step"] for r in _steps(resumed)] == [3, 4]

    # a second run under the same store: all ranks take rank 0's decision to reuse the artifact
    again = tmp_path / "a" / "runs" / "point2"
    proc = _torchrun(["run", str(spec), "--out", str(again)], tmp_path, path)
    assert proc.stdout.count("reusing the trained artifact") == 1, proc.stdout
    assert json.loads((again / "stages.json").read_text())[0]["reused"] is True


def _teacher(path: Path) -> Path:
    """A small random PHC policy on the amp humanoid (normalizer fitted to walk reference states)."""
    from mocap.humanoids.amp import amp_skeleton
    from mocap.interfaces import Box
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary
    from mocap.rl.networks import ActorCritic, save_policy
    from mocap_phc.env import PHCObservation

    amp = amp_skeleton()
    torch.manual_seed(0)
    obs_dim = 15 * amp.num_bodies - 2 + 24 * amp.num_bodies
    model = ActorCritic(obs_dim, Box((amp.num_dofs,)), actor_hidden=(16,), critic_hidden=(8,))
    lib = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp), amp)
    ids, times = lib.sample(32, generator=torch.Generator().manual_seed(0))
    model.obs_norm.update(PHCObservation.flatten(PHCObservation()(lib.frames(ids, times), lib.frames(ids, times + 1 / 30))))
    save_policy(path, model)
    return path


def test_distill_two_processes(tmp_path: Path):
    teacher = _teacher(tmp_path / "teacher.pt")
    spec = tmp_path / "pulse.yaml"
    spec.write_text(
        f"""\
spec_version: 1
name: pulse_tiny
device: cpu
humanoid: {{name: amp}}
motions: {{name: deepmimic, params: {{clips: [walk]}}}}
simulator: {{name: mujoco, params: {{threads: 1}}}}
imitator: {{name: phc, params: {{action: residual}}, checkpoint: {teacher}}}
latent:
  name: pulse
  params: {{latent_dim: 4, encoder_hidden: [16], prior_hidden: [16], decoder_hidden: [16]}}
  trainer: {{name: distill, params: {{num_envs: 2, horizon: 4, total_env_steps: 32, minibatch_envs: 1,
             eval_every: 2, eval_horizon: 0.2, checkpoint_every: 1}}}}
"""
    )
    run = tmp_path / "runs" / "pulse"
    _torchrun(["run", str(spec), "--out", str(run)], tmp_path, MOCAP_LOAD_PLUGINS="humanoids,motion,sim_mujoco,imitator_phc,latent_pulse,distill")
    stages = json.loads((run / "stages.json").read_text())
    art = Path(stages[-1]["artifact_dir"])
    assert {"distill.pt", "latent.pt", "DONE.json"} <= {p.name for p in art.iterdir()}
    rows = _steps(run)
    assert [r["step"] for r in rows] == [1, 2] and [r["env_steps"] for r in rows] == [16.0, 32.0]
    assert "eval/success_rate" in rows[-1] and "eval/success_rate" in stages[-1]["metrics"]
    ck = load_checkpoint(art / "distill.pt")
    assert ck["world_size"] == 2 and set(ck["rank_states"]) == {1}
    a, b = _digests(tmp_path, "distill")
    assert a == b == dist.state_digest(ck["student"])
    # the student's running normalizer holds both ranks' chunks (2 ranks × 2 iterations × 4 × 2 samples)
    counts = [float(v) for k, v in ck["student"].items() if k.endswith("norm.count")]
    assert counts and all(c == 2 * 2 * 4 * 2 for c in counts), counts
