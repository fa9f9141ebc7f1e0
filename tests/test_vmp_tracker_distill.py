"""VMP's tracker warm start by distillation (mocap_vmp.tracker_distill): the action-map inverse that
turns a teacher's PD targets into labels, the TD(lambda) returns of the critic fit, the schedules,
and the distiller itself (it learns a teacher's actions; a stopped run resumes to the same weights)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console

from mocap.interfaces import Imitator
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap.motion.library import MotionLibrary
from mocap.pd_actions import ActionMap
from mocap.rl.ppo import PPOTrainer
from mocap.rl.ppo_params import PPOParams
from mocap.state import Observations
from mocap_vmp.features import feature_stats
from mocap_vmp.latent import VmpParams, make_vmp
from mocap_vmp.tracker_distill import TrackerDistiller, distill_lr, mixture_beta, td_lambda_returns
from mocap_vmp.tracking import VmpTrackerParams, VmpTrackingEnv
from mocap_vmp.vmp_params import TrackerDistillParams

TINY = {"window_half": 6, "latent_dim": 8, "channels": 16, "res_blocks": 1, "downsample": 1}


# ------------------------------------------------------------------------------ action inverse
@settings(max_examples=40, deadline=None)
@given(
    mode=st.sampled_from(["absolute", "residual"]),
    clip=st.sampled_from([None, 3.0]),
    seed=st.integers(0, 2**16),
)
def test_action_map_inverse_round_trips_within_the_clip(amp, mode, clip, seed):
    g = torch.Generator().manual_seed(seed)
    amap = ActionMap.for_skeleton(amp, mode, clip)
    ref = torch.randn(5, amp.num_dofs, generator=g)
    a = (torch.rand(5, amp.num_dofs, generator=g) * 2 - 1) * 2.5  # inside the clip
    q = amap(a, ref)
    back = amap.inverse(q, ref)
    assert torch.allclose(back, a, atol=1e-5)
    assert torch.allclose(amap(back, ref), q, atol=1e-5)


def test_action_map_inverse_clamps_to_the_clip_and_needs_the_reference_when_residual(amp):
    amap = ActionMap.for_skeleton(amp, "residual", 3.0)
    ref = torch.zeros(2, amp.num_dofs)
    far = ref + 10.0
    assert float(amap.inverse(far, ref).max()) == 3.0
    with pytest.raises(ValueError, match="reference"):
        amap.inverse(far, None)


# ---------------------------------------------------------------------------- TD(lambda) returns
def _brute_returns(r, nv, term, done, gamma, lam):
    """R_t by its definition, per env and step (no recursion over tensors)."""
    T, N = r.shape
    out = torch.zeros(T, N, dtype=torch.float64)
    for n in range(N):
        nxt = None
        for t in range(T - 1, -1, -1):
            cont = 0.0 if bool(done[t, n]) or t == T - 1 else 1.0
            later = nxt if nxt is not None else 0.0
            boot = (1 - lam * cont) * float(nv[t, n]) + lam * cont * later
            val = float(r[t, n]) + gamma * (0.0 if bool(term[t, n]) else 1.0) * boot
            out[t, n] = val
            nxt = val
    return out


@settings(max_examples=60, deadline=None)
@given(
    T=st.integers(1, 6),
    N=st.integers(1, 3),
    gamma=st.floats(0.0, 1.0),
    lam=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**16),
)
def test_td_lambda_returns_match_their_definition(T, N, gamma, lam, seed):
    g = torch.Generator().manual_seed(seed)
    r = torch.randn(T, N, generator=g, dtype=torch.float64)
    nv = torch.randn(T, N, generator=g, dtype=torch.float64)
    done = torch.rand(T, N, generator=g) < 0.3
    term = done & (torch.rand(T, N, generator=g) < 0.5)
    got = td_lambda_returns(r, nv, term, done, gamma, lam)
    assert torch.allclose(got, _brute_returns(r, nv, term, done, gamma, lam), atol=1e-9)


def test_td_lambda_returns_special_cases():
    r = torch.tensor([[1.0], [2.0], [3.0]])
    nv = torch.tensor([[10.0], [20.0], [30.0]])
    none = torch.zeros(3, 1, dtype=torch.bool)
    # lambda 0: one-step targets
    assert torch.allclose(td_lambda_returns(r, nv, none, none, 0.5, 0.0), r + 0.5 * nv)
    # lambda 1, no episode end: the discounted sum bootstrapped from the last value
    assert torch.allclose(td_lambda_returns(r, nv, none, none, 0.5, 1.0)[0], torch.tensor([1 + 0.5 * 2 + 0.25 * 3 + 0.125 * 30]))
    # a termination at step 1 cuts everything after it
    term = torch.tensor([[False], [True], [False]])
    got = td_lambda_returns(r, nv, term, term, 0.5, 1.0)
    assert torch.allclose(got[:2, 0], torch.tensor([1 + 0.5 * 2, 2.0]))
    with pytest.raises(ValueError, match="shape"):
        td_lambda_returns(r, nv[:2], none, none, 0.5, 1.0)


def test_schedules_run_from_start_to_end():
    p = TrackerDistillParams(beta=(0.8, 0.2), lr=1e-3, lr_end=1e-4)
    assert mixture_beta(p, 0.0) == pytest.approx(0.8) and mixture_beta(p, 1.0) == pytest.approx(0.2)
    assert mixture_beta(p, 0.5) == pytest.approx(0.5) and mixture_beta(p, 7.0) == pytest.approx(0.2)
    assert distill_lr(p, 0.0) == pytest.approx(1e-3) and distill_lr(p, 1.0) == pytest.approx(1e-4)
    with pytest.raises(ValueError, match="beta"):
        TrackerDistillParams(beta=(1.5, 0.0))
    with pytest.raises(ValueError, match="minibatch"):
        TrackerDistillParams(num_envs=2, horizon=2, minibatch_size=8)


# ----------------------------------------------------------------------------------- distiller
OFFSET = 0.15


class _OffsetTeacher(Imitator):
    """PD targets = the reference pose + OFFSET on every joint: the label is OFFSET everywhere."""

    def observe(self, state, reference):
        return Observations(proprio=state.dof_pos.float(), goal=None, extra={"ref": reference.dof_pos.float()})

    def act(self, obs, deterministic=True):
        return self.to_pd_targets(obs, self.policy_output(obs))

    def policy_output(self, obs, deterministic=True):
        return torch.full_like(obs.extra["ref"], OFFSET)

    def to_pd_targets(self, obs, output):
        return obs.extra["ref"] + output


class _Log:
    def __init__(self):
        self.rows = []

    def log(self, step, **kw):
        self.rows.append((step, kw))

    def truncate_after(self, step):
        self.rows = [r for r in self.rows if r[0] <= step]


def _ctx(workdir, stop=lambda: False):
    return SimpleNamespace(
        workdir=workdir,
        seed=3,
        device="cpu",
        console=Console(quiet=True),
        log=_Log(),
        should_stop=stop,
        spec_yaml=lambda: "spec_version: 1\n",
    )


@pytest.fixture(scope="module")
def walk_lib(amp):
    return MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp), amp)


@pytest.fixture(scope="module")
def tiny_latent(amp, walk_lib):
    torch.manual_seed(0)
    lat = make_vmp(VmpParams(**TINY), skeleton=amp)
    mean, std = feature_stats(lat.library_frame_features(walk_lib), lat.layout, 1e-6)
    lat.set_statistics(mean, std)
    return lat.eval()


def _setup(amp, lib, latent, **distill):
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator

    sim = MujocoSimulator(MujocoParams(threads=1), skeleton=amp, num_envs=4, seed=0, dtype=torch.float32)
    env = VmpTrackingEnv(VmpTrackerParams(action="residual", action_clip=3.0, reference_jump=False, episode_length_s=1.0), amp, lib, sim, latent, seed=0)
    ppo = PPOParams(num_envs=4, horizon=4, minibatch_size=8, actor_hidden=[32], critic_hidden=[32])
    torch.manual_seed(0)
    model = PPOTrainer(ppo).build_model(env.obs_dim, env.action_space)
    params = TrackerDistillParams(**{"num_envs": 4, "horizon": 8, "minibatch_size": 16, "epochs": 2, "checkpoint_every": 100, "print_every": 100, **distill})
    return env, model, params


def test_distiller_learns_the_teachers_actions(amp, walk_lib, tiny_latent, tmp_path):
    env, model, params = _setup(amp, walk_lib, tiny_latent, total_env_steps=32 * 40, lr=3e-3, lr_end=3e-3, beta=(1.0, 1.0))
    with torch.no_grad():
        before = float((model.mean_action(env.reset()) - OFFSET).square().mean())
    ctx = _ctx(tmp_path / "d")
    out = TrackerDistiller(params, 0.95, 0.95).run(ctx, env, _OffsetTeacher(), model)
    assert out is not None and out.is_file() and (tmp_path / "d" / "distill.pt").is_file()
    losses = [row["loss/action"] for _, row in ctx.log.rows]
    assert len(losses) == 40 and losses[-1] < 0.1 * losses[0]
    with torch.no_grad():
        after = float((model.mean_action(env.current_obs()) - OFFSET).square().mean())
    assert after < 0.1 * before
    assert all(math.isfinite(row["loss/value"]) for _, row in ctx.log.rows)
    env.close()


def test_distiller_resumes_to_the_same_weights(amp, walk_lib, tiny_latent, tmp_path):
    kw = {"total_env_steps": 32 * 4, "beta": (0.5, 0.0)}
    env, model, params = _setup(amp, walk_lib, tiny_latent, **kw)
    TrackerDistiller(params, 0.95, 0.95).run(_ctx(tmp_path / "straight"), env, _OffsetTeacher(), model)
    env.close()
    straight = {k: v.clone() for k, v in model.state_dict().items() if isinstance(v, torch.Tensor)}
    assert straight

    env, model, params = _setup(amp, walk_lib, tiny_latent, checkpoint_every=1, **kw)
    calls = {"n": 0}

    def stop_once():
        calls["n"] += 1
        return calls["n"] == 2

    assert TrackerDistiller(params, 0.95, 0.95).run(_ctx(tmp_path / "cut", stop_once), env, _OffsetTeacher(), model) is None
    env.close()
    env, model, params = _setup(amp, walk_lib, tiny_latent, checkpoint_every=1, **kw)
    assert TrackerDistiller(params, 0.95, 0.95).run(_ctx(tmp_path / "cut"), env, _OffsetTeacher(), model) is not None
    env.close()
    now = {k: v for k, v in model.state_dict().items() if isinstance(v, torch.Tensor)}
    assert now.keys() == straight.keys()
    for k, v in now.items():
        assert torch.equal(v, straight[k]), k


# ------------------------------------------------------------------------------------ end to end
SPEC = """spec_version: 1
name: vmp-distill-tiny
device: cpu
seed: 0
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk]}}
simulator: {name: mujoco, params: {threads: 1}}
%s
latent:
  name: vmp
  params: {window_half: 6, latent_dim: 8, channels: 16, res_blocks: 1, downsample: 1}
  trainer:
    name: vmp_track
    params:
      vae: {num_iterations: 4, batch_size: 8, checkpoint_every: 100, print_every: 100}
      distill: {num_envs: 2, horizon: 4, total_env_steps: 16, minibatch_size: 4, epochs: 1}
      ppo: {num_envs: 2, horizon: 4, total_env_steps: 8, minibatch_size: 4, epochs: 1, actor_hidden: [16], critic_hidden: [16], checkpoint_every: 100}
      tracker: {conditioning: LM, action: residual, episode_length_s: 2.0}
"""
TEACHER = """imitator:
  name: phc
  params: {obs: rot, action: residual, eval_every: 1000}
  trainer:
    name: ppo
    params: {num_envs: 2, horizon: 4, total_env_steps: 8, minibatch_size: 4, epochs: 1, actor_hidden: [16], critic_hidden: [16]}
"""


def test_mocap_run_distills_the_imitator_into_the_tracker_before_ppo(tmp_path):
    import json

    from mocap.testing import invoke

    spec = tmp_path / "vmp.yaml"
    spec.write_text(SPEC % TEACHER)
    out = tmp_path / "runs" / "vmp"
    result = invoke(["run", spec, "--out", out])
    assert result.exit_code == 0, result.output + result.stderr
    (stage,) = list((tmp_path / "runs" / "artifacts").glob("latent-*"))
    assert (stage / "tracker_distill" / "policy.pt").is_file() and (stage / "vmp.pt").is_file()
    table = json.loads((stage / "tracker_distill" / "eval.json").read_text())
    assert table["aggregate"]["total"] == 1
    stages = [json.loads(x)["stage"] for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert stages.count("latent/tracker_distill") == 2 and stages.count("latent/tracker") == 1  # 16 / (2 x 4), 8 / (2 x 4)
    assert "ppo: starting from" in result.output and "tracker_distill" in result.output
    import torch

    data = torch.load(stage / "vmp.pt", weights_only=False)
    assert data["metrics"]["distill/env_steps"] == 16.0 and "distill/loss/action" in data["metrics"]


def test_distill_without_a_teacher_is_one_error_line(tmp_path):
    from mocap.testing import invoke

    spec = tmp_path / "vmp.yaml"
    spec.write_text(SPEC % "")
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "vmp"])
    assert result.exit_code != 0
    text = result.output + result.stderr
    assert "Traceback" not in text and "needs a teacher" in text


def test_eval_of_a_distilled_vmp_tracker_compares_it_with_its_teacher_not_with_itself():
    """`mocap eval checkpoints/vmp` printed the VMP tracker's numbers twice, once labelled as the
    teacher: for a latent with its own tracker the spec's imitator is now the teacher it is compared with."""
    from pathlib import Path

    from mocap.eval_targets import build_evaluation_target, load_evaluation_target
    from mocap.plugins import get_plugins
    from mocap_phc.imitator import PHCImitator
    from mocap_vmp.tracking import VmpImitator

    plugins = get_plugins()
    target = load_evaluation_target(Path(__file__).resolve().parents[1] / "checkpoints" / "vmp", plugins)
    loaded = build_evaluation_target(target, plugins)
    assert loaded.own_tracker and isinstance(loaded.policy, VmpImitator)
    assert isinstance(loaded.imitator, PHCImitator) and loaded.imitator is not loaded.policy
