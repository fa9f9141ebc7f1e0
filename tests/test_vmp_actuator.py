"""VMP's actuator model (Eqs. 9-11, ``mocap_sim_mujoco.actuators``) as a simulator option, and the
tracking env's domain randomization (``mocap_vmp.randomization``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from mocap_sim_mujoco.actuators import (
    ActuatorModelParams,
    applied_torque,
    clamp_torque,
    friction_torque,
    pd_torque,
    torque_limits,
)

torch.set_num_threads(1)

speed = st.floats(-300.0, 300.0, allow_nan=False)
torque = st.floats(-5000.0, 5000.0, allow_nan=False)
positive = st.floats(0.01, 1000.0)


@st.composite
def envelopes(draw):
    tau_max = draw(st.floats(0.1, 1000.0))
    qd_tau = draw(st.floats(0.0, 50.0))
    qd_max = qd_tau + draw(st.floats(0.01, 100.0))
    return tau_max, qd_tau, qd_max


# ------------------------------------------------------------------------------ envelope
@settings(max_examples=200, deadline=None)
@given(env=envelopes(), tau=torque, qd=speed)
def test_clamp_stays_in_the_envelope(env, tau, qd):
    tau_max, qd_tau, qd_max = env
    lo, hi = torque_limits(qd, tau_max, qd_tau, qd_max)
    c = float(clamp_torque(tau, qd, tau_max, qd_tau, qd_max))
    assert -tau_max - 1e-9 <= float(lo) <= 0.0 <= float(hi) <= tau_max + 1e-9
    assert float(lo) - 1e-9 <= c <= float(hi) + 1e-9 and abs(c) <= tau_max + 1e-9
    # inside the envelope the torque passes unchanged
    if float(lo) <= tau <= float(hi):
        assert c == pytest.approx(tau, abs=1e-12)
    # symmetric: tau_lo(qd) = -tau_hi(-qd)
    lo2, hi2 = torque_limits(-qd, tau_max, qd_tau, qd_max)
    assert float(lo) == pytest.approx(-float(hi2), abs=1e-9) and float(hi) == pytest.approx(-float(lo2), abs=1e-9)


@settings(max_examples=100, deadline=None)
@given(env=envelopes(), qd=st.floats(0.0, 300.0))
def test_envelope_shape(env, qd):
    tau_max, qd_tau, qd_max = env
    lo, hi = (float(x) for x in torque_limits(qd, tau_max, qd_tau, qd_max))
    # braking (torque against the motion) always allows tau_max
    assert lo == pytest.approx(-tau_max)
    # driving: full up to qd_tau, linear ramp, zero from qd_max on
    if qd <= qd_tau:
        assert hi == pytest.approx(tau_max)
    elif qd >= qd_max:
        assert hi == 0.0
    else:
        assert hi == pytest.approx(tau_max * (qd_max - qd) / (qd_max - qd_tau), rel=1e-9, abs=1e-9)
    # continuous at qd_tau and at qd_max; non-increasing in qd
    eps = 1e-6 * (qd_max - qd_tau)
    assert float(torque_limits(qd_tau + eps, tau_max, qd_tau, qd_max)[1]) == pytest.approx(tau_max, rel=1e-4)
    assert float(torque_limits(qd_max - eps, tau_max, qd_tau, qd_max)[1]) == pytest.approx(0.0, abs=1e-4 * tau_max)
    assert float(torque_limits(qd + 1.0, tau_max, qd_tau, qd_max)[1]) <= hi + 1e-12


# ------------------------------------------------------------------------------ friction
@settings(max_examples=200, deadline=None)
@given(qd=speed, mu_s=st.floats(0.0, 10.0), mu_d=st.floats(0.0, 1.0), qd_s=st.floats(0.01, 10.0))
def test_friction_is_odd_and_bounded(qd, mu_s, mu_d, qd_s):
    f = float(friction_torque(qd, mu_s, mu_d, qd_s))
    assert float(friction_torque(-qd, mu_s, mu_d, qd_s)) == pytest.approx(-f, abs=1e-12)
    assert f * qd >= 0.0  # it opposes the motion once subtracted
    assert abs(f - mu_d * qd) <= mu_s + 1e-12  # |mu_s tanh(.)| <= mu_s
    assert float(friction_torque(0.0, mu_s, mu_d, qd_s)) == 0.0


# --------------------------------------------------------------------------------- Eq. 11
def _params(env, mu_s, mu_d, qd_s, kp, kd):
    tau_max, qd_tau, qd_max = env
    return {"kp": kp, "kd": kd, "tau_max": tau_max, "qd_tau_max": qd_tau, "qd_max": qd_max, "mu_s": mu_s, "mu_d": mu_d, "qd_s": qd_s}


@settings(max_examples=150, deadline=None)
@given(env=envelopes(), q=st.floats(-3.0, 3.0), kp=positive, kd=st.floats(0.0, 100.0), mu_s=st.floats(0.0, 5.0), mu_d=st.floats(0.0, 1.0))
def test_zero_error_and_zero_speed_give_zero_torque(env, q, kp, kd, mu_s, mu_d):
    kw = _params(env, mu_s, mu_d, 0.1, kp, kd)
    assert float(applied_torque(q, q, 0.0, **kw)) == 0.0
    assert float(pd_torque(kp, kd, q, q, 0.0)) == 0.0


@settings(max_examples=150, deadline=None)
@given(
    env=envelopes(),
    q=st.floats(-3.0, 3.0),
    qd=speed,
    e1=st.floats(-5.0, 5.0),
    e2=st.floats(-5.0, 5.0),
    kp=positive,
    kd=st.floats(0.0, 100.0),
)
def test_torque_is_monotone_in_the_error_and_matches_the_formula(env, q, qd, e1, e2, kp, kd):
    kw = _params(env, 0.45, 0.023, 0.1, kp, kd)
    lo_e, hi_e = sorted((e1, e2))
    # monotone in (a - q) before the clamp (strictly: slope kp) and after it (non-decreasing)
    assert float(pd_torque(kp, kd, q + hi_e, q, qd)) - float(pd_torque(kp, kd, q + lo_e, q, qd)) == pytest.approx(kp * (hi_e - lo_e), rel=1e-6, abs=1e-6)
    assert float(applied_torque(q + hi_e, q, qd, **kw)) >= float(applied_torque(q + lo_e, q, qd, **kw)) - 1e-9
    # Eq. 11 written out by hand
    motor = kp * e1 - kd * qd
    lo, hi = torque_limits(qd, env[0], env[1], env[2])
    expect = min(max(motor, float(lo)), float(hi)) - (0.45 * np.tanh(qd / 0.1) + 0.023 * qd)
    assert float(applied_torque(q + e1, q, qd, **kw)) == pytest.approx(expect, rel=1e-9, abs=1e-9)


def test_params_validate():
    with pytest.raises(ValueError, match="qd_max"):
        ActuatorModelParams(qd_tau_max=20.0, qd_max=10.0)


# ------------------------------------------------------------------------------- simulator
def _sim(amp, n=2, timestep=1.0 / 600.0, substeps=20, model=True, **kw):
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator

    am = ActuatorModelParams(**kw) if model else None
    return MujocoSimulator(MujocoParams(threads=1, timestep=timestep, substeps=substeps, actuator_model=am), skeleton=amp, num_envs=n)


def test_default_is_off_and_keeps_position_actuators(amp):
    import mujoco

    sim = _sim(amp, timestep=1.0 / 120.0, substeps=4, model=False)
    assert sim.params.actuator_model is None and sim.actuators is None
    assert set(sim.model.actuator_biastype.tolist()) == {int(mujoco.mjtBias.mjBIAS_AFFINE)}
    np.testing.assert_allclose(sim.model.actuator_gainprm[:, 0], [h.kp for h in amp.hinges])
    sim.close()


def test_simulator_applies_equation_11_each_substep(amp):
    """With one substep the recorded joint torque is Eq. 11 at the state before the step, exactly."""
    import mujoco

    sim = _sim(amp, n=3, timestep=1.0 / 600.0, substeps=1)
    assert set(sim.model.actuator_biastype.tolist()) == {int(mujoco.mjtBias.mjBIAS_NONE)}
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        s0 = sim.state
        q0, qd0 = s0.dof_pos.double().numpy(), s0.dof_vel.double().numpy()
        targets = 0.4 * torch.randn(3, amp.num_dofs, generator=gen, dtype=torch.float64)
        st_ = sim.step(targets)
        expect = sim.actuators.torque(targets.numpy(), q0, qd0)
        np.testing.assert_allclose(st_.dof_force.double().numpy(), expect, rtol=1e-5, atol=1e-3)
        # the clamp of the targets to the joint ranges and the per-joint gains are the skeleton's
        lo = np.array([h.range[0] for h in amp.hinges])
        hi = np.array([h.range[1] for h in amp.hinges])
        kp = np.array([h.kp for h in amp.hinges])
        kd = np.array([h.kd for h in amp.hinges])
        tl = np.array([h.torque_limit for h in amp.hinges])
        manual = np.clip(kp * (np.clip(targets.numpy(), lo, hi) - q0) - kd * qd0, -tl, tl) - (0.45 * np.tanh(qd0 / 0.1) + 0.023 * qd0)
        ok = np.abs(qd0) <= 20.0  # below the ramp the envelope is the constant limit
        np.testing.assert_allclose(expect[ok], manual[ok], rtol=1e-9, atol=1e-9)
    sim.close()


def test_overrides_make_one_value_for_every_joint(amp):
    sim = _sim(amp, n=1, kp=100.0, kd=1.0, tau_max=500.0)
    assert np.all(sim.actuators.kp == 100.0) and np.all(sim.actuators.kd == 1.0) and np.all(sim.actuators.tau_max == 500.0)
    sim.close()


def test_large_timestep_is_refused(amp):
    with pytest.raises(ValueError, match="too large for explicit PD damping"):
        _sim(amp, n=1, timestep=1.0 / 120.0, substeps=4)


def test_standing_is_stable_at_the_recommended_step(amp):
    """1/600 s, 20 substeps: the humanoid holds its rest pose for 1 s (at 1/120 s it collapses)."""
    sim = _sim(amp, n=1)
    for _ in range(30):
        s = sim.step(torch.zeros(1, amp.num_dofs))
    assert float(s.root_pos[0, 2]) > 0.85 and float(s.dof_vel.abs().max()) < 2.0 and sim.instability_count == 0
    sim.close()


# ------------------------------------------------------------------------ domain randomization
def _plain_sim(amp, n):
    from mocap_sim_mujoco.simulator import MujocoParams, MujocoSimulator

    return MujocoSimulator(MujocoParams(threads=1), skeleton=amp, num_envs=n)


def test_external_wrench_pushes_the_pushed_env_only(amp):
    sim = _plain_sim(amp, 3)
    zero = torch.zeros(3, amp.num_dofs)
    push = torch.zeros(3, amp.num_bodies, 6)
    push[0, 0, 0] = 400.0  # +x force on the root of env 0
    push[1, 0, 4] = 80.0  # torque about +y on the root of env 1
    sim.set_external_wrench(torch.arange(3), push)
    torch.testing.assert_close(sim.external_wrench, push)
    s = sim.step(zero)
    assert float(s.root_lin_vel[0, 0]) > 0.1 + abs(float(s.root_lin_vel[2, 0]))
    assert float(s.root_ang_vel[1, 1]) > 0.1 + abs(float(s.root_ang_vel[2, 1]))  # the torque turns the root about +y
    # a reset clears the wrench: env 0 then evolves like the never-pushed env 2
    phys = sim.get_physics_state()
    sim.set_physics_state(torch.arange(3), np.repeat(phys[2:3], 3, axis=0))
    assert float(sim.external_wrench.abs().max()) == 0.0
    s = sim.step(zero)
    torch.testing.assert_close(s.root_lin_vel[0], s.root_lin_vel[2])
    sim.close()


def test_mass_and_friction_randomization_stay_in_range(amp):
    from mocap_vmp.randomization import DomainRandomizationParams, DomainRandomizer

    sim = _plain_sim(amp, 4)
    base_mass = sim.model.body_mass.copy()
    base_inertia = sim.model.body_inertia.copy()
    base_friction = sim.model.geom_friction[sim.index.floor_geom].copy()
    dr = DomainRandomizer(DomainRandomizationParams(mass_pct=10.0, ground_friction=(0.5, 1.25), push_interval_s=None), sim, torch.Generator().manual_seed(0))
    dr.on_reset(torch.arange(4))
    models = sim.env_models()
    bid = sim.index.body_ids
    scales = np.stack([m.body_mass[bid] / base_mass[bid] for m in models])
    assert np.all(scales >= 0.9 - 1e-12) and np.all(scales <= 1.1 + 1e-12) and scales.std() > 0.01
    np.testing.assert_allclose(scales, dr.mass_scale.numpy())
    for m, s in zip(models, scales):
        np.testing.assert_allclose(m.body_inertia[bid], base_inertia[bid] * s[:, None])
        assert m.body_subtreemass[bid[0]] == pytest.approx(float((base_mass[bid] * s).sum()))  # mj_setConst ran
    mu = np.array([m.geom_friction[sim.index.floor_geom, 0] for m in models])
    assert np.all((mu >= 0.5) & (mu <= 1.25)) and len(set(mu.tolist())) == 4
    assert all(m.geom_priority[sim.index.floor_geom] == 1 for m in models)
    # the shared model is untouched; a second reset of env 1 only redraws env 1
    np.testing.assert_array_equal(sim.model.body_mass, base_mass)
    np.testing.assert_array_equal(sim.model.geom_friction[sim.index.floor_geom], base_friction)
    before = dr.mass_scale.clone()
    dr.on_reset(torch.tensor([1]))
    assert torch.equal(dr.mass_scale[[0, 2, 3]], before[[0, 2, 3]]) and not torch.equal(dr.mass_scale[1], before[1])
    # the physics uses the per-env models: a 10 % heavier env with the same state and targets moves differently
    sim.step(torch.zeros(4, amp.num_dofs))
    sim.close()


def test_pushes_happen_on_schedule_and_change_velocities(amp):
    from mocap_vmp.randomization import DomainRandomizationParams, DomainRandomizer

    sim = _plain_sim(amp, 2)
    p = DomainRandomizationParams(
        mass_pct=None, ground_friction=None, push_interval_s=(0.1, 0.1), push_duration_s=(0.1, 0.1), push_force_max_mg=1.0, push_torque_max=10.0
    )
    dr = DomainRandomizer(p, sim, torch.Generator().manual_seed(1))
    dr.on_reset(torch.arange(2))
    assert dr._models is None  # no per-env models without mass or friction randomization
    steps = round(0.1 / sim.dt)
    assert dr.push_countdown.tolist() == [steps, steps]
    free = _plain_sim(amp, 2)  # the same envs without pushes
    zero = torch.zeros(2, amp.num_dofs)
    pushed_any = False
    for _ in range(steps + 1):
        dr.before_step()
        w = sim.external_wrench
        if float(w.abs().max()) > 0:
            pushed_any = True
            body = w.abs().sum(-1).argmax(-1)
            assert set(body.tolist()) <= set(dr.push_bodies.tolist())
            assert bool((w[..., :3].norm(dim=-1) <= 1.0 * dr.total_mass * 9.81 + 1e-6).all())
            assert bool((w[..., 3:].norm(dim=-1) <= 10.0 + 1e-9).all())
            assert int((w.abs().sum(-1) > 0).sum(-1).max()) == 1  # one body per push
        a, b = sim.step(zero), free.step(zero)
    assert pushed_any
    dv = (a.body_lin_vel - b.body_lin_vel).norm(dim=-1).amax(-1)
    assert bool((dv > 1e-3).all())
    # the push ends after its duration
    for _ in range(steps):
        dr.before_step()
        sim.step(zero)
    assert dr.push_left.max() <= steps
    sim.close()
    free.close()


def test_tracking_env_with_randomization_and_actuator_model_resumes_exactly(amp):
    """The VMP tracking env with both options: masses in range after resets, pushes on schedule,
    the torque penalty on the actuator model's torques, and an exact resume."""
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary
    from mocap_vmp.features import feature_stats
    from mocap_vmp.latent import VmpParams, make_vmp
    from mocap_vmp.randomization import DomainRandomizationParams
    from mocap_vmp.tracking import VmpTrackerParams, VmpTrackingEnv

    lib = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp), amp)
    torch.manual_seed(0)
    lat = make_vmp(VmpParams(window_half=6, latent_dim=8, channels=16, res_blocks=1, downsample=1), skeleton=amp)
    mean, std = feature_stats(lat.library_frame_features(lib), lat.layout, 1e-6)
    lat.set_statistics(mean, std)
    params = VmpTrackerParams(
        action="residual",
        episode_length_s=0.5,
        randomization=DomainRandomizationParams(push_interval_s=(0.1, 0.2), push_duration_s=(0.05, 0.1)),
    )
    assert VmpTrackerParams().randomization is None  # off by default

    def env():
        return VmpTrackingEnv(params, amp, lib, _sim(amp, n=2), lat.eval(), seed=0)

    a, b = env(), env()
    a.reset()
    s = a.randomizer.mass_scale
    assert bool(((s >= 0.9) & (s <= 1.1)).all()) and float(s.std()) > 0.01
    assert bool(((a.randomizer.friction >= 0.5) & (a.randomizer.friction <= 1.25)).all())
    g = torch.Generator().manual_seed(0)
    acts = [0.05 * torch.randn(2, amp.num_dofs, generator=g) for _ in range(16)]
    pushed = False
    for act in acts[:6]:
        out = a.step(act)
        pushed |= bool(a.sim.external_wrench.abs().sum() > 0)
        tau = a.sim.state.dof_force
        # logged unweighted (|tau|^2); the reward weighs it with -c_tau
        torch.testing.assert_close(out.info["reward/smooth/tau"], tau.square().sum(-1), rtol=1e-4, atol=1e-1)
        total = sum(w * out.info[f"reward/{k}"].double() for k, w in a.rewards.weights.items())
        assert a.rewards.weights["smooth/tau"] == -1e-5
        torch.testing.assert_close(out.reward.double(), total, rtol=1e-5, atol=1e-4)
    assert pushed
    b.load_state_dict(a.state_dict())
    torch.testing.assert_close(b.randomizer.mass_scale, a.randomizer.mass_scale)
    for act in acts[6:]:  # crosses episode ends (15 steps at 30 Hz), i.e. new masses and frictions
        ra, rb = a.step(act), b.step(act)
        assert torch.equal(ra.obs, rb.obs) and torch.equal(ra.reward, rb.reward)
    a.close(), b.close()
