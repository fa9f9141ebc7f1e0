"""Tests of the PHC+ AMP discriminator reward (``mocap_phc.amp``) and its wiring into the imitation env."""

from __future__ import annotations

import copy
import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

torch.set_num_threads(1)

import mocap_phc.plugin  # noqa: F401
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap.motion.library import MotionLibrary
from mocap.rotations import quat_apply, quat_from_axis_angle, quat_mul
from mocap.state import HumanoidState
from mocap_phc.amp import (
    AMPHistory,
    AMPObservation,
    Discriminator,
    DiscriminatorTrainer,
    ReplayBuffer,
    bce_reward,
    demo_windows,
    gradient_penalty,
    loss_config,
    lsgan_reward,
    max_bce_reward,
)
from mocap_phc.env import ImitationEnv
from mocap_phc.imitator import PHCParams

SETTINGS = settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
finite = st.floats(-50.0, 50.0, allow_nan=False)


@pytest.fixture(scope="module")
def clips(amp):
    return DeepMimicSource(DeepMimicParams(clips=["walk", "kick"])).load(amp)


@pytest.fixture(scope="module")
def walk_lib(amp, clips):
    return MotionLibrary([c for c in clips.clips if c.name == "walk"], amp)


def make_sim(skeleton, n):
    from mocap_sim_mujoco.simulator import MujocoSimulator

    return MujocoSimulator(skeleton=skeleton, num_envs=n, seed=0, dtype=torch.float32)


def make_env(skel, clips, n=4, seed=0, **overrides):
    params = PHCParams(
        **{
            "action": "residual",
            "amp": True,
            "amp_hidden": [32, 16],
            "amp_batch": 32,
            "amp_updates_per_iteration": 2,
            "amp_replay_size": 64,
            "amp_replay_keep_prob": 0.5,
            "amp_demo_buffer_size": 100,
            "amp_lr": 1e-3,
            **overrides,
        }
    )
    return ImitationEnv(params, skel, MotionLibrary(clips, skel), make_sim(skel, n), seed=seed)


# ------------------------------------------------------------------------------ reward transforms
@SETTINGS
@given(finite, finite, st.floats(0.1, 5.0))
def test_bce_reward_monotone_and_bounded(a, b, scale):
    lo, hi = min(a, b), max(a, b)
    r = bce_reward(torch.tensor([lo, hi], dtype=torch.float64), scale)
    assert r[0] <= r[1] + 1e-12
    assert torch.all(r >= 0.0)
    assert torch.all(r <= -math.log(1e-4) * scale + 1e-9)
    assert max_bce_reward(scale) == pytest.approx(-math.log(1e-4) * scale)


@SETTINGS
@given(finite)
def test_lsgan_reward_in_unit_interval_max_at_one(d):
    r = lsgan_reward(torch.tensor([d, 1.0], dtype=torch.float64))
    assert 0.0 <= float(r[0]) <= 1.0
    assert float(r[1]) == 1.0 and float(r[0]) <= float(r[1])


def test_loss_presets_paper_and_code():
    paper, code = loss_config("lsgan"), loss_config("bce")
    assert (
        paper.grad_penalty,
        paper.reward_scale,
        paper.logit_reg,
        paper.weight_decay,
    ) == (10.0, 1.0, 0.0, 0.0)
    assert (
        code.grad_penalty,
        code.reward_scale,
        code.logit_reg,
        code.weight_decay,
        code.coef,
    ) == (5.0, 2.0, 0.01, 1e-4, 5.0)
    with pytest.raises(ValueError):
        loss_config("wgan")  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- gradient penalty
@SETTINGS
@given(st.integers(0, 2**31 - 1))
def test_gradient_penalty_nonnegative_and_zero_for_constant(seed):
    torch.manual_seed(seed)
    disc = Discriminator(7, (8,))
    x = torch.randn(5, 7)
    assert float(gradient_penalty(disc, x).detach()) >= 0.0
    with torch.no_grad():
        disc.logit.weight.zero_()
        disc.logit.bias.fill_(0.3)
    assert float(gradient_penalty(disc, x).detach()) == 0.0
    assert float(gradient_penalty(lambda z: torch.full((z.shape[0],), 2.0), x)) == 0.0


# ---------------------------------------------------------------------------------- replay buffer
@SETTINGS
@given(
    st.lists(st.integers(0, 40), min_size=1, max_size=12),
    st.integers(1, 30),
    st.floats(0.05, 1.0),
    st.integers(0, 1000),
)
def test_replay_buffer_size_bound(sizes, capacity, keep, seed):
    gen = torch.Generator().manual_seed(seed)
    buf = ReplayBuffer(capacity, 3, keep)
    for n in sizes:
        before = buf.total
        written = buf.store(torch.randn(n, 3), gen)
        assert len(buf) <= capacity
        if before <= capacity:  # nothing is dropped until the buffer has seen `capacity` samples
            assert written == min(n, capacity)
    if len(buf):
        assert buf.sample(4, gen).shape == (4, 3)


def test_replay_buffer_keep_probability():
    gen = torch.Generator().manual_seed(0)
    buf = ReplayBuffer(100, 1, keep_prob=0.1)
    buf.store(torch.zeros(101, 1), gen)  # total 100 > capacity? no: exactly capacity written
    assert buf.total == 100 and len(buf) == 100
    buf.store(torch.zeros(1, 1), gen)  # total <= capacity: kept
    assert buf.total == 101
    n, written = 20_000, 0
    for _ in range(20):
        written += buf.store(torch.ones(n // 20, 1), gen)
    p, sd = 0.1, math.sqrt(n * 0.1 * 0.9)
    assert abs(written - n * p) < 5 * sd
    assert len(buf) == 100
    assert float(buf.data.mean()) > 0.9  # the ring overwrote the old zeros
    st_ = buf.state_dict()
    other = ReplayBuffer(100, 1, 0.1)
    other.load_state_dict(copy.deepcopy(st_))
    g1, g2 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    assert torch.equal(buf.sample(10, g1), other.sample(10, g2))


# ---------------------------------------------------------------------------- observation
def _transform(s: HumanoidState, yaw: float, tx: float, ty: float) -> HumanoidState:
    q = quat_from_axis_angle(
        torch.tensor([0.0, 0.0, 1.0], dtype=s.root_rot.dtype),
        torch.tensor(yaw, dtype=s.root_rot.dtype),
    )
    t = torch.tensor([tx, ty, 0.0], dtype=s.root_pos.dtype)
    N, B = s.body_pos.shape[:2]
    qb = q.expand(N, B, 4)
    return HumanoidState(
        root_pos=quat_apply(q.expand(N, 4), s.root_pos) + t,
        root_rot=quat_mul(q.expand(N, 4), s.root_rot),
        root_lin_vel=quat_apply(q.expand(N, 4), s.root_lin_vel),
        root_ang_vel=quat_apply(q.expand(N, 4), s.root_ang_vel),
        dof_pos=s.dof_pos,
        dof_vel=s.dof_vel,
        body_pos=quat_apply(qb, s.body_pos) + t,
        body_rot=quat_mul(qb, s.body_rot),
        body_lin_vel=quat_apply(qb, s.body_lin_vel),
        body_ang_vel=quat_apply(qb, s.body_ang_vel),
    )


@SETTINGS
@given(
    st.floats(-math.pi, math.pi),
    st.floats(-20, 20),
    st.floats(-20, 20),
    st.sampled_from(["rot6d", "dof"]),
)
def test_amp_observation_invariant_to_yaw_and_planar_translation(amp, walk_lib, yaw, tx, ty, joints):
    obs = AMPObservation(amp, joints)
    frames = walk_lib.frames(torch.zeros(6, dtype=torch.long), torch.linspace(0.0, 1.2, 6))
    s = HumanoidState(**{k: getattr(frames, k).double() for k in HumanoidState.__dataclass_fields__})
    a, b = obs(s), obs(_transform(s, yaw, tx, ty))
    assert a.shape == (6, obs.dim)
    assert torch.allclose(a, b, atol=1e-4), (a - b).abs().max()


def test_amp_observation_dims(amp, smpl):
    o = AMPObservation(amp)
    n_joints = sum(1 for b in amp.bodies[1:] if b.joint.hinges)
    assert o.dim == 13 + 6 * n_joints + amp.num_dofs + 3 * len(amp.end_effectors)
    assert AMPObservation(amp, "dof").dim == 13 + 2 * amp.num_dofs + 3 * len(amp.end_effectors)
    s = AMPObservation(smpl, key_bodies=["L_Ankle", "R_Ankle", "L_Wrist", "R_Wrist"])
    assert s.dim == 13 + 6 * 23 + 69 + 12  # 232 (the code's 196 drops hands and toes)


def test_amp_observation_without_hands_and_toes_is_the_codes_196(smpl):
    """[C] build_amp_observations_smpl: 19 joints (no hands, no toes) and 4 key bodies = 196 per
    frame; the kept columns are exactly those of the full observation."""
    keys = ["R_Ankle", "L_Ankle", "R_Wrist", "L_Wrist"]
    drop = ["L_Hand", "R_Hand", "L_Toe", "R_Toe"]
    full, code = AMPObservation(smpl, key_bodies=keys), AMPObservation(smpl, key_bodies=keys, exclude=drop)
    assert code.dim == 196 and code.joint_ids.numel() == 19 and code.dof_ids.numel() == 57
    g = torch.Generator().manual_seed(0)
    N, B, D = 3, smpl.num_bodies, smpl.num_dofs
    rot = torch.randn(N, B, 4, generator=g, dtype=torch.float64)
    s = HumanoidState(
        root_pos=torch.randn(N, 3, generator=g, dtype=torch.float64),
        root_rot=rot[:, 0] / rot[:, 0].norm(dim=-1, keepdim=True),
        root_lin_vel=torch.randn(N, 3, generator=g, dtype=torch.float64),
        root_ang_vel=torch.randn(N, 3, generator=g, dtype=torch.float64),
        dof_pos=torch.randn(N, D, generator=g, dtype=torch.float64),
        dof_vel=torch.randn(N, D, generator=g, dtype=torch.float64),
        body_pos=torch.randn(N, B, 3, generator=g, dtype=torch.float64),
        body_rot=rot / rot.norm(dim=-1, keepdim=True),
        body_lin_vel=torch.randn(N, B, 3, generator=g, dtype=torch.float64),
        body_ang_vel=torch.randn(N, B, 3, generator=g, dtype=torch.float64),
    )
    a, b = full(s), code(s)
    kept_joints = [i for i, j in enumerate(full.joint_ids.tolist()) if j in set(code.joint_ids.tolist())]
    joint_cols = [13 + 6 * i + k for i in kept_joints for k in range(6)]
    vel_cols = [13 + 6 * 23 + d for d in code.dof_ids.tolist()]
    key_cols = list(range(a.shape[1] - 12, a.shape[1]))
    torch.testing.assert_close(b, a[:, list(range(13)) + joint_cols + vel_cols + key_cols])
    with pytest.raises(KeyError, match="no body 'L_Paw'"):
        AMPObservation(smpl, exclude=["L_Paw"])


def test_history_push_order():
    h = AMPHistory(2, 3, 1)
    for v in (1.0, 2.0, 3.0, 4.0):
        h.push(torch.full((2, 1), v))
    assert h.buf[:, :, 0].tolist() == [[4.0, 3.0, 2.0]] * 2
    h.fill(torch.tensor([1]), torch.zeros(1, 3, 1))
    assert h.flat().tolist() == [[4.0, 3.0, 2.0], [0.0, 0.0, 0.0]]


def test_episode_start_fill_and_stacking(amp, clips):
    env = make_env(amp, clips, n=4, seed=3, episode_steps=5)
    env.reset()
    H, obs, dt = env.params.amp_history, env.amp_obs, env.dt
    buf = env.amp_history.buf
    assert buf.shape == (4, H, obs.dim)
    assert torch.allclose(buf[:, 0], obs(env.sim.state), atol=1e-5)
    for k in range(1, H):
        t = env.start_time - k * dt
        t = torch.where(env.starts.loops[env.clip_ids], t, t.clamp_min(0.0))
        assert torch.allclose(buf[:, k], obs(env.library.frames(env.clip_ids, t)), atol=1e-4)
    prev = buf.clone()
    res = env.step(torch.zeros(4, amp.num_dofs))
    done = res.terminated | res.truncated
    keep = ~done
    assert torch.equal(env.amp_history.buf[keep, 1:], prev[keep, :-1])
    # an env that ends is refilled from its new start
    for _ in range(6):
        res = env.step(torch.zeros(4, amp.num_dofs))
        done = res.terminated | res.truncated
        if done.any():
            break
    assert done.any()
    ids = done.nonzero().squeeze(-1)
    assert torch.allclose(env.amp_history.buf[ids, 0], obs(env.sim.state.index(ids)), atol=1e-5)
    assert torch.allclose(
        env.amp_history.buf[ids, 1],
        obs(env.library.frames(env.clip_ids[ids], env.start_time[ids] - dt)),
        atol=1e-4,
    )
    env.close()


# --------------------------------------------------------------------------------- learning
@pytest.mark.parametrize("loss", ["lsgan", "bce"])
def test_tiny_discriminator_separates_walk_from_noise(amp, walk_lib, loss):
    obs = AMPObservation(amp)
    H, dt = 4, 1.0 / 30.0
    pool = demo_windows(walk_lib, obs, 2000, H, dt, torch.Generator().manual_seed(0)).reshape(2000, -1)

    def demo_fn(n, gen):
        return pool[torch.randint(0, 1000, (n,), generator=gen)]

    def noisy(x, seed):
        return x + 0.3 * torch.randn(x.shape, generator=torch.Generator().manual_seed(seed))

    tr = DiscriminatorTrainer(
        pool.shape[1],
        demo_fn,
        loss_config(loss),
        hidden=(64, 64),
        lr=1e-3,
        replay_size=4000,
        demo_buffer_size=2000,
        seed=1,
    )
    tr.observe_policy(noisy(pool[:1000], 1))
    stats = tr.update(200, 64)
    assert set(stats) >= {
        "loss",
        "accuracy",
        "grad_penalty",
        "demo_logit",
        "policy_logit",
    }
    test_demo, test_noise = pool[1000:], noisy(pool[1000:], 2)
    acc = 0.5 * (float((tr.logits(test_demo) > 0).float().mean()) + float((tr.logits(test_noise) < 0).float().mean()))
    assert acc > 0.8, acc
    assert float(tr.reward(test_demo).mean()) > float(tr.reward(test_noise).mean())


# ------------------------------------------------------------------------------------- env
@pytest.mark.parametrize("mix,loss", [("paper", "lsgan"), ("code", "bce")])
def test_env_reward_mix_shapes_and_finiteness(amp, clips, mix, loss):
    env = make_env(amp, clips, n=4, amp_energy_mix=mix, amp_loss=loss, energy_coef=5e-5)
    env.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(6):
        res = env.step(0.05 * torch.randn(4, amp.num_dofs, generator=gen))
        assert res.reward.shape == (4,) and torch.all(torch.isfinite(res.reward))
        i = res.info
        r_amp, r_im, e = (
            i["reward/amp"].double(),
            i["reward/imitation"].double(),
            i["reward/energy"].double(),
        )
        want = 0.5 * r_im + 0.5 * r_amp + e if mix == "paper" else 0.5 * (r_im + e) + 0.5 * r_amp
        ok = i["terminated/unstable"] == 0
        assert torch.allclose(res.reward.double()[ok], want.float().double()[ok], atol=1e-5)
        assert torch.all(r_amp >= 0)
    assert env.amp_trainer.num_recent == 6 * 4
    logs = env.after_iteration(1, lambda o: torch.zeros(o.shape[0], amp.num_dofs))
    assert "amp/loss" in logs and math.isfinite(logs["amp/loss"])
    assert env.amp_trainer.num_recent == 0 and len(env.amp_trainer.replay) > 0
    env.close()


def test_env_state_dict_round_trip_with_amp(amp, clips):
    gen = torch.Generator().manual_seed(0)
    actions = [0.05 * torch.randn(4, amp.num_dofs, generator=gen) for _ in range(30)]
    policy_fn = lambda o: torch.zeros(o.shape[0], amp.num_dofs)
    a = make_env(amp, clips, n=4, seed=1, episode_steps=8, update_every=4)
    a.reset()
    for k in range(8):
        a.step(actions[k])
    a.after_iteration(1, policy_fn)  # a trained discriminator and a non-empty replay buffer
    for k in range(8, 12):
        a.step(actions[k])  # and windows of an unfinished rollout
    saved = copy.deepcopy(a.state_dict())

    def run(env):
        out = []
        for k in range(12, 20):
            r = env.step(actions[k])
            out.append((r.obs, r.reward, r.terminated, r.truncated, r.info["reward/amp"]))
        logs = env.after_iteration(2, policy_fn)
        for k in range(20, 30):
            r = env.step(actions[k])
            out.append((r.obs, r.reward, r.info["reward/amp"]))
        return out, logs

    ra, la = run(a)
    b = make_env(amp, clips, n=4, seed=99, episode_steps=8, update_every=4)
    b.load_state_dict(saved)
    assert torch.equal(b.amp_history.buf, saved["amp"]["history"])
    rb, lb = run(b)
    for x, y in zip(ra, rb):
        for u, v in zip(x, y):
            assert torch.equal(u, v)
    assert la == lb
    with pytest.raises(ValueError):
        make_env(amp, clips, n=4, amp_history=3).load_state_dict(saved)
    a.close()
    b.close()


def test_amp_off_is_unchanged(amp, clips):
    env = make_env(amp, clips, n=2, amp=False)
    env.reset()
    res = env.step(torch.zeros(2, amp.num_dofs))
    assert env.amp_trainer is None and "reward/amp" not in res.info and "amp" not in env.state_dict()
    assert env.after_iteration(1, lambda o: torch.zeros(o.shape[0], amp.num_dofs)) == {}
    env.close()


def test_env_with_amp_on_smpl(smpl):
    from test_phc import standing_clip

    lib = MotionLibrary([standing_clip(smpl)], smpl)
    params = PHCParams(
        amp=True,
        amp_hidden=[16],
        amp_batch=8,
        amp_replay_size=32,
        amp_demo_buffer_size=32,
        amp_key_bodies=["L_Ankle", "R_Ankle", "L_Wrist", "R_Wrist"],
    )
    env = ImitationEnv(params, smpl, lib, make_sim(smpl, 2), seed=0)
    env.reset()
    assert env.amp_history.buf.shape == (2, 10, 232)
    for _ in range(3):
        res = env.step(torch.zeros(2, 69))
        assert res.reward.shape == (2,) and torch.all(torch.isfinite(res.reward))
    assert "amp/accuracy" in env.after_iteration(1, lambda o: torch.zeros(o.shape[0], 69))
    env.close()


def test_ppo_resume_with_amp_is_exact(amp, clips, tmp_path):
    """PPO drives the AMP env (rewards, after_iteration training) and a Ctrl-C + resume ends bit-identical."""
    from mocap.checkpoint import load_checkpoint
    from mocap.rl.ppo import PPOTrainer
    from test_ppo import FakeContext, small_params

    params = small_params(num_envs=4, horizon=8, total_env_steps=4 * 8 * 4, minibatch_size=16, epochs=1, checkpoint_every=3)

    def train(workdir, stop_after=None):
        ctx = FakeContext(workdir, lambda n: make_env(amp, clips, n=n, seed=5, episode_steps=6), seed=0, stop_after=stop_after)
        result = PPOTrainer(params).run(ctx)
        ctx.log.close()
        return result

    train(tmp_path / "straight")
    train(tmp_path / "split", stop_after=2)
    train(tmp_path / "split")
    a, b = load_checkpoint(tmp_path / "straight" / "ppo.pt"), load_checkpoint(tmp_path / "split" / "ppo.pt")
    assert a["iteration"] == b["iteration"] == 4
    for key, value in a["model"].items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, b["model"][key]), key
    da, db = a["env"]["amp"]["trainer"], b["env"]["amp"]["trainer"]
    assert da["updates"] == db["updates"] == 4 * 2
    for key, value in da["disc"].items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, db["disc"][key]), key
    assert torch.equal(da["replay"]["data"], db["replay"]["data"])
    lines = (tmp_path / "straight" / "metrics.jsonl").read_text()
    assert "eval/amp/loss" in lines and "env/reward/amp" in lines
