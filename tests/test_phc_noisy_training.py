"""PHC training on noisy references (PHCParams.reference_noise): the policy sees the noisy
reference and acts relative to it; reward and termination use the clean clip; resume is exact."""

from __future__ import annotations

import torch

from mocap.motion.library import MotionLibrary
from mocap.noisy import DEFAULT_LEVELS
from mocap_phc.env import ImitationEnv, PHCObservation
from mocap_phc.imitator import PHCParams


def _env(amp, clips, noise, n=4, seed=0):
    from mocap_sim_mujoco.simulator import MujocoSimulator

    lib = MotionLibrary([c for c in clips.clips if c.name in ("walk", "kick")], amp)
    params = PHCParams(action="residual", reference_noise=noise, eval_every=0)
    return ImitationEnv(params, amp, lib, MujocoSimulator(skeleton=amp, num_envs=n, seed=0), seed=seed)


def _clips(amp):
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource

    return DeepMimicSource(DeepMimicParams(clips=["walk", "kick"])).load(amp)


def test_policy_sees_the_noisy_reference_and_the_reward_the_clean_one(amp):
    clips = _clips(amp)
    env = _env(amp, clips, DEFAULT_LEVELS[3])
    assert env.observed is not None
    obs = env.reset()
    times = env.start_time + env.dt
    clean = env.library.frames(env.clip_ids, times)
    noisy = env.observed.frames(env.clip_ids, times)
    assert not torch.allclose(clean.dof_pos, noisy.dof_pos)
    expect = PHCObservation.flatten(env.observation(env.sim.state, noisy))
    torch.testing.assert_close(obs, expect.to(obs))
    torch.testing.assert_close(env._ref_next.body_pos, clean.body_pos)
    # the PD targets of a zero residual are the noisy reference's joint angles
    seen_targets = {}
    step = env.sim.step

    def spy(targets):
        seen_targets["t"] = targets.clone()
        return step(targets)

    env.sim.step = spy
    result = env.step(torch.zeros(4, env.action_space.shape[0]))
    torch.testing.assert_close(seen_targets["t"].to(noisy.dof_pos), env.action_map(torch.zeros(4, env.action_space.shape[0]), noisy.dof_pos).to(noisy.dof_pos))
    # the imitation reward is computed against the clean reference, not the one the policy saw
    r_clean, _ = env.reward_fn(env.sim.state, clean)
    r_noisy, _ = env.reward_fn(env.sim.state, noisy)
    got = result.info["reward/imitation"].double()
    torch.testing.assert_close(got, r_clean.double().to(got))
    assert not torch.allclose(got, r_noisy.double().to(got))


def test_clean_level_and_none_are_the_plain_env(amp):
    clips = _clips(amp)
    a, b = _env(amp, clips, None), _env(amp, clips, DEFAULT_LEVELS[0])
    assert a.observed is None and b.observed is None
    torch.testing.assert_close(a.reset(), b.reset())


def test_noise_is_redrawn_and_resume_restores_the_draw(amp):
    clips = _clips(amp)
    env = _env(amp, clips, DEFAULT_LEVELS[2])
    env.reset()
    before = env.observed.dof_pos.clone()
    zero = torch.zeros(4, env.action_space.shape[0])
    env.after_iteration(1, lambda o: torch.zeros(o.shape[0], env.action_space.shape[0]))
    # the redraw waits for the next step: the observation already handed out stays valid
    assert env._noise_draw == 0 and torch.equal(env.observed.dof_pos, before)
    sd = env.state_dict()  # a checkpoint between the iteration and the next step
    fresh = _env(amp, clips, DEFAULT_LEVELS[2])
    fresh.reset()
    fresh.load_state_dict(sd)
    torch.testing.assert_close(fresh.current_obs(), env.current_obs())
    a, b = env.step(zero), fresh.step(zero)
    assert env._noise_draw == 1 and not torch.allclose(env.observed.dof_pos, before)
    torch.testing.assert_close(fresh.observed.dof_pos, env.observed.dof_pos)
    torch.testing.assert_close(a.obs, b.obs)
    torch.testing.assert_close(a.reward, b.reward)
