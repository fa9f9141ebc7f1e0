"""Fallen starts that track a get-up clip (``PHCParams.getup_starts``, ``mocap.getup_starts``): the
reference is the get-up clip that lies like the humanoid, laid onto it; its last frame is held at rest
for ``hold_s``; those episodes stay out of the mining statistics; the env resumes exactly."""

from __future__ import annotations

import pydantic
import pytest
import torch
from test_recovery_eval import bundled  # noqa: F401  (fixture)

from mocap.motion.transform import best_yaw
from mocap.rotations import quat_angle_between
from mocap_phc.recovery import FailStateParams


def _env(amp, lib, n=3, hold_s=0.5, recovery_steps=1000, fall=1.0, grid=False):
    from mocap_phc.env import ImitationEnv
    from mocap_phc.imitator import PHCParams
    from mocap.fail_state_params import GetUpStartParams
    from mocap_sim_mujoco.simulator import MujocoSimulator

    params = PHCParams(
        action="residual",
        fail_states=FailStateParams(fall_init_prob=fall, recovery_steps=recovery_steps, settle_steps=40),
        getup_starts=GetUpStartParams(hold_s=hold_s),
        eval_every=0,
        control_grid=grid,
    )
    return ImitationEnv(params, amp, lib, MujocoSimulator(skeleton=amp, num_envs=n, seed=0), seed=5)


def test_getup_starts_need_fallen_starts_and_exclude_amp():
    from mocap_phc.imitator import PHCParams

    with pytest.raises(pydantic.ValidationError, match="getup_starts needs fallen starts"):
        PHCParams(getup_starts={})
    with pytest.raises(pydantic.ValidationError, match="getup_starts needs fallen starts"):
        PHCParams(getup_starts={}, fail_states={"far_init_prob": 0.5})
    with pytest.raises(pydantic.ValidationError, match="getup_starts with amp"):
        PHCParams(getup_starts={}, fail_states={"fall_init_prob": 0.3}, amp=True)
    assert PHCParams(getup_starts={"clips": ["getup_faceup"]}, fail_states={"fall_init_prob": 0.3}).getup_starts.hold_s == 2.0


@pytest.mark.parametrize("grid", [False, True])
def test_a_fallen_start_tracks_the_get_up_clip_that_lies_like_it(amp, bundled, grid):  # noqa: F811
    lib = bundled
    env = _env(amp, lib, grid=grid)
    env.reset()
    s = env.sim.state
    names = [lib.clip_names[int(c)] for c in env.clip_ids]
    assert all(n.startswith("getup_") for n in names) and bool((env.start_time == 0).all())
    ref0 = env._ref_at(None, 0)
    torch.testing.assert_close(ref0.root_pos[:, :2].double(), s.root_pos[:, :2].double(), atol=1e-5, rtol=0)  # laid onto the humanoid
    # the chosen clip's first frame, turned, is the closest to how the humanoid lies among the get-ups
    getups = [i for i, n in enumerate(lib.clip_names) if n.startswith("getup_")]
    first = lib.frames(torch.tensor(getups), torch.zeros(len(getups), dtype=lib.dtype)).root_rot.double()
    resid = torch.stack([best_yaw(s.root_rot.double(), first[j].expand(3, 4))[1] for j in range(len(getups))], -1)
    torch.testing.assert_close(quat_angle_between(ref0.root_rot.double(), s.root_rot.double()), resid.min(-1).values, atol=1e-5, rtol=0)
    assert bool(env.getup.active.all())


def test_a_get_up_episode_holds_the_last_frame_at_rest_then_ends_and_is_not_mined(amp, bundled):  # noqa: F811
    lib = bundled
    env = _env(amp, lib, n=2, hold_s=0.5)
    recorded = []
    env._record = lambda clips, failed: recorded.append(clips.clone())  # what mining would count
    env.reset()
    dur = float(lib.durations[int(env.clip_ids[0])])
    zero = torch.zeros(2, amp.num_dofs)
    steps = 0
    while True:
        res = env.step(zero)
        steps += 1
        done = bool(res.terminated[0] | res.truncated[0])
        t_ref = (steps + 1) * env.dt  # the reference the next observation holds
        if not done and t_ref >= dur:
            assert float(env._ref_next.body_lin_vel[0].abs().max()) == 0.0  # held at rest after the clip
        if done:
            break
        assert steps < 400
    assert bool(res.truncated[0]) and not bool(res.terminated[0])
    assert steps == pytest.approx((dur + 0.5) / env.dt, abs=1.5)  # the clip, then hold_s
    assert all(len(c) == 0 for c in recorded)  # get-up episodes are left out of the mining statistics


def test_get_up_starts_resume_exactly(amp, bundled):  # noqa: F811
    a, b = _env(amp, bundled, n=4, fall=0.5, recovery_steps=20), _env(amp, bundled, n=4, fall=0.5, recovery_steps=20)
    a.reset()
    g = torch.Generator().manual_seed(1)
    acts = [0.2 * torch.randn(4, amp.num_dofs, generator=g) for _ in range(20)]
    for x in acts[:10]:
        a.step(x)
    b.load_state_dict(a.state_dict())
    assert torch.equal(a.getup.active, b.getup.active) and torch.equal(a.getup.yaw, b.getup.yaw)
    for x in acts[10:]:
        ra, rb = a.step(x), b.step(x)
        assert torch.equal(ra.obs, rb.obs) and torch.equal(ra.reward, rb.reward)
    sd = a.state_dict()
    sd.pop("getup_starts")
    with pytest.raises(ValueError, match="no get-up start state"):
        b.load_state_dict(sd)


def test_distillation_gives_fallen_starts_the_get_up_reference_too(amp, bundled):  # noqa: F811
    """A latent space distilled from a teacher trained with getup_starts sees its get-ups the same way."""
    from mocap.distill import DistillParams
    from mocap.distill_episodes import DistillEpisodes
    from mocap_sim_mujoco.simulator import MujocoSimulator

    with pytest.raises(pydantic.ValidationError, match="getup_starts needs fallen starts"):
        DistillParams(num_envs=4, minibatch_envs=4, getup_starts={})
    fs = FailStateParams(fall_init_prob=1.0, recovery_steps=1000, settle_steps=40)

    def make():
        params = DistillParams(num_envs=3, minibatch_envs=3, fail_states=fs, getup_starts={"hold_s": 0.2}, control_grid=False)
        return DistillEpisodes(params, bundled, MujocoSimulator(skeleton=amp, num_envs=3, seed=0), seed=0)

    ep = make()
    mined = []
    ep._record = lambda clips, failed: mined.append(clips.clone())
    ep.reset_all()
    assert bool(ep.getup.active.all())
    names = [bundled.clip_names[int(c)] for c in ep.clip_ids]
    assert all(n.startswith("getup_") for n in names) and bool((ep.start_time == 0).all())
    s = ep.sim.state
    ref = ep.reference_next()  # one step into the clip laid onto the humanoid: its root is near the humanoid's
    assert float(torch.linalg.vector_norm(ref.root_pos[:, :2].double() - s.root_pos[:, :2].double(), dim=-1).max()) < 0.1
    hold = s.dof_pos.clone()
    for _ in range(12):
        ep.after_step(ep.sim.step(hold), ep.reference_next())
    ep2 = make()
    ep2.reset_all()
    ep2.load_state_dict(ep.state_dict())
    assert torch.equal(ep2.getup.active, ep.getup.active) and torch.equal(ep2.getup.target, ep.getup.target)
    torch.testing.assert_close(ep2.reference_next().body_pos, ep.reference_next().body_pos)
    dur = float(bundled.durations[int(ep.clip_ids[0])])
    steps, ended = 12, False
    while not ended:  # a get-up episode ends after its clip plus hold_s, and is not mined
        out = ep.after_step(ep.sim.step(hold), ep.reference_next())
        steps += 1
        ended = bool(out["truncated"][0] | out["terminated"][0])
        assert steps < 200
    assert bool(out["truncated"][0]) and steps == pytest.approx((dur + 0.2) / ep.dt, abs=1.5)
    assert all(len(c) == 0 for c in mined)
