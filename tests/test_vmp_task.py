"""VMP as a task action space (``mocap_vmp.task``, ``VmpLatent.task_action_space`` / ``to_latent`` /
``decode_action`` / ``random_action``), a smoke PPO run of the ``speed`` task through a tiny VMP
checkpoint, and the latent-space metrics (LDA accuracy, mutual information)."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from mocap.interfaces import Box
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap.motion.library import MotionLibrary
from mocap.observations import proprioception, proprioception_dim
from mocap.state import Observations
from mocap_vmp.features import feature_stats, standardize
from mocap_vmp.latent import VmpParams, make_vmp
from mocap_vmp.metrics import (
    discrete_mutual_information,
    latent_label_metrics,
    lda_accuracy,
    mutual_information,
    quantile_bins,
)
from mocap_vmp.task import features_from_proprio
from mocap_vmp.tracking import VmpTrackerParams, conditioning_dim, state_features

torch.set_num_threads(1)

TINY = {"window_half": 6, "latent_dim": 8, "channels": 16, "res_blocks": 1, "downsample": 1}


@pytest.fixture(scope="module")
def lib(amp):
    return MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp), amp)


def _tracker_entry(amp, latent, **kw):
    """A tracking-policy entry as the vmp_track trainer writes it (untrained weights, non-trivial head)."""
    from mocap.rl.networks import ActorCritic

    params = VmpTrackerParams(**{"conditioning": "LM", "action": "residual", "action_clip": 3.0, **kw})
    D = amp.num_dofs
    obs_dim = proprioception_dim(amp.num_bodies) + params.prev_actions * D + conditioning_dim(params.conditioning, latent.layout.dim, latent.latent_dim)
    torch.manual_seed(1)
    policy = ActorCritic(obs_dim, Box((D,)), actor_hidden=[16], critic_hidden=[16])
    with torch.no_grad():
        policy.action_head.weight.mul_(30.0)  # actions of order 0.1 rad, so that wrong inputs show
    return {"params": params.model_dump(mode="json"), "policy_config": policy.config, "policy_state": policy.state_dict()}


@pytest.fixture(scope="module")
def vmp_file(amp, lib, tmp_path_factory):
    """A tiny combined vmp.pt (stage-1 VAE with the walk clip's statistics + a tracker entry)."""
    from mocap.checkpoint import save_checkpoint

    torch.manual_seed(0)
    lat = make_vmp(VmpParams(**TINY), skeleton=amp)
    mean, std = feature_stats(lat.library_frame_features(lib), lat.layout, 1e-6)
    lat.set_statistics(mean, std)
    path = tmp_path_factory.mktemp("vmp") / "vmp.pt"
    save_checkpoint(
        path,
        {
            "format": "mocap_vmp.vmp/1",
            "latent": lat.state_dict(),
            "config": lat.config,
            "frame_latents": lat.encode_library(lib),
            "clip_names": list(lib.clip_names),
            "tracker": _tracker_entry(amp, lat),
        },
    )
    return path


def _load(amp, vmp_file, **kw):
    return make_vmp(VmpParams(**{**TINY, **kw}), skeleton=amp, checkpoint=vmp_file)


def _states(amp, lib, n=4, steps=3):
    """Simulated states a few steps after reference starts (body velocities consistent with qvel)."""
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator

    sim = MujocoSimulator(MujocoParams(threads=1), skeleton=amp, num_envs=n)
    ids = torch.zeros(n, dtype=torch.long)
    t = torch.linspace(0.1, 1.0, n, dtype=torch.float64)
    sim.reset(torch.arange(n), lib.frames(ids, t))
    for k in range(steps):
        state = sim.step(lib.frames(ids, t + (k + 1) * sim.dt).dof_pos)
    return sim, state


# ----------------------------------------------------------------------------------- features
def test_features_from_proprio_match_the_state(amp, lib, vmp_file):
    latent = _load(amp, vmp_file)
    sim, state = _states(amp, lib)
    got = features_from_proprio(proprioception(state).double(), amp, latent.ee_index)
    want = state_features(state, latent.ee_index).double()
    s = latent.layout.slices
    for g in ("h", "theta", "v", "q", "p"):
        torch.testing.assert_close(got[:, s[g]], want[:, s[g]], atol=2e-5, rtol=0, msg=g)
    # joint speeds by a central difference of the Euler decomposition: close to MuJoCo's qvel
    torch.testing.assert_close(got[:, s["qd"]], want[:, s["qd"]], atol=2e-3 * (1 + float(want[:, s["qd"]].abs().max())), rtol=0)
    assert float(want[:, s["qd"]].abs().max()) > 0.5  # the states move, so the check has teeth
    sim.close()


# ------------------------------------------------------------------------------ action space
def test_task_action_space_and_shapes(amp, lib, vmp_file):
    latent = _load(amp, vmp_file)
    assert latent.decodes_pd_targets and latent.task_action_space == Box((8,))
    assert _load(amp, vmp_file, task_action_clip=2.0).task_action_space == Box((8,), -2.0, 2.0)
    sim, state = _states(amp, lib, n=3)
    obs = Observations(proprio=proprioception(state), goal=None, extra={})
    a = torch.randn(3, 8)
    assert torch.equal(latent.to_latent(obs, a), a)  # default: the action is z
    clipped = _load(amp, vmp_file, task_action_clip=0.5).to_latent(obs, 3 * a)
    assert float(clipped.abs().max()) <= 0.5
    targets = latent.decode_action(obs, a)
    assert targets.shape == (3, amp.num_dofs) and bool(torch.isfinite(targets).all())
    torch.testing.assert_close(_load(amp, vmp_file).decoder(obs, a), _load(amp, vmp_file).decode_action(obs, a))  # same map
    # random_action: z ~ N(0, I) decoded; reproducible with a generator, different across seeds
    r1 = _load(amp, vmp_file).random_action(obs, generator=torch.Generator().manual_seed(3))
    r2 = _load(amp, vmp_file).random_action(obs, generator=torch.Generator().manual_seed(3))
    r3 = _load(amp, vmp_file).random_action(obs, generator=torch.Generator().manual_seed(4))
    assert r1.shape == (3, amp.num_dofs) and torch.equal(r1, r2) and not torch.allclose(r1, r3)
    sim.close()


def test_a_stage_one_latent_cannot_decode(amp, vmp_file):
    stage1 = make_vmp(VmpParams(**TINY), skeleton=amp)
    assert not stage1.decodes_pd_targets
    with pytest.raises(NotImplementedError, match="stage II"):
        stage1.decode_action(Observations(proprio=torch.zeros(1, proprioception_dim(amp.num_bodies))), torch.zeros(1, 8))


def test_decoding_is_the_tracker_on_the_decoded_centre_frame(amp, lib, vmp_file):
    """PD targets = reference q of the window's centre frame + tracker(proprio | history | m, z)."""
    latent = _load(amp, vmp_file)
    dec = latent._tracker_decoder()
    sim, state = _states(amp, lib, n=2)
    prop = proprioception(state)
    obs = Observations(proprio=prop, goal=None, extra={})
    z = torch.randn(2, 8, generator=torch.Generator().manual_seed(0))
    W = latent.params.window_half
    with torch.no_grad():
        window = latent.decode_window(z)
        m = window[:, W]
        D = amp.num_dofs
        x = torch.cat((prop, torch.zeros(2, 2 * D), standardize(m, latent.feat_mean, latent.feat_std), z), -1)
        a1 = dec.policy.mean_action(x).clamp(-3, 3)
    t1 = latent.decode_action(obs, z)
    torch.testing.assert_close(t1, m[:, latent.layout.slices["q"]] + a1)
    # the history advances: the next call sees a_{t-1} = a1, a_{t-2} = 0 (residual hold action)
    x2 = torch.cat((prop, a1, torch.zeros(2, D), standardize(m, latent.feat_mean, latent.feat_std), z), -1)
    with torch.no_grad():
        a2 = dec.policy.mean_action(x2).clamp(-3, 3)
    torch.testing.assert_close(latent.decode_action(obs, z), m[:, latent.layout.slices["q"]] + a2)
    assert not torch.allclose(a1, a2)
    # a reset restarts env 1's history only
    latent.reset_envs(torch.tensor([1]))
    latent.decode_action(obs, z)
    assert torch.equal(dec.hist[1, 1], torch.zeros(D)) and not torch.equal(dec.hist[0, 1], torch.zeros(D))
    sim.close()


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 1000), scale=st.floats(0.01, 3.0))
def test_residual_is_around_the_current_encoding(amp, lib, vmp_file, seed, scale):
    latent = _load(amp, vmp_file, task_action="residual")
    frames = lib.frames(torch.zeros(2, dtype=torch.long), torch.tensor([0.2, 0.7], dtype=torch.float64))
    obs = Observations(proprio=proprioception(frames).float(), goal=None, extra={})
    z0 = latent.to_latent(obs, torch.zeros(2, 8))
    # zero residual = the encoder's mean of the current frame held over the window
    feat = features_from_proprio(obs.proprio, amp, latent.ee_index)
    window = feat[:, None, :].expand(-1, latent.window, -1)
    with torch.no_grad():
        post = latent.encoder(Observations(proprio=obs.proprio, extra={"window": window}))
        torch.testing.assert_close(z0, post.mean)
        torch.testing.assert_close(latent.decode_window(z0), latent.decode_window(post.mean))
    # and a residual adds linearly
    a = scale * torch.randn(2, 8, generator=torch.Generator().manual_seed(seed))
    torch.testing.assert_close(latent.to_latent(obs, a) - z0, a, atol=1e-5, rtol=0)


# ------------------------------------------------------------------------------- speed + PPO
class _Ctx:
    def __init__(self, workdir, make_env):
        from mocap.runlog import MetricsLogger
        from rich.console import Console

        self.workdir = workdir
        self.seed = 0
        self.device = "cpu"  # a StageContext field PPO reads
        self.make_rl_env = make_env
        self.log = MetricsLogger(workdir / "metrics.jsonl", "task")
        self.console = Console(quiet=True)

    def should_stop(self):
        return False

    def spec_yaml(self):
        return None


def test_speed_task_trains_with_ppo_through_a_tiny_vmp(amp, lib, vmp_file, tmp_path):
    from mocap.task_env import TaskEnv
    from mocap.rl.ppo import PPOParams, PPOTrainer
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator
    from mocap_tasks.speed import SpeedParams, make_speed

    latent = _load(amp, vmp_file)

    def make_env(n):
        task = make_speed(SpeedParams(), skeleton=amp, num_envs=n)
        sim = MujocoSimulator(MujocoParams(threads=1), skeleton=amp, num_envs=n)
        return TaskEnv(task, latent, lambda obs, out: out, lib, sim, seed=0)

    params = PPOParams(num_envs=2, horizon=4, total_env_steps=16, minibatch_size=4, epochs=1, actor_hidden=[16], critic_hidden=[16], checkpoint_every=100)
    res = PPOTrainer(params).run(_Ctx(tmp_path, make_env))
    assert res.checkpoint is not None and res.checkpoint.name == "policy.pt" and res.checkpoint.is_file()
    import json

    rows = [json.loads(x) for x in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and all(math.isfinite(r["reward"]) for r in rows if "reward" in r)
    from mocap.rl.networks import load_policy

    policy = load_policy(res.checkpoint)
    assert policy.action_dim == 8  # the task policy acts in VMP's latent space


# ------------------------------------------------------------------------------------ metrics
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(2, 5), d=st.integers(1, 6))
def test_lda_separates_separable_classes_and_not_noise(seed, k, d):
    g = torch.Generator().manual_seed(seed)
    y = torch.arange(k).repeat(20)
    centres = torch.randn(k, d, generator=g, dtype=torch.float64)
    centres = centres / centres.norm(dim=-1, keepdim=True).clamp_min(1e-6) * 10.0
    centres[:, 0] = 10.0 * torch.arange(k)  # distinct along axis 0 for sure
    x = centres[y] + 0.05 * torch.randn(len(y), d, generator=g, dtype=torch.float64)
    assert lda_accuracy(x, y) == 1.0 and lda_accuracy(x, y, folds=1) == 1.0
    # features independent of the labels: near chance under cross-validation
    noise = torch.randn(200 * k, d, generator=g, dtype=torch.float64)
    labels = torch.arange(k).repeat(200)
    assert lda_accuracy(noise, labels) < 1.0 / k + 0.15


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(1, 6), m=st.integers(1, 6), n=st.integers(5, 200))
def test_discrete_mutual_information_properties(seed, k, m, n):
    g = torch.Generator().manual_seed(seed)
    a = torch.randint(0, k, (n,), generator=g)
    b = torch.randint(0, m, (n,), generator=g)
    p = torch.bincount(a).double() / n
    p = p[p > 0]
    entropy = float(-(p * p.log()).sum())
    assert discrete_mutual_information(a, a) == pytest.approx(entropy, abs=1e-9)  # I(X; X) = H(X)
    mi = discrete_mutual_information(a, b)
    assert 0.0 <= mi <= min(entropy, discrete_mutual_information(b, b)) + 1e-9
    assert mi == pytest.approx(discrete_mutual_information(b, a), abs=1e-9)
    assert discrete_mutual_information(a, torch.zeros(n)) == pytest.approx(0.0, abs=1e-12)
    # a relabelling (bijection) changes nothing
    assert discrete_mutual_information(7 - 3 * a, b) == pytest.approx(mi, abs=1e-9)


def test_binned_mutual_information(amp):
    g = torch.Generator().manual_seed(0)
    y = torch.arange(4).repeat(250)
    z = torch.cat(
        (y[:, None].double() + 0.01 * torch.randn(1000, 1, generator=g, dtype=torch.float64), torch.randn(1000, 1, generator=g, dtype=torch.float64)), -1
    )
    codes = quantile_bins(z, 4)
    assert codes.shape == (1000, 2) and int(codes.min()) == 0 and int(codes.max()) == 3
    assert torch.bincount(codes[:, 1]).tolist() == [250] * 4  # equal-count bins
    # dim 0 carries all of H(y) = log 4, dim 1 almost nothing: the mean is about log(4) / 2
    assert mutual_information(z, y, bins=4) == pytest.approx(math.log(4) / 2, abs=0.03)


def test_latent_label_metrics_on_bundled_clips(amp):
    lib2 = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk", "run"])).load(amp), amp)
    torch.manual_seed(0)
    lat = make_vmp(VmpParams(**TINY), skeleton=amp)
    mean, std = feature_stats(lat.library_frame_features(lib2), lat.layout, 1e-6)
    lat.set_statistics(mean, std)
    out = latent_label_metrics(lat.eval(), lib2, folds=3, bins=5)
    assert out["num_labels"] == 2.0
    assert 0.5 <= out["lda_accuracy"] <= 1.0  # even an untrained encoder tells walking from running
    assert 0.0 < out["mutual_information"] <= math.log(2) + 1e-9


def test_mocap_run_of_a_task_spec_through_a_vmp_checkpoint(vmp_file, tmp_path):
    from mocap.testing import invoke

    spec = tmp_path / "spec.yaml"
    spec.write_text(
        "spec_version: 1\nname: speed-vmp-tiny\ndevice: cpu\nhumanoid: {name: amp}\n"
        "motions: {name: deepmimic, params: {clips: [walk]}}\nsimulator: {name: mujoco, params: {threads: 1}}\n"
        "latent:\n  name: vmp\n  params: {window_half: 6, latent_dim: 8, channels: 16, res_blocks: 1, downsample: 1, task_action: residual}\n"
        f"  checkpoint: {vmp_file}\n"
        "task:\n  name: speed\n  trainer: {name: ppo, params: {num_envs: 2, horizon: 4, total_env_steps: 16, minibatch_size: 4, "
        "epochs: 1, actor_hidden: [16], critic_hidden: [16], torch_threads: 1}}\n"
        "eval:\n  trainer: {name: eval_suite, params: {imitation: {video: false}, "
        "generation: {num_rollouts: 2, seconds: 0.3, video_rollouts: 0}}}\n"
    )
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "t"])
    assert result.exit_code == 0, result.output + (result.stderr or "")
    (policy,) = list((tmp_path / "runs" / "artifacts").glob("task-*/policy.pt"))
    from mocap.rl.networks import load_policy

    assert load_policy(policy).action_dim == 8
    # eval_suite of the cell: VMP imitates with its own tracker and samples its prior
    import json

    stages = {s["stage"]: s for s in json.loads((tmp_path / "runs" / "t" / "stages.json").read_text())}
    m = stages["eval"]["metrics"]
    assert m["imitation/total"] == 1 and 0.0 <= m["imitation/success_rate"] <= 1.0
    assert 0.0 <= m["generation/fall_rate"] <= 1.0
    gen = invoke(["generate", tmp_path / "runs" / "t", "--rollouts", "2", "--seconds", "0.3", "--json", tmp_path / "g.json"])
    assert gen.exit_code == 0, gen.output + (gen.stderr or "")
    assert json.loads((tmp_path / "g.json").read_text())["num_rollouts"] == 2


def test_the_vae_trainer_reports_the_latent_metrics(amp, tmp_path):
    from mocap_vmp.trainer import SupervisedParams
    from test_vmp import FakeContext, _run

    two = DeepMimicSource(DeepMimicParams(clips=["walk", "run"])).load(amp)
    result = _run(FakeContext(tmp_path, amp, two), SupervisedParams(num_iterations=5, batch_size=16, checkpoint_every=100, print_every=100))
    m = result.metrics
    assert 0.5 <= m["latent/lda_accuracy"] <= 1.0 and 0.0 < m["latent/mutual_information"] <= math.log(2) + 1e-9
    saved = torch.load(result.checkpoint, weights_only=False)
    assert saved["metrics"]["latent/lda_accuracy"] == m["latent/lda_accuracy"]


def test_task_state_round_trip_restores_the_history(amp, lib, vmp_file):
    a, b, c = _load(amp, vmp_file), _load(amp, vmp_file), _load(amp, vmp_file)
    assert a.task_state_dict() == {}
    sim, state = _states(amp, lib, n=2)
    obs = Observations(proprio=proprioception(state), goal=None, extra={})
    z = torch.randn(2, 8, generator=torch.Generator().manual_seed(0))
    a.decode_action(obs, z)
    b.load_task_state_dict(a.task_state_dict())
    ta, tb, tc = a.decode_action(obs, z), b.decode_action(obs, z), c.decode_action(obs, z)
    torch.testing.assert_close(ta, tb)
    assert not torch.allclose(ta, tc)  # without the history (c) the tracker sees other previous actions
    sim.close()


def test_segment_labels_follow_the_papers_protocol():
    """VMP Sec. 4.2: consecutive 2 s of codes form a class, the next 2 s are left out (issue 27 item 9)."""
    from mocap_vmp.metrics import segment_labels

    frame_clip = torch.cat((torch.zeros(150, dtype=torch.long), torch.ones(30, dtype=torch.long)))
    y = segment_labels(frame_clip, torch.tensor([30.0, 30.0]))
    assert torch.equal(y[:60], torch.zeros(60, dtype=torch.long))
    assert bool((y[60:120] == -1).all())
    assert torch.equal(y[120:150], torch.ones(30, dtype=torch.long))
    assert torch.equal(y[150:], torch.full((30,), 2, dtype=torch.long))
    # at another frame rate the same seconds
    y60 = segment_labels(torch.zeros(300, dtype=torch.long), torch.tensor([60.0]))
    assert int((y60 == 0).sum()) == 120 and int((y60 == -1).sum()) == 120 and int((y60 == 1).sum()) == 60
