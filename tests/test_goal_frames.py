"""A PHC goal of several reference frames (PHCParams.goal_frames, Imitator.reference_steps): the
reference frames ahead, the goal blocks, the imitator contract, and widening a one-frame policy into
one that starts exactly where it was (PPO's init_policy_repeat_tail)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap.checkpoint import CheckpointError
from mocap.imitation_eval import episode_frames, rollout_imitation
from mocap.interfaces import Box
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap.motion.library import MotionLibrary
from mocap.observations import imitation_goal, imitation_goal_dim, proprioception_and_goal, proprioception_dim
from mocap.rl.networks import ActorCritic, init_from_policy, save_policy
from mocap_phc.imitator import PHCImitator, PHCParams
from mocap_phc.observation import PHCObservation

torch.set_num_threads(1)
DT = 1.0 / 30.0


@pytest.fixture(scope="module")
def lib(amp):
    """walk (looping) and kick (non-looping)."""
    return MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk", "kick"])).load(amp), amp)


def make_sim(skeleton, n):
    from mocap_sim_mujoco.simulator import MujocoSimulator

    return MujocoSimulator(skeleton=skeleton, num_envs=n, seed=0, dtype=torch.float32)


def test_frames_ahead_are_the_frames_one_two_steps_later_and_follow_index(lib):
    ids, t = torch.tensor([0, 1, 1]), torch.tensor([0.2, 0.0, 1.5], dtype=torch.float64)
    ref = lib.frames_ahead(ids, t, DT, 3)
    assert len(ref.ahead) == 2 and lib.frames_ahead(ids, t, DT, 1).ahead == ()
    for k, later in enumerate(ref.ahead, start=1):
        assert torch.equal(later.body_pos, lib.frames(ids, t + k * DT).body_pos)
    rows = ref.index(torch.tensor([2, 0]))
    assert torch.equal(rows.ahead[1].body_pos, ref.ahead[1].body_pos[[2, 0]])
    assert rows.to("cpu").ahead[0].times.tolist() == ref.ahead[0].times[[2, 0]].tolist()
    with pytest.raises(ValueError, match="steps must be >= 1"):
        lib.frames_ahead(ids, t, DT, 0)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(t0=st.floats(0.0, 1.2), lag=st.floats(0.0, 0.5), kind=st.sampled_from(["rot", "keypoint"]), frames=st.integers(1, 4))
def test_the_goal_is_one_block_per_frame_each_against_the_current_state(amp, lib, t0, lag, kind, frames):
    ids = torch.tensor([0, 1])
    t = torch.full((2,), t0, dtype=torch.float64)
    state = lib.frames(ids, t + lag)  # a "simulated" state off the reference by lag seconds
    ref = lib.frames_ahead(ids, t + DT, DT, frames)
    proprio, goal = proprioception_and_goal(state, ref, kind, "zhou", ref.ahead)
    g = imitation_goal_dim(amp.num_bodies, kind)
    assert proprio.shape[-1] == proprioception_dim(amp.num_bodies) and goal.shape[-1] == frames * g
    for k, r in enumerate((ref, *ref.ahead)):
        torch.testing.assert_close(goal[:, k * g : (k + 1) * g], imitation_goal(state, r, kind, "zhou"))


def test_the_phc_observation_needs_its_frames_ahead(amp, lib):
    ids, t = torch.tensor([0]), torch.tensor([0.1], dtype=torch.float64)
    obs3 = PHCObservation(frames=3)
    assert obs3.dim(amp.num_bodies) == PHCObservation().dim(amp.num_bodies) + 2 * imitation_goal_dim(amp.num_bodies, "rot")
    with pytest.raises(ValueError, match="observes 3 reference frames but got 1"):
        obs3(lib.frames(ids, t), lib.frames(ids, t + DT))
    one = PHCObservation()(lib.frames(ids, t), lib.frames_ahead(ids, t + DT, DT, 3))  # extra frames are ignored by a one-frame goal
    assert one.goal is not None and one.goal.shape[-1] == imitation_goal_dim(amp.num_bodies, "rot")
    assert PHCImitator(PHCParams(goal_frames=3), amp).reference_steps == 3 and PHCImitator(PHCParams(), amp).reference_steps == 1


def _policy(tmp_path: Path, obs_dim: int, actions: int) -> tuple[ActorCritic, Path]:
    torch.manual_seed(0)
    model = ActorCritic(obs_dim, Box((actions,), -1.0, 1.0), actor_hidden=(16,), critic_hidden=(16,), normalize_value=True)
    with torch.no_grad():
        model.obs_norm.update(torch.randn(64, obs_dim) * 3 + 1)
        model.value_norm.update(torch.randn(64) * 2)
    path = tmp_path / "policy.pt"
    save_policy(path, model)
    return model, path


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(tail=st.integers(1, 6), reps=st.integers(1, 3), seed=st.integers(0, 2**31 - 1))
def test_a_widened_policy_acts_and_values_exactly_as_its_source_whatever_the_new_inputs(tmp_path_factory, tail, reps, seed):
    src, path = _policy(tmp_path_factory.mktemp("p"), 6, 3)
    wide = ActorCritic(6 + tail * reps, Box((3,), -1.0, 1.0), actor_hidden=(16,), critic_hidden=(16,), normalize_value=True)
    init_from_policy(wide, path, None, tail)
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(5, 6, generator=g) * 4
    new = torch.randn(5, tail * reps, generator=g) * 4
    with torch.no_grad():
        torch.testing.assert_close(wide.mean_action(torch.cat([x, new], -1)), src.mean_action(x), rtol=0, atol=1e-6)
        torch.testing.assert_close(wide.value(torch.cat([x, new], -1)), src.value(x), rtol=0, atol=1e-6)
    torch.testing.assert_close(wide.obs_norm.mean[6:], src.obs_norm.mean[6 - tail :].repeat(reps))
    torch.testing.assert_close(wide.obs_norm.var[6:], src.obs_norm.var[6 - tail :].repeat(reps))


def test_widening_refuses_what_is_not_whole_repeats_of_the_tail(tmp_path):
    _, path = _policy(tmp_path, 6, 3)
    with pytest.raises(CheckpointError, match="cannot widen"):
        init_from_policy(ActorCritic(11, Box((3,), -1.0, 1.0), actor_hidden=(16,), critic_hidden=(16,)), path, None, 3)
    with pytest.raises(CheckpointError, match="cannot widen"):
        init_from_policy(ActorCritic(20, Box((3,), -1.0, 1.0), actor_hidden=(16,), critic_hidden=(16,)), path, None, 7)
    with pytest.raises(CheckpointError, match="does not fit"):  # without repeat_tail the sizes must match
        init_from_policy(ActorCritic(9, Box((3,), -1.0, 1.0), actor_hidden=(16,), critic_hidden=(16,)), path)


def test_a_three_frame_imitator_widened_from_a_one_frame_one_tracks_identically(amp, lib, tmp_path):
    """End to end through the evaluator (rollout_imitation builds frames_ahead from the imitator's
    reference_steps): the widened three-frame PHC imitator's rollout is the one-frame one's."""
    p1 = PHCParams(action="residual")
    d1 = p1.observation().dim(amp.num_bodies)
    src, path = _policy(tmp_path, d1, amp.num_dofs)
    one = PHCImitator(p1, amp, src)
    p3 = PHCParams(action="residual", goal_frames=3)
    wide = ActorCritic.from_config({**src.config, "obs_dim": p3.observation().dim(amp.num_bodies)})
    init_from_policy(wide, path, None, imitation_goal_dim(amp.num_bodies, "rot"))
    three = PHCImitator(p3, amp, wide)
    ids = torch.arange(lib.num_clips)
    runs = []
    for imitator in (one, three):
        sim = make_sim(amp, len(ids))
        runs.append(rollout_imitation(sim, lib, imitator, ids, episode_frames(lib, ids, sim.dt, None).clamp_max(12), threshold=10.0).traj.sim)
        sim.close()
    # equal up to float rounding: a wider matrix product may sum the same non-zero terms in another order
    torch.testing.assert_close(runs[0], runs[1], rtol=0, atol=1e-4)


def test_the_env_observes_the_goal_frames_and_a_latent_refuses_a_multi_frame_teacher(amp, lib):
    from mocap.latent_imitator import LatentImitator
    from mocap_phc.env import ImitationEnv

    params = PHCParams(action="residual", goal_frames=2, start_sampling={"mode": "uniform"})
    env = ImitationEnv(params, amp, lib, make_sim(amp, 4), seed=0)
    obs = env.reset()
    assert obs.shape == (4, params.observation().dim(amp.num_bodies)) == (4, env.obs_dim)
    g = imitation_goal_dim(amp.num_bodies, "rot")
    later = lib.frames(env.clip_ids, env.start_time + 2 * env.dt)  # the second goal frame: t + 2 dt
    torch.testing.assert_close(obs[:, -g:], imitation_goal(env.sim.state, later, "rot", "zhou").float())
    obs2 = env.step(torch.zeros(4, amp.num_dofs)).obs
    assert obs2.shape == obs.shape and bool(torch.isfinite(obs2).all())
    env.close()

    class _Encoder:
        has_encoder = True

    with pytest.raises(ValueError, match="observes 2 reference frames"):
        LatentImitator(PHCImitator(params, amp), _Encoder())  # type: ignore[arg-type]
