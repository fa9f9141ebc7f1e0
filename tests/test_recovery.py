"""PHC's fail-state recovery goal (``mocap_phc.recovery``): close -> the full goal, far -> a point
goal on the (clamped) reference root, paper vs code velocity handling."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from test_distill import walk  # noqa: F401  (fixture)
from test_observations import SETTINGS, random_state, seeds

from mocap.observations import imitation_goal_rot
from mocap.rotations import quat_to_sixd
from mocap_phc.env import PHCObservation
from mocap_phc.recovery import RecoveryGoalParams, recovery_reference

B = 5


def _goal_parts(goal: torch.Tensor) -> dict[str, torch.Tensor]:
    g = goal.reshape(goal.shape[0], B, 24)
    return {"pos": g[..., 0:3], "rot": g[..., 3:9], "vel": g[..., 9:12], "ang": g[..., 12:15], "ref_pos": g[..., 15:18]}


@SETTINGS
@given(seeds, st.sampled_from(["paper", "code"]), st.floats(0.6, 12.0))
def test_far_goal_is_a_point_goal_on_the_clamped_root(seed, form, distance):
    rng = np.random.default_rng(seed)
    state, ref = random_state(rng, 4, B), random_state(rng, 4, B)
    # env 0 close (0.1 m), the others `distance` away from the simulated root
    direction = torch.nn.functional.normalize(torch.as_tensor(rng.standard_normal((4, 3))), dim=-1)
    gap = torch.tensor([0.1, distance, distance, distance], dtype=torch.float64)
    shift = state.root_pos + direction * gap[:, None] - ref.root_pos
    ref.body_pos = ref.body_pos + shift[:, None, :]
    ref.root_pos = ref.body_pos[:, 0].clone()
    params = RecoveryGoalParams(form=form, close_distance=0.5, far_distance=5.0)
    masked, far = recovery_reference(state, ref, params)
    assert far.tolist() == [False, True, True, True]
    for name in ("body_pos", "body_rot", "body_lin_vel", "body_ang_vel", "dof_pos"):
        assert torch.equal(getattr(masked, name)[0], getattr(ref, name)[0]), name  # the close env is untouched
    # far: the reference root pulled to at most far_distance, its rotation kept
    reach = torch.linalg.vector_norm(masked.root_pos[1:] - state.root_pos[1:], dim=-1)
    assert torch.allclose(reach, torch.full((3,), min(distance, 5.0), dtype=torch.float64), atol=1e-9)
    assert torch.equal(masked.body_rot[1:, 0], ref.body_rot[1:, 0])
    parts = _goal_parts(imitation_goal_rot(state, masked))
    identity6 = quat_to_sixd(torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64))
    assert torch.allclose(parts["pos"][1:, 1:], torch.zeros(3, B - 1, 3, dtype=torch.float64), atol=1e-9)
    assert torch.allclose(parts["rot"][1:, 1:], identity6.expand(3, B - 1, 6), atol=1e-6)
    assert torch.allclose(parts["vel"][1:, 1:], torch.zeros(3, B - 1, 3, dtype=torch.float64), atol=1e-9)
    root_vel_zero = torch.allclose(parts["vel"][1:, 0], torch.zeros(3, 3, dtype=torch.float64), atol=1e-9)
    assert root_vel_zero == (form == "code")  # the paper keeps the reference root's velocity
    assert torch.linalg.vector_norm(parts["pos"][1:, 0], dim=-1).max() > 0.5  # the point goal itself


def test_observation_reports_recovering_envs_and_keeps_shapes():
    rng = np.random.default_rng(0)
    state, ref = random_state(rng, 3, B), random_state(rng, 3, B)
    plain = PHCObservation()(state, ref)
    rec = PHCObservation(recovery=RecoveryGoalParams(close_distance=1e-3))(state, ref)
    assert rec.goal.shape == plain.goal.shape and bool(rec.extra["recovering"].all())
    assert not torch.allclose(rec.goal, plain.goal)
    never = PHCObservation(recovery=RecoveryGoalParams(close_distance=1e6))(state, ref)
    assert torch.equal(never.goal, plain.goal) and not bool(never.extra["recovering"].any())


def test_params_validate():
    with pytest.raises(ValueError):
        RecoveryGoalParams(close_distance=0.0)
    assert RecoveryGoalParams(form="code", close_distance=0.25, far_distance=3.0).far_distance == 3.0


# ------------------------------------------------------------------------------- fail states
def _env(amp, clip, fail, n=4, recovery_goal=None):
    from mocap.motion.library import MotionLibrary
    from mocap_phc.env import ImitationEnv
    from mocap_phc.imitator import PHCParams
    from mocap_sim_mujoco.simulator import MujocoSimulator

    params = PHCParams(action="residual", fail_states=fail, recovery_goal=recovery_goal, hard_negative=False, eval_every=0)
    return ImitationEnv(params, amp, MotionLibrary(clip, amp), MujocoSimulator(skeleton=amp, num_envs=n, seed=0), seed=3)


def test_fallen_starts_lie_on_the_ground_and_get_a_grace_window(amp, walk):  # noqa: F811
    from mocap_phc.recovery import FailStateParams

    env = _env(amp, walk, FailStateParams(fall_init_prob=1.0, recovery_steps=10, settle_steps=40), recovery_goal=RecoveryGoalParams())
    env.reset()
    s = env.sim.state
    assert bool((s.root_pos[:, 2] < 0.5).all()), s.root_pos  # lying, not standing (the reference root is ~0.9 m)
    ref_xy = env._ref_next.root_pos[:, :2]
    assert torch.allclose(s.root_pos[:, :2].double(), ref_xy.double(), atol=0.15)  # at the reference's place
    assert bool((env.recovery_left == 10).all())
    zero = torch.zeros(4, amp.num_dofs)
    for _ in range(9):  # far from the reference pose, but inside the grace window: no termination
        assert not bool(env.step(zero).terminated.any())
    ended = False
    for _ in range(5):
        ended |= bool(env.step(zero).terminated.any())
    assert ended  # after the window the tracking termination is back


def test_far_starts_and_exact_resume(amp, walk):  # noqa: F811
    from mocap_phc.recovery import FailStateParams

    fs = FailStateParams(fall_init_prob=0.5, far_init_prob=1.0, far_init_range=(2.0, 3.0), recovery_steps=5, settle_steps=20)
    a, b = _env(amp, walk, fs), _env(amp, walk, fs)
    a.reset()
    d = torch.linalg.vector_norm((a.sim.state.root_pos - a._ref_next.root_pos)[:, :2].double(), dim=-1)
    far = d > 1.5
    assert bool(far.any()) and bool(((d[far] > 1.9) & (d[far] < 3.2)).all()), d
    g = torch.Generator().manual_seed(0)
    acts = [0.2 * torch.randn(4, amp.num_dofs, generator=g) for _ in range(16)]
    for x in acts[:8]:
        a.step(x)
    b.load_state_dict(a.state_dict())
    for x in acts[8:]:
        ra, rb = a.step(x), b.step(x)
        assert torch.equal(ra.obs, rb.obs) and torch.equal(ra.reward, rb.reward) and torch.equal(ra.terminated, rb.terminated)


# ------------------------------------------------------------- PHC Eq. 4 and bonus recovery episodes
@SETTINGS
@given(st.lists(st.floats(0.0, 10.0), min_size=1, max_size=8), st.lists(st.floats(0.0, 10.0), min_size=1, max_size=8))
def test_point_goal_reward_is_the_decrease_of_the_distance(prev, now):
    from mocap_phc.recovery import point_goal_reward

    n = min(len(prev), len(now))
    p, d = torch.tensor(prev[:n], dtype=torch.float64), torch.tensor(now[:n], dtype=torch.float64)
    r = point_goal_reward(p, d)
    assert torch.allclose(r, p - d)
    assert bool(((r > 0) == (d < p)).all())  # positive exactly when the humanoid got closer
    assert torch.allclose(point_goal_reward(d, p), -r)


def test_point_reward_replaces_imitation_while_far(amp, walk):  # noqa: F811
    from mocap_phc.recovery import FailStateParams

    fs = FailStateParams(far_init_prob=1.0, far_init_range=(3.0, 4.0), recovery_steps=20)
    env = _env(amp, walk, fs, recovery_goal=RecoveryGoalParams(reward="point"))
    env.reset()
    prev = env.root_dist.clone()
    assert bool((prev > 2.9).all())
    res = env.step(torch.zeros(4, amp.num_dofs))
    expected = prev - env.root_dist
    energy = res.reward.double() - expected
    assert bool((energy <= 1e-9).all()) and bool((energy > -0.05).all()), energy  # reward = point term + a small energy penalty
    assert bool((res.info["recovery/far"] == 1.0).all())  # diagnostics: every env is recovering ...
    torch.testing.assert_close(res.info["recovery/root_dist_m"].double(), env.root_dist.double(), atol=1e-5, rtol=0)  # ... at this distance
    near = _env(amp, walk, None, recovery_goal=RecoveryGoalParams(reward="point"))
    near.reset()
    res = near.step(torch.zeros(4, amp.num_dofs))
    assert bool((res.reward > 0.1).all())  # close to the reference: the imitation reward (in (0, 1]), not a tiny distance change
    assert bool((res.info["recovery/far"] == 0.0).all())


def test_bonus_recovery_episodes_replace_terminations(amp, walk):  # noqa: F811
    from mocap_phc.recovery import FailStateParams

    fs = FailStateParams(recovery_episode_prob=1.0, recovery_steps=6)
    env = _env(amp, walk, fs)
    env.reset()
    flop = torch.full((4, amp.num_dofs), 2.5)  # wild residual targets: the humanoid leaves the reference quickly
    windows = 0
    for _ in range(60):
        res = env.step(flop)
        assert not bool(res.terminated.any())  # every termination became a bonus recovery episode
        windows += int((env.recovery_left == 6).sum())
    assert windows > 0


@SETTINGS
@given(st.lists(st.floats(0.0, 10.0), min_size=1, max_size=8), st.lists(st.floats(0.0, 10.0), min_size=1, max_size=8))
def test_point_goal_code_form_is_scaled_and_clipped(prev, now):
    """The official code's point reward: 9 min(d_{t-1} - d_t, 1/3) (issue 27 item 5)."""
    from mocap_phc.recovery import point_goal_reward

    n = min(len(prev), len(now))
    p, d = torch.tensor(prev[:n], dtype=torch.float64), torch.tensor(now[:n], dtype=torch.float64)
    r = point_goal_reward(p, d, "code")
    assert torch.allclose(r, 9.0 * torch.minimum(p - d, torch.full_like(p, 1.0 / 3.0)))
    assert bool((r <= 3.0 + 1e-12).all())


@pytest.mark.parametrize("weight", [0.1, 1.0])
def test_energy_penalty_is_weighted_while_recovering(amp, walk, weight):  # noqa: F811
    """PHC Eq. 4: r = 0.5 r^point + 0.5 r^amp + 0.1 r^energy while far: the env's energy term carries
    far_energy_weight (0.1 by default) for far envs; the logged reward/energy is the weighted one."""
    from mocap_phc.recovery import FailStateParams

    fs = FailStateParams(far_init_prob=1.0, far_init_range=(3.0, 4.0), recovery_steps=20)
    env = _env(amp, walk, fs, recovery_goal=RecoveryGoalParams(reward="point", far_energy_weight=weight))
    env.reset()
    for _ in range(5):  # past the code form's energy warm-up
        res = env.step(0.3 * torch.ones(4, amp.num_dofs))
    from mocap.imitation_rewards import energy_penalty

    st_ = env.sim.state
    raw = energy_penalty(st_.dof_force, st_.dof_vel, env.params.energy_form, env.params.energy_coef, env.progress)
    far = res.info["recovery/far"] > 0.5
    assert bool(far.any()) and bool((raw[far] < 0).all())
    torch.testing.assert_close(res.info["reward/energy"][far].double(), weight * raw[far].double(), atol=1e-9, rtol=1e-5)
