"""Tests of the ``phc`` imitator plugin: termination, the imitation env and the imitator (its rewards: test_phc_rewards.py)."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

torch.set_num_threads(1)

import mocap_phc.plugin
from mocap.baselines import PDReplay
from mocap.imitation_eval import rollout_imitation
from mocap.humanoids import smpl_skeleton
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap.motion.library import MotionLibrary
from mocap.observations import ROT_GOAL_COLUMNS, imitation_goal_rot
from mocap.state import SimState
from phc_states import random_state
from mocap_phc.env import ActionMap, ImitationEnv, hard_negative_weights, pd_offset_scale
from mocap_phc.imitator import PHCImitator, PHCParams, make_phc
from mocap_phc.termination import Termination, checked_mask, imitation_failed

F64 = torch.float64
SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
seeds = st.integers(0, 2**32 - 1)


# ------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def clips(amp):
    """walk (looping, 1.27 s) and kick (non-looping, 1.53 s)."""
    return DeepMimicSource(DeepMimicParams(clips=["walk", "kick"])).load(amp)


def make_sim(skeleton, n):
    from mocap_sim_mujoco.simulator import MujocoSimulator

    return MujocoSimulator(skeleton=skeleton, num_envs=n, seed=0, dtype=torch.float32)


def make_env(amp, clips, n=8, seed=0, clip_names=None, **overrides):
    motion = clips if clip_names is None else [c for c in clips.clips if c.name in clip_names]
    lib = MotionLibrary(motion, amp)
    params = PHCParams(**{"action": "residual", **overrides})
    return ImitationEnv(params, amp, lib, make_sim(amp, n), seed=seed, eval_simulator_factory=lambda k: make_sim(amp, k))


# --------------------------------------------------------------------------------- termination
def test_termination_rules(amp):
    B = amp.num_bodies
    checked = checked_mask(amp)
    feet = [amp.body_index(n) for n in amp.feet]
    assert not checked[feet].any() and int(checked.sum()) == B - 2
    dist = torch.zeros(3, B)
    dist[0, feet] = 10.0  # feet far away: never terminates (relaxed early termination)
    dist[1, 1] = 0.3  # one body at 0.3 m: code (any > 0.25) terminates, paper (mean > 0.5) does not
    dist[2, :] = 0.6  # everything at 0.6 m: both terminate
    assert imitation_failed(dist, checked, "paper").tolist() == [False, False, True]
    assert imitation_failed(dist, checked, "code").tolist() == [False, True, True]
    assert imitation_failed(dist, checked, "paper", threshold=0.2).tolist() == [False, False, True]
    # code rule: the first step after a reset is not checked (progress_buf > 1)
    assert imitation_failed(dist, checked, "code", progress=torch.tensor([1, 1, 2])).tolist() == [False, False, True]
    assert imitation_failed(dist, checked, "code", progress=torch.tensor([1, 1, 1]), grace=0).tolist() == [False, True, True]
    smpl = smpl_skeleton()
    names = [smpl.body_names[i] for i in range(smpl.num_bodies) if not checked_mask(smpl)[i]]
    assert sorted(names) == ["L_Ankle", "L_Toe", "R_Ankle", "R_Toe"]


def test_termination_unstable_and_fall(amp):
    s = random_state(np.random.default_rng(0), 3, amp.num_bodies, amp.num_dofs)
    s.body_contact = torch.zeros(3, amp.num_bodies, dtype=torch.bool)
    s.unstable = torch.tensor([False, True, False])
    s.body_contact[2, amp.body_index("head")] = True
    s.body_contact[0, amp.body_index("left_foot")] = True
    term = Termination.for_skeleton(amp)
    done, parts = term(s, s)
    assert done.tolist() == [False, True, False] and not parts["tracking"].any()
    done, parts = Termination.for_skeleton(amp, fall_check=True)(s, s)
    assert done.tolist() == [False, True, True] and parts["fall"].tolist() == [False, False, True]


# ------------------------------------------------------------------------------------- actions
def test_action_scales(amp):
    smpl = smpl_skeleton()
    off, scale = pd_offset_scale(smpl, {"*Knee_y": 5.0})
    names = smpl.dof_names
    assert torch.equal(off, torch.zeros(69, dtype=F64))
    s = dict(zip(names, scale.tolist()))
    assert s["L_Hip_x"] == pytest.approx(min(1.2 * math.pi / 2, math.pi)) == s["L_Hip_z"]
    assert s["L_Knee_y"] == 5.0 and s["L_Knee_x"] == pytest.approx(math.pi)  # 1.2 * 180 deg, capped at pi
    assert max(scale.tolist()) <= 5.0
    off, scale = pd_offset_scale(amp)
    k = amp.dof_names.index("right_knee")
    lo, hi = amp.hinges[k].range
    assert off[k] == pytest.approx((lo + hi) / 2) and scale[k] == pytest.approx(0.7 * (hi - lo))
    am = ActionMap.for_skeleton(amp, "residual", clip=0.5)
    ref = torch.randn(2, amp.num_dofs)
    torch.testing.assert_close(am(torch.full((2, amp.num_dofs), 3.0), ref), ref + 0.5)
    assert am.space.high == 0.5


# ----------------------------------------------------------------------------------------- env
def test_env_shapes_and_rsi_reset(amp, clips):
    env = make_env(amp, clips, n=6)
    obs = env.reset()
    B, D = amp.num_bodies, amp.num_dofs
    assert env.obs_dim == 15 * B - 2 + 24 * B and obs.shape == (6, env.obs_dim)
    assert env.action_space.shape == (D,)
    # the simulator sits at the reference state of each env's start time: root and DoFs exactly;
    # bodies within a few mm (the library slerps local rotations between frames, the simulator
    # runs forward kinematics of the interpolated DoFs)
    state = env.sim.state
    ref0 = env.library.frames(env.clip_ids, env.start_time)
    torch.testing.assert_close(state.dof_pos, ref0.dof_pos, atol=1e-6, rtol=0)
    torch.testing.assert_close(state.dof_vel, ref0.dof_vel, atol=1e-5, rtol=0)
    torch.testing.assert_close(state.root_pos, ref0.root_pos, atol=1e-6, rtol=0)
    torch.testing.assert_close(state.root_lin_vel, ref0.root_lin_vel, atol=1e-5, rtol=0)
    torch.testing.assert_close(state.root_ang_vel, ref0.root_ang_vel, atol=1e-5, rtol=0)
    g = imitation_goal_rot(state, ref0).reshape(6, B, 24)
    assert g[..., ROT_GOAL_COLUMNS["pos_diff"]].abs().max() < 5e-3
    ident = torch.tensor([1.0, 0, 0, 0, 1, 0]).expand(6, B, 6)
    torch.testing.assert_close(g[..., ROT_GOAL_COLUMNS["rot_diff"]], ident, atol=2e-2, rtol=0)
    for name in ("vel_diff", "ang_vel_diff"):
        assert g[:, 0, ROT_GOAL_COLUMNS[name]].abs().max() < 1e-4, name  # root velocities are set exactly
    # the observation's goal is to the next frame: a one-step difference
    goal = obs[:, 15 * B - 2 :].reshape(6, B, 24)
    assert 0 < goal[..., ROT_GOAL_COLUMNS["pos_diff"]].abs().max() < 0.2
    res = env.step(torch.zeros(6, D))
    assert res.obs.shape == res.final_obs.shape == (6, env.obs_dim)
    assert res.reward.shape == res.terminated.shape == res.truncated.shape == (6,)
    # zero residual from the reference state stays close to the reference; no energy penalty in
    # the code form's first 3 steps, so the reward is the imitation reward, in (0, 1]
    assert torch.all(res.reward > 0.1) and torch.all(res.reward <= 1.0)
    torch.testing.assert_close(res.reward, res.info["reward/imitation"].float())
    assert all(v.shape == (6,) for v in res.info.values())
    env.close()


def test_truncation_and_termination_flags(amp, clips):
    # time limit: zero residual on walk survives ~26 steps; a 5-step limit truncates every env
    env = make_env(amp, clips, n=4, clip_names=["walk"], episode_steps=5, hard_negative=False)
    env.reset()
    for _k in range(5):
        res = env.step(torch.zeros(4, amp.num_dofs))
    assert res.truncated.all() and not res.terminated.any()
    assert res.episodes["length"].tolist() == [5.0] * 4 and res.episodes["success"].tolist() == [1.0] * 4
    assert torch.equal(env.progress, torch.zeros(4, dtype=torch.long))  # auto-reset
    assert not torch.equal(res.obs, res.final_obs)
    env.close()
    # tracking failure: a 1 mm threshold terminates at the first step (paper rule has no grace)
    env = make_env(amp, clips, n=4, termination_threshold=1e-3, hard_negative=False)
    env.reset()
    res = env.step(torch.full((4, amp.num_dofs), 0.5))
    assert res.terminated.all() and not res.truncated.any()
    assert res.episodes["success"].tolist() == [0.0] * 4 and res.episodes["length"].tolist() == [1.0] * 4
    env.close()


def test_non_looping_clip_truncates_at_its_end(amp, clips):
    env = make_env(amp, clips, n=4, clip_names=["kick"], termination_threshold=100.0, hard_negative=False)
    env.reset()
    dur = float(env.library.durations[0])
    finished = 0
    for _ in range(60):
        start = env.start_time.clone()
        res = env.step(torch.zeros(4, amp.num_dofs))
        assert not res.terminated.any()
        ended = res.truncated.nonzero().flatten().tolist()
        if ended:
            # the episode ran until the clip had no next frame: floor((duration - start) / dt) steps
            want = sorted(float(math.floor((dur - float(start[i])) / env.dt + 1e-6)) for i in ended)
            assert sorted(res.episodes["length"].tolist()) == want
            finished += len(ended)
    assert finished > 0, "no episode reached the clip's end"
    env.close()


@pytest.mark.parametrize("cycles", [None, 0.5, 1.0])
def test_loop_cycles_ends_looping_episodes_after_that_many_periods(amp, clips, cycles):
    """``loop_cycles``: an episode of a looping clip (walk, 1.27 s) is truncated, not failed, after
    ceil(cycles * period / dt) steps whatever its start; None lets it loop until episode_steps."""
    env = make_env(amp, clips, n=4, clip_names=["walk"], termination_threshold=100.0, hard_negative=False, episode_steps=60, loop_cycles=cycles)
    env.reset()
    period = float(env.library.durations64[0])
    want = 60 if cycles is None else math.ceil(cycles * period / env.dt - 1e-6)
    lengths: list[float] = []
    for _ in range(70):
        res = env.step(torch.zeros(4, amp.num_dofs))
        assert not res.terminated.any()
        lengths += res.episodes.get("length", torch.zeros(0)).tolist()
    env.close()
    assert lengths and set(lengths) == {float(want)}, (lengths, want)


def test_state_dict_round_trip_reproduces_transitions(amp, clips):
    gen = torch.Generator().manual_seed(0)
    actions = [0.05 * torch.randn(8, amp.num_dofs, generator=gen) for _ in range(40)]
    a = make_env(amp, clips, n=8, seed=1, episode_steps=12, update_every=4)
    a.reset()
    for k in range(10):
        a.step(actions[k])
    saved = copy.deepcopy(a.state_dict())
    obs_a = a.current_obs()

    def run(env):
        out = []
        for k in range(10, 40):
            r = env.step(actions[k])
            out.append((r.obs, r.reward, r.terminated, r.truncated, r.final_obs))
        return out, env.clip_weights

    ra, wa = run(a)
    b = make_env(amp, clips, n=8, seed=99, episode_steps=12, update_every=4)
    b.load_state_dict(saved)
    diff = (b.current_obs() - obs_a).abs()
    assert torch.equal(b.current_obs(), obs_a), (diff.max(), (diff > 0).nonzero()[:10], b.current_obs()[diff > 0][:5], obs_a[diff > 0][:5])
    rb, wb = run(b)
    for x, y in zip(ra, rb):
        for u, v in zip(x, y):
            assert torch.equal(u, v)
    assert torch.equal(wa, wb)
    with pytest.raises(ValueError):
        make_env(amp, clips, n=4).load_state_dict(saved)
    a.close()
    b.close()


# ------------------------------------------------------------------------------ hard negatives
@SETTINGS
# floor 0, or one whose share floor * base is a normal float (5e-324 * 0.5 underflows to 0: w > 0 cannot hold)
@given(counts=st.lists(st.floats(0.0, 100.0), min_size=1, max_size=8), floor=st.one_of(st.just(0.0), st.floats(1e-12, 1.0)))
def test_hard_negative_weights(counts, floor):
    f = torch.tensor(counts, dtype=F64)
    base = torch.full_like(f, 1.0 / len(counts))
    w = hard_negative_weights(f, base, floor)
    assert float(w.sum()) == pytest.approx(1.0)
    assert torch.all(w >= floor * base - 1e-12)
    if f.sum() > 0 and floor == 0.0:
        torch.testing.assert_close(w, f / f.sum())
    if f.sum() > 0 and floor > 0.0:
        assert torch.all(w > 0)
        order = torch.argsort(f)
        assert torch.all(torch.diff(w[order]) >= -1e-12)  # monotone in the failure count


def test_hard_negative_weights_follow_training_failures(amp, clips):
    env = make_env(amp, clips, n=2, update_every=10, hard_negative_floor=0.2)
    env.reset()
    w0 = env.clip_weights
    torch.testing.assert_close(w0, torch.full((2,), 0.5, dtype=F64))
    walk, kick = env.library.clip_index("walk"), env.library.clip_index("kick")
    # 5 kick episodes that all fail, 5 walk episodes that all succeed -> one update
    env._record(torch.tensor([kick] * 5 + [walk] * 5), torch.tensor([True] * 5 + [False] * 5))
    w = env.clip_weights
    assert w[kick] > w[walk] > 0 and float(w.sum()) == pytest.approx(1.0)
    assert float(w[walk]) == pytest.approx(0.2 * 0.5)  # the floor
    assert env.failures_per_clip[kick] == 5 and env.episodes_per_clip[walk] == 5
    stats = env.clip_stats()
    assert stats["kick"]["failures"] == 5.0 and stats["walk"]["weight"] == pytest.approx(float(w[walk]))
    env.close()


def test_evaluate_clips_counts_failures(amp, clips):
    env = make_env(amp, clips, n=2, hard_negative_floor=0.1, eval_every=3)
    env.reset()
    D = amp.num_dofs
    # zero residual (open-loop PD replay) falls on both clips well before their end
    res = env.evaluate_clips(lambda obs: torch.zeros(obs.shape[0], D))
    assert set(res["failed"]) == {"walk", "kick"} and res["success_rate"] == 0.0
    assert torch.equal(env.fail_counts, torch.ones(2, dtype=F64))
    assert all(0 < c["tracked_steps"] < 300 for c in res["clips"].values())
    assert env.after_iteration(1, lambda obs: torch.zeros(obs.shape[0], D)) == {}
    logs = env.after_iteration(3, lambda obs: torch.zeros(obs.shape[0], D))
    assert logs["hard_negative/failed_clips"] == 2.0 and torch.equal(env.fail_counts, torch.full((2,), 2.0, dtype=F64))
    env.close()


# ---------------------------------------------------------------------------------- end to end
def test_zero_residual_survives_a_few_steps_on_walk(amp, clips):
    env = make_env(amp, clips, n=4, clip_names=["walk"], hard_negative=False)
    env.reset()
    for _ in range(10):
        res = env.step(torch.zeros(4, amp.num_dofs))
        assert not res.terminated.any()


def test_imitator_matches_pd_replay_in_the_evaluator(amp, clips):
    """Residual mapping of zero actions = PD targets on the next reference = PDReplay, through
    ``rollout_imitation`` (which passes the reference at t + 1 to ``observe``)."""
    lib = MotionLibrary([c for c in clips.clips if c.name == "walk"], amp)
    phc = PHCImitator(PHCParams(action="residual"), amp, policy=lambda obs: torch.zeros(obs.shape[0], amp.num_dofs))
    ids, frames = torch.tensor([0]), torch.tensor([15])
    out_a = rollout_imitation(make_sim(amp, 1), lib, phc, ids, frames, threshold=10.0)
    out_b = rollout_imitation(make_sim(amp, 1), lib, PDReplay(), ids, frames, threshold=10.0)
    assert torch.equal(out_a.traj.sim, out_b.traj.sim)


def test_registry_and_checkpoint(amp, tmp_path):
    from mocap.interfaces import Box
    from mocap.rl.networks import ActorCritic, save_policy
    from mocap.testing import use_plugins

    with use_plugins(("imitator_phc", mocap_phc.plugin)) as pset:
        comp = pset.get("imitator", "phc")
        imitator = comp.build({"action": "residual", "sixd": "tan_norm"}, skeleton=amp)
        assert isinstance(imitator, PHCImitator) and imitator.params.sixd == "tan_norm"
        with pytest.raises(ValidationError):
            comp.build({"bogus": 1}, skeleton=amp)
    params = PHCParams(obs="keypoint", action="absolute")
    obs_dim = 15 * amp.num_bodies - 2 + 9 * amp.num_bodies
    model = ActorCritic(obs_dim, Box((amp.num_dofs,)), actor_hidden=(16,), critic_hidden=(16,))
    save_policy(tmp_path / "policy.pt", model)
    imitator = make_phc(params, skeleton=amp, checkpoint=tmp_path / "policy.pt")
    s = random_state(np.random.default_rng(0), 3, amp.num_bodies, amp.num_dofs)
    s = SimState(**{k: v.float() for k, v in vars(s).items() if isinstance(v, torch.Tensor) and v.is_floating_point()})
    obs = imitator.observe(s, s)
    assert obs.proprio.shape == (3, 15 * amp.num_bodies - 2) and obs.goal is not None and obs.goal.shape == (3, 9 * amp.num_bodies)
    act = imitator.act(obs)
    assert act.shape == (3, amp.num_dofs) and torch.all(torch.isfinite(act))
    torch.testing.assert_close(act, imitator.action_map(model.mean_action(torch.cat((obs.proprio, obs.goal), -1)), None))
    with pytest.raises(ValueError, match="observation dims"):
        make_phc(PHCParams(obs="rot"), skeleton=amp, checkpoint=tmp_path / "policy.pt")


def standing_clip(skeleton, frames: int = 20):
    """A synthetic clip: the rest pose, feet just above the ground, not moving."""
    from mocap.kinematics import forward_kinematics_dofs
    from mocap.motion.clip import Clip

    root_rot = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=F64)
    pos, _ = forward_kinematics_dofs(skeleton, torch.zeros(1, 3, dtype=F64), root_rot, torch.zeros(1, skeleton.num_dofs, dtype=F64))
    height = 0.1 - float(pos[0, :, 2].min())
    root_pos = np.tile([0.0, 0.0, height], (frames, 1))
    joint_rot = np.tile([1.0, 0.0, 0.0, 0.0], (frames, skeleton.num_bodies - 1, 1))
    return Clip("stand", skeleton.name, 30.0, root_pos, np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1)), joint_rot, loop=False)


@pytest.mark.parametrize("obs, dim", [("rot", 358 + 576), ("keypoint", 358 + 216)])
def test_env_on_smpl(obs, dim):
    smpl = smpl_skeleton()
    lib = MotionLibrary([standing_clip(smpl)], smpl)
    env = ImitationEnv(PHCParams(obs=obs, action="absolute", sixd="tan_norm"), smpl, lib, make_sim(smpl, 2), seed=0)
    assert env.obs_dim == dim and env.reset().shape == (2, dim) and env.action_space.shape == (69,)
    for _ in range(3):
        res = env.step(torch.zeros(2, 69))  # absolute zero action = the rest pose = the reference
        assert res.obs.shape == (2, dim) and torch.all(torch.isfinite(res.reward))
    env.close()


def test_make_env_from_stage_context(amp, clips):
    """``PHCImitator.make_env`` builds the library and the simulators through the stage context."""
    import types

    from rich.console import Console

    built = []

    def build(path, **kwargs):
        built.append((path, kwargs.get("num_envs")))
        if path == "motions":
            return types.SimpleNamespace(load=lambda skeleton: clips)
        assert path == "simulator" and kwargs["skeleton"] is amp
        return make_sim(amp, kwargs["num_envs"])

    ctx = types.SimpleNamespace(build=build, seed=3, console=Console(quiet=True))
    imitator = make_phc(PHCParams(), skeleton=amp)
    env = imitator.make_env(ctx, 3)
    assert isinstance(env, ImitationEnv) and env.num_envs == 3 and env.obs_dim == imitator.obs_dim
    assert env.library.clip_names == ["walk", "kick"]
    env.reset()
    env.evaluate_clips(lambda obs: torch.zeros(obs.shape[0], amp.num_dofs))
    assert built == [("motions", None), ("simulator", 3), ("simulator", 2)]
    env.close()


@pytest.mark.parametrize("grid", [True, False])
def test_control_grid_starts_and_reference(amp, clips, grid):
    """control_grid: start times are grid times j dt inside the admissible range and the step's
    reference is the table row (= interpolation at that time); off: continuous start times."""
    env = make_env(amp, clips, n=64, seed=3, control_grid=grid)
    env.reset()
    j = env.start_time / env.dt
    on_grid = (j - j.round()).abs() < 1e-9
    assert bool(on_grid.all()) == grid
    assert (env.library._grid is not None) == grid
    dur = env.library._dur64[env.clip_ids]
    assert bool((env.start_time <= dur - env.dt * (~env.library.loops[env.clip_ids]).double() + 1e-9).all())
    loops = env.library.loops[env.clip_ids]
    assert bool((env.start_time[loops] < dur[loops] - 1e-9).all())  # one period: [0, duration)
    plain = MotionLibrary(clips, amp)
    res = env.step(torch.zeros(64, amp.num_dofs))
    live = ~(res.terminated | res.truncated)
    t = env.start_time + (env.progress + 1).double() * env.dt
    expect = plain.frames(env.clip_ids, t)
    torch.testing.assert_close(env._ref_next.body_pos[live], expect.body_pos[live], atol=2e-6, rtol=0)
    env.close()


def test_termination_curriculum_anneals_loose_to_tight_and_resumes(amp, clips):
    """``termination_curriculum``: the threshold starts at ``start``, moves linearly to the rule's over
    ``env_steps`` training env steps, then holds; it is part of the env state (exact resume)."""
    from mocap_phc.termination import curriculum_threshold

    n = 4
    env = make_env(amp, clips, n=n, termination="code", termination_curriculum={"start": 1.0, "env_steps": 4 * n})
    env.reset()
    assert env.termination.threshold == pytest.approx(1.0)
    zeros = torch.zeros(n, *env.action_space.shape)
    seen = []
    for _ in range(6):
        env.step(zeros)
        seen.append(env.termination.threshold)
    assert seen[:4] == pytest.approx([1.0 - 0.75 * k / 4 for k in range(1, 5)]) and seen[4:] == pytest.approx([0.25, 0.25])
    saved = env.state_dict()
    other = make_env(amp, clips, n=n, termination="code", termination_curriculum={"start": 1.0, "env_steps": 4 * n})
    other.reset()
    other.load_state_dict(saved)
    assert other.termination.threshold == pytest.approx(0.25) and other._steps_seen == 6 * n
    plain = make_env(amp, clips, n=n, termination="code")
    assert plain.termination.threshold is None  # no curriculum: the rule's fixed default
    assert curriculum_threshold(type("C", (), {"start": 0.5, "env_steps": 10})(), 0.25, 5) == pytest.approx(0.375)
    env.close(), other.close(), plain.close()
