"""The ``phc`` imitator's reward formulas: the imitation reward's terms and forms, the energy penalty."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from phc_states import perturbed, random_state

from mocap.imitation_rewards import ImitationReward, energy_penalty, exp_term, imitation_errors

F64 = torch.float64
SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
seeds = st.integers(0, 2**32 - 1)


# ------------------------------------------------------------------------------------- rewards
@SETTINGS
@given(e1=st.floats(0.0, 50.0), e2=st.floats(0.0, 50.0), k=st.floats(0.01, 10.0))
def test_exp_term_range_identity_and_monotone(e1, e2, k):
    a, b = exp_term(torch.tensor(e1, dtype=F64), k), exp_term(torch.tensor(e2, dtype=F64), k)
    assert 0.0 < float(a) <= 1.0
    if e1 == 0.0:
        assert float(a) == 1.0
    if k * e1 > 1e-12:  # any error that floating point can resolve gives less than 1
        assert float(a) < 1.0
    if e1 < e2:
        assert float(a) >= float(b)
        if k * (e2 - e1) > 1e-12:
            assert float(a) > float(b)


@SETTINGS
@given(seed=seeds, eps=st.floats(0.0, 0.3), form=st.sampled_from(["paper", "code"]))
def test_imitation_reward_in_unit_interval_and_one_at_zero_error(seed, eps, form):
    rng = np.random.default_rng(seed)
    ref = random_state(rng, 4, 15)
    sim = perturbed(ref, rng, eps)
    fn = ImitationReward(form=form)
    total, terms = fn(sim, ref)
    assert torch.all(total > 0) and torch.all(total <= 1.0 + 1e-12)
    for v in terms.values():
        assert torch.all(v > 0) and torch.all(v <= 1.0)
    same, same_terms = fn(ref, ref)
    torch.testing.assert_close(same, torch.ones(4, dtype=F64), atol=1e-6, rtol=0)
    errs = imitation_errors(ref, ref, form)
    for name in ("pos", "vel", "ang_vel"):
        assert torch.equal(errs[name], torch.zeros(4, dtype=F64))


@SETTINGS
@given(seed=seeds, form=st.sampled_from(["paper", "code"]))
def test_imitation_reward_decreases_with_error(seed, form):
    rng = np.random.default_rng(seed)
    ref = random_state(rng, 3, 10)
    direction = random_state(rng, 3, 10)
    fn = ImitationReward(form=form)

    def shifted(scale):
        """Positions and velocities moved away from the reference along a fixed random direction."""
        return dataclasses.replace(
            ref,
            body_pos=ref.body_pos + scale * direction.body_pos,
            body_lin_vel=ref.body_lin_vel + scale * direction.body_lin_vel,
            body_ang_vel=ref.body_ang_vel + scale * direction.body_ang_vel,
        )

    r = [fn(shifted(s), ref)[0] for s in (0.0, 0.01, 0.05, 0.2)]
    for a, b in zip(r, r[1:]):
        assert torch.all(a > b)


def test_reward_forms_match_their_formulas():
    ref = random_state(np.random.default_rng(0), 2, 5)
    sim = perturbed(ref, np.random.default_rng(1), 0.1)
    d = ref.body_pos - sim.body_pos
    paper = imitation_errors(sim, ref, "paper")["pos"]
    code = imitation_errors(sim, ref, "code")["pos"]
    torch.testing.assert_close(paper, d.norm(dim=-1).mean(-1))
    torch.testing.assert_close(code, (d**2).sum((-1, -2)) / (3 * 5))
    total, terms = ImitationReward("code")(sim, ref)
    torch.testing.assert_close(total, 0.5 * terms["pos"] + 0.3 * terms["rot"] + 0.1 * terms["vel"] + 0.1 * terms["ang_vel"])
    torch.testing.assert_close(terms["pos"], torch.exp(-100.0 * code))


@SETTINGS
@given(seed=seeds, form=st.sampled_from(["paper", "code"]), coef=st.floats(0.0, 0.01))
def test_energy_penalty_sign_and_zeros(seed, form, coef):
    rng = np.random.default_rng(seed)
    tau = torch.as_tensor(rng.normal(0, 100, (5, 7)))
    qd = torch.as_tensor(rng.normal(0, 5, (5, 7)))
    e = energy_penalty(tau, qd, form, coef)
    assert torch.all(e <= 0)
    assert torch.equal(energy_penalty(torch.zeros_like(tau), qd, form, coef), torch.zeros(5, dtype=F64))
    assert torch.equal(energy_penalty(tau, torch.zeros_like(qd), form, coef), torch.zeros(5, dtype=F64))
    expect = -coef * ((tau * qd) ** 2).sum(-1) if form == "paper" else -coef * (tau * qd).abs().sum(-1)
    torch.testing.assert_close(e, expect)


def test_energy_code_form_warmup():
    tau, qd = torch.ones(5, 3), torch.ones(5, 3)
    progress = torch.arange(1, 6)
    e = energy_penalty(tau, qd, "code", 0.1, progress)
    assert torch.equal(e[:3], torch.zeros(3)) and torch.all(e[3:] < 0)  # progress_buf <= 3 -> 0
    assert torch.all(energy_penalty(tau, qd, "paper", 0.1, progress) < 0)
    assert torch.equal(energy_penalty(torch.zeros(5, 0), qd, "code"), torch.zeros(5))


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    term=st.sampled_from(["pos", "rot", "vel", "ang_vel"]),
    form=st.sampled_from(["paper", "code"]),
    scales=st.tuples(*[st.floats(0.05, 200.0)] * 4),
)
def test_each_reward_term_responds_to_its_own_quantity_and_scale_alone(seed, term, form, scales):
    """Issue 27 item 11: perturb one quantity alone; only its term drops, to exp(-k e) with e computed
    here from the perturbation (rotation: the angle, both forms), for any of the four scales."""
    from dataclasses import replace as dc_replace

    from mocap.rotations import quat_from_axis_angle, quat_mul

    rng = np.random.default_rng(seed)
    ref = random_state(rng, 3, 5)
    delta = torch.as_tensor(rng.normal(0, 0.2, (3, 5, 3)), dtype=F64)
    if term == "pos":
        sim = dc_replace(ref, body_pos=ref.body_pos + delta)
        norms = delta.norm(dim=-1)
    elif term == "vel":
        sim = dc_replace(ref, body_lin_vel=ref.body_lin_vel + delta)
        norms = delta.norm(dim=-1)
    elif term == "ang_vel":
        sim = dc_replace(ref, body_ang_vel=ref.body_ang_vel + delta)
        norms = delta.norm(dim=-1)
    else:
        angle = torch.as_tensor(rng.uniform(0.05, 2.5, (3, 5)), dtype=F64)
        rot = quat_from_axis_angle(delta / delta.norm(dim=-1, keepdim=True), angle)
        sim = dc_replace(ref, body_rot=quat_mul(rot, ref.body_rot))
        norms = angle
    if form == "paper":
        e = norms.mean(-1)
    else:
        e = norms.square().mean(-1) if term == "rot" else delta.square().mean(dim=(-1, -2))
    reward = ImitationReward(form, (0.5, 0.3, 0.1, 0.1), tuple(scales))
    terms = reward.terms(sim, ref)
    k = dict(zip(("pos", "rot", "vel", "ang_vel"), scales))[term]
    torch.testing.assert_close(terms[term], torch.exp(-k * e), atol=1e-9, rtol=1e-7)
    for other in ("pos", "rot", "vel", "ang_vel"):
        if other != term:
            torch.testing.assert_close(terms[other], torch.ones(3, dtype=F64), atol=1e-9, rtol=0)


@pytest.mark.parametrize("form", ["paper", "code"])
def test_default_reward_pins_each_scale_to_its_term_and_squares_the_code_forms_angles(form):
    """The defaults of PHC's code (PULSE Table 4): weights (0.5, 0.3, 0.1, 0.1) and scales
    (k_p, k_r, k_v, k_w) = (100, 10, 0.1, 0.1), each on its own term; the rotation error of the code
    form is the mean over bodies of the *squared* angle (``compute_imitation_reward``), the paper
    form's the mean angle. Hand numbers: two bodies rotated by 0.2 and 0.6 rad."""
    from dataclasses import replace as dc_replace

    from mocap.rotations import quat_from_axis_angle, quat_mul

    ref = random_state(np.random.default_rng(3), 1, 2)
    angles = torch.tensor([[0.2, 0.6]], dtype=F64)
    turn = quat_from_axis_angle(torch.tensor([[[0.0, 0.0, 1.0]] * 2], dtype=F64), angles)
    offset = torch.tensor([[[0.03, 0.0, 0.04], [0.0, 0.0, 0.0]]], dtype=F64)  # norms 0.05 and 0
    e = {  # per-term errors of the perturbations below
        "pos": 0.025 if form == "paper" else (0.03**2 + 0.04**2) / 6,
        "rot": 0.4 if form == "paper" else (0.2**2 + 0.6**2) / 2,
    }
    e["vel"] = e["ang_vel"] = e["pos"]
    scale = {"pos": 100.0, "rot": 10.0, "vel": 0.1, "ang_vel": 0.1}
    weight = {"pos": 0.5, "rot": 0.3, "vel": 0.1, "ang_vel": 0.1}
    moved = {
        "pos": dc_replace(ref, body_pos=ref.body_pos + offset),
        "rot": dc_replace(ref, body_rot=quat_mul(turn, ref.body_rot)),
        "vel": dc_replace(ref, body_lin_vel=ref.body_lin_vel + offset),
        "ang_vel": dc_replace(ref, body_ang_vel=ref.body_ang_vel + offset),
    }
    fn = ImitationReward(form=form)
    for term, sim in moved.items():
        total, terms = fn(sim, ref)
        expect = math.exp(-scale[term] * e[term])
        assert float(terms[term][0]) == pytest.approx(expect, rel=1e-9), term
        assert float(total[0]) == pytest.approx(1.0 - weight[term] * (1.0 - expect), rel=1e-9), term
