"""Random generation (``mocap.generation``, ``mocap generate``) and the evaluation of latent spaces
(``mocap eval`` of a latent run, checkpoint directory or latent file)."""

from __future__ import annotations

import io
import json
import math
import shutil
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console
from test_distill import teacher_file, walk  # noqa: F401  (fixtures)

from mocap.generation import GenerationParams
from mocap.generation_eval import evaluate_generation, heading_frame, in_start_frame, motion_matching, pairwise_diversity
from mocap.rotations import quat_apply, quat_from_axis_angle, quat_mul
from mocap.testing import invoke

floats = st.floats(-3.0, 3.0, allow_nan=False, width=32)


# --------------------------------------------------------------------------------- properties
@settings(max_examples=40, deadline=None)
@given(st.integers(2, 5), st.integers(1, 4), st.integers(1, 3), st.integers(0, 2**31 - 1))
def test_diversity_is_zero_for_copies_and_symmetric(n, t, b, seed):
    g = torch.Generator().manual_seed(seed)
    one = torch.randn(t, 1, b, 3, generator=g, dtype=torch.float64)
    assert pairwise_diversity(one.expand(t, n, b, 3)) == pytest.approx(0.0, abs=1e-12)
    many = torch.randn(t, n, b, 3, generator=g, dtype=torch.float64)
    perm = torch.randperm(n, generator=g)
    assert pairwise_diversity(many[:, perm]) == pytest.approx(pairwise_diversity(many), rel=1e-9)
    assert pairwise_diversity(many) > 0


@settings(max_examples=40, deadline=None)
@given(floats, floats, floats)
def test_diversity_of_two_shifted_copies_is_the_shift(x, y, z):
    base = torch.randn(3, 1, 4, 3, dtype=torch.float64)
    shift = torch.tensor([x, y, z], dtype=torch.float64)
    pair = torch.cat([base, base + shift], 1)
    assert pairwise_diversity(pair) == pytest.approx(float(torch.linalg.vector_norm(shift)), rel=1e-6, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.floats(-math.pi, math.pi), floats, floats, st.integers(0, 2**31 - 1))
def test_start_frame_removes_where_and_which_way_a_rollout_started(yaw, dx, dy, seed):
    """Moving and turning a whole rollout about the vertical does not change it in its start frame."""
    g = torch.Generator().manual_seed(seed)
    T, N, B = 3, 2, 4
    body = torch.randn(T, N, B, 3, generator=g, dtype=torch.float64)
    root_pos = torch.randn(N, 3, generator=g, dtype=torch.float64)
    root_rot = torch.nn.functional.normalize(torch.randn(N, 4, generator=g, dtype=torch.float64), dim=-1)
    turn = quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor(yaw, dtype=torch.float64))
    move = torch.tensor([dx, dy, 0.0], dtype=torch.float64)
    a = in_start_frame(body, *heading_frame(root_pos, root_rot))
    body2 = quat_apply(turn.expand(T, N, B, 4), body) + move
    root_pos2 = quat_apply(turn.expand(N, 4), root_pos) + move
    root_rot2 = quat_mul(turn.expand(N, 4), root_rot)
    b = in_start_frame(body2, *heading_frame(root_pos2, root_rot2))
    assert torch.allclose(a, b, atol=1e-8)
    origin, _ = heading_frame(root_pos, root_rot)
    assert torch.all(origin[:, 2] == 0)


def test_motion_matching_zero_on_the_dataset_and_filters_outliers():
    g = torch.Generator().manual_seed(0)
    data = torch.randn(50, 6, generator=g)
    out = motion_matching(data[:10], data, threshold=1.0)
    assert out["match_distance"] == pytest.approx(0.0, abs=1e-5) and out["filtered"] == 0.0
    assert out["coverage"] == pytest.approx(10 / 50)
    far = data[:4] + 100.0
    mixed = motion_matching(torch.cat([data[:4], far]), data, threshold=1.0)
    assert mixed["filtered"] == pytest.approx(0.5) and mixed["coverage"] == pytest.approx(4 / 50)
    assert motion_matching(far, data, threshold=1.0)["coverage"] == 0.0


# ------------------------------------------------------------------------------ end to end
def _spec(teacher: Path, latent: str = "pulse", label: str = "pd_targets") -> str:
    params = (
        "{latent_dim: 4, encoder_hidden: [16], prior_hidden: [16], decoder_hidden: [16]}"
        if latent == "pulse"
        else "{latent_dim: 4, num_codebooks: 2, codebook_size: 8, encoder_hidden: [16], prior_hidden: [16], decoder_hidden: [16], codebook_init: random}"
    )
    return f"""\
spec_version: 1
name: gen_tiny
device: cpu
humanoid: {{name: amp}}
motions: {{name: deepmimic, params: {{clips: [walk]}}}}
simulator: {{name: mujoco}}
imitator: {{name: phc, params: {{action: residual}}, checkpoint: {teacher}}}
latent:
  name: {latent}
  params: {params}
  trainer: {{name: distill, params: {{num_envs: 2, horizon: 4, total_env_steps: 16, minibatch_envs: 2, eval_every: 0, act_with: teacher, label: {label}}}}}
eval:
  trainer: {{name: generation_eval, params: {{num_rollouts: 3, seconds: 0.3, video_rollouts: 0}}}}
"""


@pytest.fixture(scope="module")
def pulse_run(teacher_file, tmp_path_factory):  # noqa: F811
    root = tmp_path_factory.mktemp("genrun")
    spec = root / "spec.yaml"
    spec.write_text(_spec(teacher_file))
    result = invoke(["run", spec, "--out", root / "runs" / "tiny"])
    assert result.exit_code == 0, result.output
    return root / "runs" / "tiny"


def test_generation_stage_and_command(pulse_run, tmp_path):
    table = json.loads((pulse_run / "generation.json").read_text())
    for key in ("fall_rate", "time_to_fall_s", "survival_s", "diversity_m", "match_distance", "filtered", "coverage"):
        assert key in table, key
    assert 0.0 <= table["fall_rate"] <= 1.0 and 0.0 <= table["coverage"] <= 1.0 and table["num_rollouts"] == 3
    assert 0.0 < table["survival_s"] <= table["seconds"] + 1e-9 and table["diversity_m"] > 0
    per = table["fall_time_s_per_rollout"]  # the per-rollout record agrees with the aggregate
    assert len(per) == len(table["start_clips"]) == 3
    assert table["fall_rate"] == pytest.approx(sum(t is not None for t in per) / 3)
    horizon = table["seconds"]
    assert table["survival_s"] == pytest.approx(sum(horizon if t is None else t for t in per) / 3)
    assert "Random generation" in (pulse_run / "generation.md").read_text()
    out = tmp_path / "g.json"
    result = invoke(["generate", pulse_run, "--rollouts", "2", "--seconds", "0.2", "--json", out])
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text())["num_rollouts"] == 2 and "fall_rate" in result.stdout


def test_falls_by_start_clip_counts_per_clip():
    from mocap.generation_eval import falls_by_start_clip

    rows = falls_by_start_clip(["walk", "kick", "walk", "walk"], [2.0, 0.5, None, None], [False, True, False, True])
    assert list(rows) == ["kick", "walk"]
    assert rows["walk"] == {"rollouts": 3, "falls": 1, "down_at_end": 1, "time_to_fall_s": 2.0}
    assert rows["kick"] == {"rollouts": 1, "falls": 1, "down_at_end": 1, "time_to_fall_s": 0.5}
    assert falls_by_start_clip(["run"], [None], [False])["run"]["time_to_fall_s"] is None
    with pytest.raises(ValueError):
        falls_by_start_clip(["walk"], [1.0, None], [False])


def test_start_states_only_from_the_named_clips(amp):
    from mocap.generation_eval import start_states
    from mocap.motion.library import MotionLibrary
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource

    lib = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk", "run", "kick"])).load(amp), amp)
    ids, times = start_states(lib, 40, amp, 0.25, torch.Generator().manual_seed(0), ["kick", "run"])
    names = {lib.clip_names[int(i)] for i in ids}
    assert names <= {"kick", "run"} and len(ids) == 40
    assert bool((times >= 0).all()) and bool((times <= lib.durations[ids] + 1e-6).all())
    everywhere, _ = start_states(lib, 200, amp, 0.25, torch.Generator().manual_seed(0))
    assert "walk" in {lib.clip_names[int(i)] for i in everywhere}  # without the option every clip starts rollouts
    with pytest.raises(ValueError, match="no clip 'wlak'.*walk"):
        start_states(lib, 4, amp, 0.25, torch.Generator().manual_seed(0), ["wlak"])
    with pytest.raises(ValueError, match="at least one clip"):
        start_states(lib, 4, amp, 0.25, torch.Generator().manual_seed(0), [])


def test_generate_start_clips_and_the_per_clip_table(pulse_run, tmp_path):
    out = tmp_path / "g.json"
    result = invoke(["generate", pulse_run, "--rollouts", "2", "--seconds", "0.2", "--start-clips", "walk", "--json", out])
    assert result.exit_code == 0, result.output
    table = json.loads(out.read_text())
    assert table["start_clips"] == ["walk", "walk"] and table["params"]["start_clips"] == ["walk"]
    assert table["falls_by_start_clip"]["walk"]["rollouts"] == 2 and "start states of walk" in table["protocol"]
    assert "| start clip | rollouts | fell | time to fall (s) | down at the end |" in result.stdout and "| walk | 2 |" in result.stdout
    bad = invoke(["generate", pulse_run, "--rollouts", "2", "--seconds", "0.2", "--start-clips", "kick"])
    assert bad.exit_code == 2 and "Traceback" not in bad.output and "no clip 'kick'" in bad.stderr
    empty = invoke(["generate", pulse_run, "--rollouts", "2", "--start-clips", " , "])
    assert empty.exit_code == 2 and "at least one clip name" in empty.stderr


def test_eval_of_a_latent_run_compares_it_with_its_teacher(pulse_run, tmp_path):
    out = tmp_path / "e.json"
    result = invoke(["eval", pulse_run, "--json", out])
    assert result.exit_code == 0, result.output
    table = json.loads(out.read_text())
    assert table["evaluated"].startswith("pulse latent") and "imitator" in table
    comp = table["comparison"]
    assert set(comp["both_succeeded"]) <= set(comp["teacher_succeeded"])
    assert comp["mpjpe_g_ratio_all"] == pytest.approx(table["aggregate"]["mpjpe_g"] / table["imitator"]["aggregate"]["mpjpe_g"])
    teacher_only = invoke(["eval", pulse_run, "--imitator-only", "--json", tmp_path / "t.json"])
    assert teacher_only.exit_code == 0, teacher_only.output
    assert json.loads((tmp_path / "t.json").read_text())["aggregate"]["mpjpe_g"] == pytest.approx(table["imitator"]["aggregate"]["mpjpe_g"])


def test_export_makes_a_self_contained_checkpoint_directory(pulse_run, teacher_file, tmp_path):  # noqa: F811
    """``mocap export RUN DEST``: latent.pt copied, the teacher referenced by a relative path."""
    (tmp_path / "checkpoints" / "teacher").mkdir(parents=True)
    teacher = tmp_path / "checkpoints" / "teacher" / "policy.pt"
    shutil.copy(teacher_file, teacher)
    run_copy = tmp_path / "run"
    shutil.copytree(pulse_run, run_copy)
    stages = json.loads((run_copy / "stages.json").read_text())
    for s in stages:  # as if the run had used the committed teacher
        if s["stage"] == "imitator":
            s["checkpoint"] = str(teacher)
    (run_copy / "stages.json").write_text(json.dumps(stages))
    spec = (run_copy / "spec.yaml").read_text().replace(str(teacher_file), str(teacher))
    (run_copy / "spec.yaml").write_text(spec)
    ckdir = tmp_path / "checkpoints" / "pulse_tiny"
    result = invoke(["export", run_copy, ckdir])
    assert result.exit_code == 0, result.output
    assert (ckdir / "latent.pt").is_file() and not (ckdir / "policy.pt").exists()
    assert "checkpoint: ../teacher/policy.pt" in (ckdir / "spec.yaml").read_text()
    moved = tmp_path / "elsewhere"
    shutil.copytree(tmp_path / "checkpoints", moved)  # relative paths survive a move of the tree
    result = invoke(["eval", moved / "pulse_tiny", "--json", tmp_path / "e.json"])
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "e.json").read_text())["checkpoint"] == str((moved / "pulse_tiny" / "latent.pt").resolve())
    (moved / "teacher" / "policy.pt").unlink()
    missing = invoke(["eval", moved / "pulse_tiny"])
    assert missing.exit_code == 2 and "Traceback" not in missing.output and "does not exist" in missing.stderr
    assert invoke(["export", tmp_path / "nothing", ckdir]).exit_code == 2


def test_generation_refuses_a_reference_dependent_decoder(amp, walk, teacher_file):  # noqa: F811
    """A latent that learned a residual teacher's raw output needs the reference to act: refused."""
    from mocap.motion.library import MotionLibrary
    from mocap_phc.imitator import PHCParams, make_phc
    from mocap_pulse.latent import PulseParams, make_pulse
    from mocap_sim_mujoco.simulator import MujocoSimulator

    teacher = make_phc(PHCParams(action="residual"), skeleton=amp, checkpoint=teacher_file)
    latent = make_pulse(PulseParams(latent_dim=4, encoder_hidden=[8], prior_hidden=[8], decoder_hidden=[8]), skeleton=amp)
    lib = MotionLibrary(walk, amp)
    params = GenerationParams(num_rollouts=2, seconds=0.1, video_rollouts=0)
    make_sim = lambda n: MujocoSimulator(skeleton=amp, num_envs=n, seed=0)  # noqa: E731
    with pytest.raises(ValueError, match="without a reference"):
        evaluate_generation(latent, teacher, teacher.to_pd_targets, lib, make_sim, params)
    result = evaluate_generation(latent, teacher, lambda obs, out: out, lib, make_sim, params, console=Console(file=io.StringIO()))
    assert result["num_rollouts"] == 2 and math.isfinite(result["survival_s"])


def test_hybrid_random_action_shapes(amp):
    from mocap.state import Observations
    from mocap_hybrid_rvq.model import HybridParams, make_hybrid

    for variant in ("hybrid", "continuous", "discrete"):
        latent = make_hybrid(
            HybridParams(
                variant=variant,
                latent_dim=4,
                num_codebooks=2,
                codebook_size=8,
                single_codebook_size=8,
                encoder_hidden=[8],
                prior_hidden=[8],
                decoder_hidden=[8],
            ),
            skeleton=amp,
        )
        obs = Observations(proprio=torch.randn(3, latent.proprio_dim), goal=None, extra={})
        g = torch.Generator().manual_seed(0)
        a = latent.random_action(obs, generator=g)
        b = latent.random_action(obs, generator=torch.Generator().manual_seed(0))
        assert a.shape == (3, amp.num_dofs) and torch.equal(a, b)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(features=st.integers(2, 16), threshold=st.floats(0.05, 5.0), factor=st.sampled_from([0.8, 1.25]), seed=st.integers(0, 1000))
def test_motion_matching_filters_on_the_per_feature_squared_distance(features, threshold, factor, seed):
    """hybrid_rvq Eq. 8's filter: a transition is kept when its squared distance to the nearest
    dataset transition, in standardized features, divided by the feature count F is within the
    threshold. A point at per-feature squared distance 0.8 t is kept (its total, 0.8 t F, is not
    within t); at 1.25 t it is filtered."""
    gen = torch.Generator().manual_seed(seed)
    scale = torch.rand(features, generator=gen, dtype=torch.float64) + 0.5
    centre = torch.randn(features, generator=gen, dtype=torch.float64)
    data = torch.stack([centre + scale, centre - scale])  # standardized: +-1/sqrt(2) per feature
    std = data.std(0)
    e = math.sqrt(factor * threshold)  # per-feature standardized offset, away from the other point
    point = data[0] + e * std
    out = motion_matching(point.unsqueeze(0), data, threshold=threshold)
    assert out["filtered"] == (0.0 if factor < 1 else 1.0)
    if factor < 1:
        assert out["match_distance"] == pytest.approx(features * e * e, rel=1e-4)
