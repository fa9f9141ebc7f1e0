"""VMP stage II (plugin ``latent_vmp``): the tracking env's reward terms, the end-effector
termination counter, the conditioning ablations' observations, standardization, exact resume, the
joint-MAE metric and one tiny ``mocap run`` of the ``vmp_track`` trainer (VAE + tracker -> vmp.pt).
The reward terms on random features are tested in ``test_vmp_track_rewards.py``."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

torch.set_num_threads(1)

from mocap.episodes import RewardTerms
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap.motion.library import MotionLibrary
from mocap.state import Trajectories
from mocap_vmp.features import (
    feature_stats,
    window_features,
    window_rows,
)
from mocap_vmp.latent import VmpParams, make_vmp
from mocap_vmp.metrics import joint_mae_deg, joint_mae_deg_from_dofs
from mocap_vmp.tracking import (
    VmpConditioning,
    VmpTrackerParams,
    VmpTrackingEnv,
    conditioning_dim,
    end_effector_error,
    persist_steps,
    smoothness_errors,
    state_features,
    tracking_errors,
    update_counter,
    vmp_imitator,
    vmp_reward_terms,
    vmp_reward_weights,
)

TINY = {
    "window_half": 6,
    "latent_dim": 8,
    "channels": 16,
    "res_blocks": 1,
    "downsample": 1,
}
f64 = torch.float64


@pytest.fixture(scope="module")
def walk(amp):
    return DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp)


@pytest.fixture(scope="module")
def lib(amp, walk):
    return MotionLibrary(walk, amp)


@pytest.fixture(scope="module")
def latent(amp, lib):
    """An untrained tiny VAE with the walk clip's statistics (the env only needs stats + encoder)."""
    torch.manual_seed(0)
    lat = make_vmp(VmpParams(**TINY), skeleton=amp)
    mean, std = feature_stats(lat.library_frame_features(lib), lat.layout, 1e-6)
    lat.set_statistics(mean, std)
    return lat.eval()


def _sim(amp, n):
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator

    return MujocoSimulator(MujocoParams(threads=1), skeleton=amp, num_envs=n, seed=0, dtype=torch.float32)


def _env(amp, lib, latent, n=3, seed=0, **kw):
    return VmpTrackingEnv(VmpTrackerParams(**kw), amp, lib, _sim(amp, n), latent, seed=seed)


def _frame(draw_vec, n):
    return torch.tensor(draw_vec, dtype=f64).reshape(n, -1)


# --------------------------------------------------------------------------------- reward terms
def _weighted_sum(weights, info):
    """sum_k w_k r_k of the logged (unweighted) terms, float64."""
    return sum(w * info[f"reward/{k}"].double() for k, w in weights.items())


@pytest.mark.parametrize("form", ["paper", "exp"])
def test_logged_reward_terms_are_the_unweighted_formulas_and_sum_to_the_reward(amp, lib, latent, form):
    """Each ``reward/<term>`` is the raw term (alive 1, e_g or its kernel, e_s); the step's reward is
    their sum weighted by VmpRewardWeights (-c_g or +c_g, -c_s, c_alive)."""
    env = _env(amp, lib, latent, n=2, reward_form=form, exp_scale=2.0)
    p, cond = env.params, env.cond
    env.reset()
    g = torch.Generator().manual_seed(4)
    for _ in range(3):
        ref, hist = env._ref_feat.clone(), env.hist_targets.clone()
        res = env.step(0.1 * torch.randn(2, env.num_actions, generator=g))
        assert not bool((res.terminated | res.truncated).any())  # env.sim.state is the stepped state
        st_ = env.sim.state
        sim = state_features(st_, cond.ee_index).to(ref)
        track = tracking_errors(cond.reward_standardize(ref), cond.reward_standardize(sim), env.layout)
        assert torch.equal(res.info["reward/alive"], torch.ones(2))
        for gr, e in track.items():
            want = e if form == "paper" else torch.exp(-2.0 * e / env.track_dims[gr])
            torch.testing.assert_close(res.info[f"reward/track/{gr}"], want, rtol=1e-5, atol=1e-6)
        if form == "exp":
            v = torch.stack([res.info[f"reward/track/{gr}"] for gr in track])
            assert bool((v >= 0).all()) and bool((v <= 1).all())
        a = env.hist_targets[:, 0]  # this step's PD targets (smoothness_on: targets)
        torch.testing.assert_close(res.info["reward/smooth/da"], (a - hist[:, 0]).square().sum(-1))
        torch.testing.assert_close(res.info["reward/smooth/dda"], (a - 2 * hist[:, 0] + hist[:, 1]).square().sum(-1))
        torch.testing.assert_close(res.info["reward/smooth/tau"], st_.dof_force.float().square().sum(-1), rtol=1e-5, atol=1e-3)
        weights = env.rewards.weights
        assert weights == vmp_reward_weights(p.reward, form)
        assert weights["track/q"] == (-1.0 if form == "paper" else 1.0) and weights["smooth/tau"] == -1e-5
        torch.testing.assert_close(res.reward.double(), _weighted_sum(weights, res.info), rtol=1e-5, atol=1e-4)
    env.close()


@pytest.mark.parametrize("form", ["paper", "exp"])
def test_reward_weights_from_the_params_reach_the_env_reward(amp, lib, latent, form):
    """Changed VmpRewardWeights: the same raw terms (the dynamics do not see the reward), the reward
    their sum with the new weights."""
    changed = {"h": 2.0, "qd": 0.0, "p": 0.25, "alive": 3.0, "da": 0.5, "tau": 1e-3}
    a, b = _env(amp, lib, latent, n=2, seed=2, reward_form=form), _env(amp, lib, latent, n=2, seed=2, reward_form=form, reward=changed)
    assert b.rewards.weights["alive"] == 3.0 and b.rewards.weights["smooth/tau"] == -1e-3
    assert b.rewards.weights["track/h"] == (-2.0 if form == "paper" else 2.0) and b.rewards.weights["track/qd"] == 0.0
    a.reset(), b.reset()
    g = torch.Generator().manual_seed(5)
    for _ in range(4):
        act = 0.2 * torch.randn(2, a.num_actions, generator=g)
        ra, rb = a.step(act), b.step(act)
        for k in a.rewards.names:
            assert torch.equal(ra.info[f"reward/{k}"], rb.info[f"reward/{k}"])
        torch.testing.assert_close(rb.reward.double(), _weighted_sum(b.rewards.weights, rb.info), rtol=1e-5, atol=1e-4)
        assert not torch.equal(ra.reward, rb.reward)
    a.close(), b.close()


# --------------------------------------------------------------------------------- termination
@settings(max_examples=60, deadline=None)
@given(over=st.lists(st.booleans(), min_size=1, max_size=200), steps=st.integers(1, 20))
def test_termination_counter_fires_after_persistent_error(over, steps):
    errs = torch.tensor([[0.5 if o else 0.1] for o in over], dtype=f64)
    counter = torch.zeros(1, dtype=torch.long)
    run = 0
    for t, o in enumerate(over):
        counter, fired = update_counter(counter, errs[t], 0.2, steps)
        run = run + 1 if o else 0
        assert int(counter) == run  # consecutive steps above the threshold; reset when it drops
        assert bool(fired) == (run >= steps)  # exactly when the deviation has lasted `steps` steps


def test_termination_duration_and_norms():
    assert persist_steps(3.0, 1 / 30) == 90 and persist_steps(3.0, 1 / 60) == 180 and persist_steps(0.001, 1 / 30) == 1
    counter = torch.zeros(2, dtype=torch.long)
    fired_at = [None, None]
    for t in range(200):
        e = torch.tensor([0.25, 0.25 if t != 50 else 0.2])  # env 1 drops to the threshold (not above) once
        counter, fired = update_counter(counter, e, 0.2, 90)
        for i in range(2):
            if fired[i] and fired_at[i] is None:
                fired_at[i] = t + 1  # steps elapsed
    assert fired_at == [90, 51 + 90]  # 3 s at 30 Hz of continuous error
    ref = torch.zeros(1, 6)
    sim = torch.tensor([[0.3, 0.4, 0.0, 0.1, 0.0, 0.0]])
    assert math.isclose(float(end_effector_error(ref, sim, "max_euclidean")), 0.5, rel_tol=1e-6)
    assert math.isclose(float(end_effector_error(ref, sim, "inf")), 0.4, rel_tol=1e-6)


def test_env_terminates_after_persistent_end_effector_error(amp, lib, latent):
    """Zero absolute actions (PD targets at mid-range) make the humanoid collapse: the episode ends by
    the end-effector rule exactly when the counter reaches f / dt steps (f = 0.5 s here, to keep it short)."""
    env = _env(amp, lib, latent, n=2, termination_persist_s=0.5, episode_length_s=5.0)
    env.reset()
    steps = persist_steps(0.5, env.dt)
    seen = []
    for _ in range(40):
        before = env.ee_counter.clone()
        res = env.step(torch.zeros(2, env.num_actions))
        for i in range(2):
            if bool(res.terminated[i]):
                seen.append(int(before[i]) + 1)
        if seen:
            break
    assert seen and all(s == steps for s in seen)
    assert float(res.info["terminated/ee"].sum()) >= 1


# -------------------------------------------------------------------------------- conditioning
@pytest.mark.parametrize(
    "mode,future,use_m,use_z",
    [
        ("M", 0, True, False),
        ("M5", 5, True, False),
        ("M10", 10, True, False),
        ("L", 0, False, True),
        ("LM", 0, True, True),
    ],
)
def test_conditioning_size_and_content(amp, lib, latent, mode, future, use_m, use_z):
    F, Z = latent.layout.dim, latent.latent_dim
    assert conditioning_dim(mode, F, Z) == (F * (1 + future) if use_m else 0) + (Z if use_z else 0)
    cond = VmpConditioning(VmpTrackerParams(conditioning=mode), latent, lib, 1 / 30)
    frames = torch.tensor([0, 7, 30, 38])  # 38 = the walk clip's last frame: future frames edge-padded
    clips = torch.zeros(4, dtype=torch.long)
    times = frames.double() / 30.0
    from mocap_vmp.tracking import clip_frames

    ref = clip_frames(lib, clips, times)
    c, feat = cond(ref, clips, times)
    assert c.shape == (4, cond.dim)
    # m_t = the stage-1 features of the frame in its own heading, standardized with the VAE's statistics
    rows = window_rows(lib, frames, future)[:, future:]  # the centre frame and the next K (edge-padded)
    own = window_features(lib, rows[:, :1], latent.ee_index, centre=0)[:, 0]
    torch.testing.assert_close(feat, own, atol=2e-4, rtol=1e-4)
    col = 0
    if use_m:
        torch.testing.assert_close(c[:, :F], (own - latent.feat_mean) / latent.feat_std, atol=2e-2, rtol=1e-3)
        col = F
    if future:
        # the next K frames (edge-padded at the clip end), in the heading of m_t, standardized
        fut = window_features(lib, rows, latent.ee_index, centre=0)[:, 1:]  # (4, K, F)
        got = c[:, F : F * (1 + future)].reshape(4, future, F)
        torch.testing.assert_close(got, (fut - latent.feat_mean) / latent.feat_std, atol=2e-2, rtol=1e-3)
        assert torch.equal(rows[3], torch.full((future + 1,), 38))
        col = F * (1 + future)
    if use_z:
        z = latent.encode_library(lib)[frames]
        torch.testing.assert_close(c[:, col:], z, atol=1e-5, rtol=1e-5)
        col += Z
    assert col == c.shape[1]


def test_observation_layout_in_env(amp, lib, latent):
    from mocap.observations import proprioception

    dims = {}
    for mode in ("M", "M5", "M10", "L", "LM"):
        env = _env(amp, lib, latent, n=2, conditioning=mode)
        obs = env.reset()
        P = 15 * amp.num_bodies - 2
        A = amp.num_dofs
        dims[mode] = obs.shape[1]
        assert obs.shape == (2, env.obs_dim) == (2, P + 2 * A + env.cond.dim)
        torch.testing.assert_close(obs[:, :P], proprioception(env.sim.state).float())
        # previous actions at a reset: the action that holds the reset pose (absolute map)
        hold = (env.sim.state.dof_pos.float() - env.action_map.offset.float()) / env.action_map.scale.float()
        torch.testing.assert_close(obs[:, P : P + A], hold, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(obs[:, P + A : P + 2 * A], hold, atol=1e-5, rtol=1e-5)
        from mocap_vmp.tracking import clip_frames

        ref = clip_frames(lib, env.clip_ids, env.target_time)
        c, _ = env.cond(ref, env.clip_ids, env.target_time)
        torch.testing.assert_close(obs[:, P + 2 * A :], c)
        env.close()
    F, Z = latent.layout.dim, latent.latent_dim
    assert dims["M5"] - dims["M"] == 5 * F and dims["M10"] - dims["M"] == 10 * F
    assert dims["LM"] - dims["M"] == Z and dims["LM"] - dims["L"] == F


def test_standardization_uses_the_vae_statistics(amp, lib, latent):
    """The observation's m_t follows the VAE's saved statistics; the reward uses them with the std floored."""
    import copy

    other = copy.deepcopy(latent)
    other.set_statistics(latent.feat_mean + 0.5, latent.feat_std * 2.0)
    p = VmpTrackerParams(conditioning="M")
    clips, times = (
        torch.zeros(3, dtype=torch.long),
        torch.tensor([0.0, 0.5, 1.0], dtype=f64),
    )
    ref = lib.frames(clips, times)
    c1, feat = VmpConditioning(p, latent, lib, 1 / 30)(ref, clips, times)
    c2, _ = VmpConditioning(p, other, lib, 1 / 30)(ref, clips, times)
    th = latent.layout.theta
    torch.testing.assert_close(c2, (feat - other.feat_mean) / other.feat_std)
    torch.testing.assert_close(c1[:, th], feat[:, th])  # orientation channels are not standardized
    cond = VmpConditioning(VmpTrackerParams(reward_std_min=0.05), latent, lib, 1 / 30)
    assert bool((cond.reward_std >= 0.05).all()) and bool((cond.reward_std[th] == 1).all())
    keep = latent.feat_std >= 0.05
    torch.testing.assert_close(
        cond.reward_std[keep & (torch.arange(len(keep)) >= th.stop)],
        latent.feat_std[keep & (torch.arange(len(keep)) >= th.stop)],
    )


def test_reward_is_alive_bonus_when_tracking_is_perfect(amp, lib, latent):
    """A state equal to the reference (and no motion of the targets, no torque) earns exactly c_alive."""
    env = _env(amp, lib, latent, n=2)
    env.reset()
    ref = lib.frames(env.clip_ids, env.target_time)
    fa = env.cond.reward_standardize(state_features(ref, env.cond.ee_index))
    track = tracking_errors(fa, fa, env.layout)
    a = torch.zeros(2, env.num_actions)
    terms = vmp_reward_terms(track, smoothness_errors(a, a, a, torch.zeros(2, env.num_actions)))
    total, _ = RewardTerms(vmp_reward_weights(env.params.reward))(terms)
    assert torch.allclose(total, torch.full((2,), 6.0, dtype=f64))
    env.close()


def test_only_positive_rewards_clips_the_step_reward_at_zero(amp, lib, latent):
    """Wild actions: the paper's reward goes negative; the switch clips exactly those steps to 0."""
    g = torch.Generator().manual_seed(3)
    acts = [2.0 * torch.randn(3, amp.num_dofs, generator=g) for _ in range(6)]
    plain, clipped = _env(amp, lib, latent, seed=1), _env(amp, lib, latent, seed=1, only_positive_rewards=True)
    plain.reset()
    clipped.reset()
    saw_negative = False
    for a in acts:
        r0, r1 = plain.step(a).reward, clipped.step(a).reward
        saw_negative |= bool((r0 < 0).any())
        assert torch.equal(r1, r0.clamp_min(0.0))
    assert saw_negative
    plain.close()
    clipped.close()


# -------------------------------------------------------------------------------------- resume
def test_env_resume_is_exact(amp, lib, latent):
    N, T = 3, 16
    kw = {"conditioning": "LM", "episode_length_s": 0.3, "termination_persist_s": 0.2}

    def actions(t):
        g = torch.Generator().manual_seed(100 + t)
        return 0.3 * torch.randn(N, amp.num_dofs, generator=g)

    a = _env(amp, lib, latent, n=N, seed=5, **kw)
    obs_a, rew_a = [a.reset()], []
    for t in range(T):
        r = a.step(actions(t))
        obs_a.append(r.obs)
        rew_a.append(r.reward)
    b = _env(amp, lib, latent, n=N, seed=5, **kw)
    obs_b, rew_b = [b.reset()], []
    for t in range(T // 2):
        r = b.step(actions(t))
        obs_b.append(r.obs)
        rew_b.append(r.reward)
    state = b.state_dict()
    b.close()
    c = _env(amp, lib, latent, n=N, seed=99, **kw)  # another seed: everything comes from the state
    c.load_state_dict(state)
    assert torch.equal(c.current_obs(), obs_b[-1])
    for t in range(T // 2, T):
        r = c.step(actions(t))
        obs_b.append(r.obs)
        rew_b.append(r.reward)
    for x, y in zip(obs_a, obs_b):
        assert torch.equal(x, y)
    for x, y in zip(rew_a, rew_b):
        assert torch.equal(x, y)
    assert int(sum(float(r.sum() != 0) for r in rew_a)) > 0
    a.close()
    c.close()


# ------------------------------------------------------------------------------------- metrics
@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 1000), off=st.floats(-0.5, 0.5))
def test_joint_mae(amp, seed, off):
    g = torch.Generator().manual_seed(seed)
    q = 0.3 * torch.randn(5, 2, 3, generator=g, dtype=f64)
    assert torch.equal(joint_mae_deg_from_dofs(q, q), torch.zeros(2, dtype=f64))
    torch.testing.assert_close(
        joint_mae_deg_from_dofs(q + off, q),
        torch.full((2,), abs(off) * 180 / math.pi, dtype=f64),
    )
    # wrapping: 2 pi apart is no error
    torch.testing.assert_close(
        joint_mae_deg_from_dofs(q + 2 * math.pi, q),
        torch.zeros(2, dtype=f64),
        atol=1e-9,
        rtol=0,
    )


def test_joint_mae_from_trajectories(amp, lib):
    from mocap.kinematics import forward_kinematics_dofs

    T = 6
    ref = lib.frames(torch.zeros(T, dtype=torch.long), torch.arange(T, dtype=f64) / 30)
    dq = torch.zeros(amp.num_dofs, dtype=torch.float32)
    dq[-1] = 0.1  # one hinge off by 0.1 rad
    sim_pos, sim_rot = forward_kinematics_dofs(amp, ref.root_pos, ref.root_rot, ref.dof_pos + dq)
    tr = Trajectories(
        sim_pos[:, None],
        ref.body_pos[:, None],
        30.0,
        None,
        sim_rot[:, None],
        ref.body_rot[:, None],
    )
    torch.testing.assert_close(
        joint_mae_deg(tr, amp),
        torch.tensor([0.1 / amp.num_dofs * 180 / math.pi]),
        atol=2e-3,
        rtol=1e-2,
    )
    same = Trajectories(
        ref.body_pos[:, None],
        ref.body_pos[:, None],
        30.0,
        None,
        ref.body_rot[:, None],
        ref.body_rot[:, None],
    )
    assert float(joint_mae_deg(same, amp)) < 1e-3


# ------------------------------------------------------------------------------------ end to end
def test_mocap_run_vmp_track_produces_vmp_pt(amp, lib, tmp_path):
    from mocap.imitation_eval import rollout_imitation
    from mocap.testing import invoke

    spec = tmp_path / "vmp.yaml"
    spec.write_text(
        "spec_version: 1\nname: vmp-track-tiny\ndevice: cpu\nseed: 0\nhumanoid: {name: amp}\n"
        "motions: {name: deepmimic, params: {clips: [walk]}}\n"
        "simulator: {name: mujoco, params: {threads: 1}}\n"
        "latent:\n  name: vmp\n"
        "  params: {window_half: 6, latent_dim: 8, channels: 16, res_blocks: 1, downsample: 1}\n"
        "  trainer:\n    name: vmp_track\n    params:\n"
        "      vae: {num_iterations: 6, batch_size: 8, checkpoint_every: 100, print_every: 100}\n"
        "      ppo: {num_envs: 2, horizon: 4, total_env_steps: 16, minibatch_size: 4, epochs: 1,"
        " actor_hidden: [16], critic_hidden: [16], checkpoint_every: 100}\n"
        "      tracker: {conditioning: LM, episode_length_s: 2.0}\n"
    )
    out = tmp_path / "runs" / "vmp"
    result = invoke(["run", spec, "--out", out])
    assert result.exit_code == 0, result.output + result.stderr
    (vmp_file,) = list((tmp_path / "runs" / "artifacts").glob("latent-*/vmp.pt"))
    assert (vmp_file.parent / "vae" / "vae.pt").is_file() and (vmp_file.parent / "tracker" / "policy.pt").is_file()
    assert (out / "vmp_reconstruction.md").is_file()
    import json

    stages = [json.loads(x)["stage"] for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert stages.count("latent/vae") == 6 and stages.count("latent/tracker") == 2  # 16 env steps / (2 envs x 4 steps)
    data = torch.load(vmp_file, weights_only=False)
    assert data["format"] == "mocap_vmp.vmp/1" and data["tracker"]["params"]["conditioning"] == "LM"
    # the combined file loads as the latent space (stage 1) ...
    latent = make_vmp(VmpParams(**TINY), skeleton=amp, checkpoint=vmp_file)
    assert latent.frame_latents.shape == (39, 8) and latent.tracker is not None
    # ... and as an imitator that runs the project's imitation protocol
    imitator = vmp_imitator(vmp_file, amp, lib)
    assert imitator.obs_dim == 15 * amp.num_bodies - 2 + 2 * amp.num_dofs + latent.layout.dim + 8
    sim = _sim(amp, 2)
    out_r = rollout_imitation(
        sim,
        lib,
        imitator,
        torch.zeros(2, dtype=torch.long),
        torch.tensor([5, 5]),
        threshold=10.0,
    )
    assert out_r.traj.sim.shape[0] == 6
    assert joint_mae_deg(out_r.traj, amp).shape == (2,)
    sim.close()
    # `mocap eval` of the run directory and of the file: the tracker through the imitation protocol
    for target in (out, vmp_file):
        ev = invoke(["eval", target, "--json", tmp_path / "e.json"])
        assert ev.exit_code == 0, ev.output
        table = json.loads((tmp_path / "e.json").read_text())
        assert table["evaluated"].startswith("vmp (its own tracking policy)") and table["aggregate"]["total"] == 1
    # a stage-1-only checkpoint still loads
    stage1 = make_vmp(VmpParams(**TINY), skeleton=amp, checkpoint=vmp_file.parent / "vae" / "vae.pt")
    assert stage1.tracker is None
    with pytest.raises(ValueError, match="no tracking policy"):
        vmp_imitator(vmp_file.parent / "vae" / "vae.pt", amp, lib)
    # the registered imitator factory loads the same file
    from mocap_vmp.tracking import make_vmp_tracker

    tracker = make_vmp_tracker(skeleton=amp, checkpoint=vmp_file)
    assert tracker.policy is not None and tracker.imitator(lib).obs_dim == imitator.obs_dim


def test_imitator_observation_matches_the_env(amp, lib, latent):
    """The evaluation-time imitator builds the training env's observation from the same state and reference."""
    from mocap_vmp.tracking import VmpImitator, clip_frames

    for mode in ("M5", "LM"):
        env = _env(amp, lib, latent, n=3, conditioning=mode)
        env.reset()
        from mocap.rl.networks import ActorCritic

        policy = ActorCritic(env.obs_dim, env.action_space, actor_hidden=[8], critic_hidden=[8])
        imitator = VmpImitator(env.params, amp, latent, policy, lib, dt=env.dt)
        assert imitator.obs_dim == env.obs_dim
        obs = imitator.observe(env.sim.state, clip_frames(lib, env.clip_ids, env.target_time))
        torch.testing.assert_close(torch.cat((obs.proprio, obs.goal), -1), env.current_obs(), atol=1e-5, rtol=1e-5)
        # the action history advances like the env's
        a = 0.1 * torch.ones(3, amp.num_dofs)
        targets = imitator.to_pd_targets(obs, a)
        env.step(a)
        torch.testing.assert_close(targets, env.hist_targets[:, 0], atol=1e-6, rtol=0)
        torch.testing.assert_close(imitator._hist_a, env.hist_actions)
        env.close()
