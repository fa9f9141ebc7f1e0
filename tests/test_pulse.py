"""Tests of the ``pulse`` latent space: the math of Eq. 3 (property tests; PULSE Sec. 4.2, Eqs. 2-3), the
networks, the task-side mapping (Eq. 4), the ablation switches, the registry and checkpoints."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

torch.set_num_threads(1)

import mocap_pulse.plugin
from mocap.interfaces import Box
from mocap.state import Observations
from mocap_pulse.latent import GaussianMLP, PulseLatent, PulseParams, make_pulse
from mocap_pulse.losses import (
    action_loss,
    beta_schedule,
    gaussian_kl,
    project_to_sphere,
    reparameterize,
    standard_normal_kl,
    temporal_regularizer,
)

F64 = torch.float64
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
P_DIM, G_DIM, A_DIM = 7, 5, 4


def close(a: torch.Tensor, b: torch.Tensor, rtol: float = 1e-6, atol: float = 1e-8) -> bool:
    return a.shape == b.shape and bool(torch.allclose(a, b, rtol=rtol, atol=atol))


def gaussians(seed: int, n: int, z: int, scale: float = 1.0) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    mu_q = torch.randn(n, z, generator=g, dtype=F64) * scale
    mu_p = torch.randn(n, z, generator=g, dtype=F64) * scale
    lv_q = torch.empty(n, z, dtype=F64).uniform_(-5, 2, generator=g)
    lv_p = torch.empty(n, z, dtype=F64).uniform_(-5, 2, generator=g)
    return mu_q, lv_q, mu_p, lv_p


def tiny(**overrides) -> PulseParams:
    base = dict(latent_dim=3, encoder_hidden=[16], prior_hidden=[16], decoder_hidden=[16], proprio_dim=P_DIM, goal_dim=G_DIM, action_dim=A_DIM)
    return PulseParams(**{**base, **overrides})


def tiny_latent(seed: int = 0, **overrides) -> PulseLatent:
    torch.manual_seed(seed)
    return PulseLatent(tiny(**overrides), P_DIM, G_DIM, A_DIM)


def random_obs(n: int, seed: int = 0, lead: tuple[int, ...] = ()) -> Observations:
    g = torch.Generator().manual_seed(seed)
    return Observations(proprio=torch.randn(*lead, n, P_DIM, generator=g), goal=torch.randn(*lead, n, G_DIM, generator=g))


seeds = st.integers(0, 2**31 - 1)
dims = st.integers(1, 6)


# ------------------------------------------------------------------------------------------ KL
@SETTINGS
@given(seed=seeds, z=dims)
def test_kl_is_nonnegative_and_matches_torch_distributions(seed, z):
    mu_q, lv_q, mu_p, lv_p = gaussians(seed, 8, z)
    kl = gaussian_kl(mu_q, lv_q, mu_p, lv_p)
    assert kl.shape == (8,) and bool((kl >= -1e-12).all())
    q = torch.distributions.Normal(mu_q, torch.exp(0.5 * lv_q))
    p = torch.distributions.Normal(mu_p, torch.exp(0.5 * lv_p))
    ref = torch.distributions.kl_divergence(q, p).sum(-1)
    assert close(kl, ref, rtol=1e-9, atol=1e-9)


@SETTINGS
@given(seed=seeds, z=dims)
def test_kl_is_zero_iff_equal(seed, z):
    mu_q, lv_q, mu_p, lv_p = gaussians(seed, 8, z)
    assert close(gaussian_kl(mu_q, lv_q, mu_q, lv_q), torch.zeros(8, dtype=F64), atol=1e-12)
    differs = ((mu_q - mu_p).abs() > 1e-3).any(-1) | ((lv_q - lv_p).abs() > 1e-3).any(-1)
    assert bool((gaussian_kl(mu_q, lv_q, mu_p, lv_p)[differs] > 0).all())


@SETTINGS
@given(seed=seeds, z=dims)
def test_kl_reduces_to_the_standard_normal_formula_and_is_additive(seed, z):
    mu, lv, mu2, lv2 = gaussians(seed, 8, z)
    zeros = torch.zeros_like(mu)
    assert close(gaussian_kl(mu, lv, zeros, zeros), standard_normal_kl(mu, lv), rtol=1e-10, atol=1e-10)
    assert close(standard_normal_kl(mu, lv), -0.5 * (1 + lv - mu**2 - lv.exp()).sum(-1))
    both = gaussian_kl(torch.cat((mu, mu2), -1), torch.cat((lv, lv2), -1), torch.cat((mu2, mu), -1), torch.cat((lv2, lv), -1))
    assert close(both, gaussian_kl(mu, lv, mu2, lv2) + gaussian_kl(mu2, lv2, mu, lv), rtol=1e-10, atol=1e-10)


def test_kl_is_not_symmetric_and_matches_monte_carlo():
    mu_q, lv_q = torch.tensor([[0.3, -1.0]], dtype=F64), torch.tensor([[-1.0, 0.5]], dtype=F64)
    mu_p, lv_p = torch.tensor([[0.0, 0.5]], dtype=F64), torch.tensor([[0.7, -0.2]], dtype=F64)
    forward, backward = gaussian_kl(mu_q, lv_q, mu_p, lv_p), gaussian_kl(mu_p, lv_p, mu_q, lv_q)
    assert abs(float(forward - backward)) > 0.1
    g = torch.Generator().manual_seed(0)
    z = reparameterize(mu_q.expand(200_000, 2), lv_q.expand(200_000, 2), torch.randn(200_000, 2, generator=g, dtype=F64))
    q = torch.distributions.Normal(mu_q, torch.exp(0.5 * lv_q))
    p = torch.distributions.Normal(mu_p, torch.exp(0.5 * lv_p))
    mc = (q.log_prob(z) - p.log_prob(z)).sum(-1).mean()
    assert abs(float(mc - forward)) < 0.02 * max(1.0, float(forward))


def test_logvar_clamp_keeps_kl_finite():
    net = GaussianMLP(4, [8], 3, "silu", (-5.0, 2.0))
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.Linear):
                m.weight.fill_(100.0)
    for sign in (1.0, -1.0):
        mu, lv = net(sign * torch.full((2, 4), 10.0))
        assert bool(((lv >= -5.0) & (lv <= 2.0)).all())
        assert bool(torch.isfinite(gaussian_kl(mu, lv, torch.zeros_like(mu), torch.full_like(lv, -5.0))).all())


# --------------------------------------------------------------------------- reparameterization
@SETTINGS
@given(seed=seeds, z=dims)
def test_reparameterization_with_zero_noise_is_the_mean(seed, z):
    mu, lv, _, _ = gaussians(seed, 4, z)
    assert torch.equal(reparameterize(mu, lv, torch.zeros_like(mu)), mu)


def test_reparameterization_moments_and_gradients():
    mu = torch.tensor([0.5, -2.0], dtype=F64, requires_grad=True)
    lv = torch.tensor([-1.0, 1.0], dtype=F64, requires_grad=True)
    torch.manual_seed(0)
    z = reparameterize(mu.expand(100_000, 2), lv.expand(100_000, 2))
    assert close(z.mean(0), mu.detach(), atol=0.02)
    assert close(z.var(0), lv.detach().exp(), rtol=0.03)
    z.sum().backward()
    assert mu.grad is not None and lv.grad is not None and bool(torch.isfinite(lv.grad).all())


# ------------------------------------------------------------------------------------- L_regu
sequences = st.tuples(st.integers(2, 8), st.integers(1, 3), dims, seeds)


@SETTINGS
@given(shape=sequences)
def test_regularizer_is_zero_for_constant_or_ar1_sequences_and_nonnegative(shape):
    T, N, Z, seed = shape
    g = torch.Generator().manual_seed(seed)
    starts = torch.rand(T, N, generator=g) < 0.3
    mu0 = torch.randn(N, Z, generator=g, dtype=F64)
    const = mu0.expand(T, N, Z)
    assert float(temporal_regularizer(const, starts, "paper")) == 0.0
    ar1 = torch.stack([mu0 * 0.99**t for t in range(T)])
    assert float(temporal_regularizer(ar1, starts, "code", 0.99)) < 1e-5
    rand = torch.randn(T, N, Z, generator=g, dtype=F64)
    for form in ("paper", "code"):
        assert float(temporal_regularizer(rand, starts, form)) >= 0.0


@SETTINGS
@given(t1=st.integers(1, 6), t2=st.integers(1, 6), z=dims, seed=seeds, form=st.sampled_from(["paper", "code"]))
def test_regularizer_ignores_pairs_across_episode_starts(t1, t2, z, seed, form):
    """Two episodes in one column: swapping their order (each keeping its start flag) or shifting
    the second by a constant (paper form) leaves L_regu unchanged; so does anything at a start."""
    g = torch.Generator().manual_seed(seed)
    a, b = torch.randn(t1, 1, z, generator=g, dtype=F64), torch.randn(t2, 1, z, generator=g, dtype=F64)
    sa, sb = torch.zeros(t1, 1, dtype=torch.bool), torch.zeros(t2, 1, dtype=torch.bool)
    sa[0] = sb[0] = True
    ab = temporal_regularizer(torch.cat((a, b)), torch.cat((sa, sb)), form)
    ba = temporal_regularizer(torch.cat((b, a)), torch.cat((sb, sa)), form)
    assert close(ab, ba, rtol=1e-9, atol=1e-12)
    if form == "paper":
        shifted = temporal_regularizer(torch.cat((a, b + 7.0)), torch.cat((sa, sb)), form)
        assert close(ab, shifted, rtol=1e-9, atol=1e-12)
    all_starts = torch.ones(t1 + t2, 1, dtype=torch.bool)
    assert float(temporal_regularizer(torch.cat((a, b)), all_starts, form)) == 0.0


def test_regularizer_forms_match_their_formulas():
    mu = torch.tensor([[[1.0, 0.0]], [[1.0, 2.0]], [[0.0, 2.0]]], dtype=F64)
    starts = torch.zeros(3, 1, dtype=torch.bool)
    assert close(temporal_regularizer(mu, starts, "paper"), torch.tensor(2.5, dtype=F64))  # (4 + 1) / 2
    expected = (torch.tensor([0.01, 2.0], dtype=F64).norm() + torch.tensor([-0.99, 2 - 1.98], dtype=F64).norm()) / 2
    assert close(temporal_regularizer(mu, starts, "code", 0.99), expected)


# ------------------------------------------------------------------------------------- L_action
@SETTINGS
@given(seed=seeds, z=dims, form=st.sampled_from(["paper", "code"]))
def test_action_loss_zero_iff_identical_and_symmetric(seed, z, form):
    a, _, b, _ = gaussians(seed, 5, z)
    assert float(action_loss(a, a, form)) < 1e-5
    assert close(action_loss(a, b, form), action_loss(b, a, form))
    if not torch.equal(a, b):
        assert float(action_loss(a, b, form)) > 0
    expected = (a - b).square().sum(-1) if form == "paper" else (a - b).norm(dim=-1)
    assert close(action_loss(a, b, form), expected.mean(), rtol=1e-6)


# -------------------------------------------------------------------------------------- β schedule
@SETTINGS
@given(
    w=st.tuples(st.floats(0, 0.9), st.floats(0.01, 1.0)).filter(lambda w: w[0] < w[1]),
    x=st.floats(0, 1),
    y=st.floats(0, 1),
)
def test_beta_schedule_endpoints_monotone_continuous(w, x, y):
    a, b = w
    assert beta_schedule(0.0, 0.01, 0.001, w) == 0.01
    assert beta_schedule(a, 0.01, 0.001, w) == pytest.approx(0.01)
    assert beta_schedule(b, 0.01, 0.001, w) == pytest.approx(0.001)
    assert beta_schedule(1.0, 0.01, 0.001, w) == pytest.approx(0.001)
    lo, hi = min(x, y), max(x, y)
    assert beta_schedule(lo, 0.01, 0.001, w) >= beta_schedule(hi, 0.01, 0.001, w) - 1e-15
    assert 0.001 - 1e-15 <= beta_schedule(x, 0.01, 0.001, w) <= 0.01 + 1e-15
    # continuity at both ends of the window (Lipschitz with slope (0.01 - 0.001) / (b - a))
    eps = 1e-9
    for edge in (a, b):
        assert abs(beta_schedule(edge + eps, 0.01, 0.001, w) - beta_schedule(edge - eps, 0.01, 0.001, w)) <= 0.009 * 2 * eps / (b - a) + 1e-15


def test_beta_default_window_matches_the_code_epochs():
    p = PulseParams()
    assert (p.beta_start, p.beta_end) == (0.01, 0.001)
    assert beta_schedule(2500 / 10170, *(p.beta_start, p.beta_end), p.beta_anneal) == pytest.approx(0.01, rel=0.02)
    assert beta_schedule(0.375, p.beta_start, p.beta_end, p.beta_anneal) == pytest.approx(0.0055)


# ----------------------------------------------------------------------------- the latent space
def test_shapes_sampling_and_losses():
    lat = tiny_latent()
    obs = random_obs(6)
    enc = lat.encoder(obs)
    assert enc.mean.shape == enc.std.shape == enc.z.shape == (6, 3) and torch.equal(enc.z, enc.mean)
    assert not torch.equal(lat.encoder(obs, sample=True).z, enc.mean)
    prior = lat.prior(obs)
    assert prior.mean.shape == (6, 3) and bool((prior.std > 0).all())
    assert torch.equal(lat.student_action(obs, sample=False), lat.decode_action(obs, enc.mean))
    assert lat.student_action(obs).shape == (6, A_DIM)
    seq = random_obs(4, lead=(5,))  # (T, N, ...)
    assert lat.student_action(seq, sample=False).shape == (5, 4, A_DIM)
    starts = torch.zeros(5, 4, dtype=torch.bool)
    starts[0] = True
    losses = lat.distill_losses(seq, torch.randn(5, 4, A_DIM), starts, progress=0.0)
    assert {"loss", "action", "regu", "kl", "beta"} <= set(losses) and float(losses["beta"]) == pytest.approx(0.01)
    assert all(bool(torch.isfinite(v).all()) for v in losses.values())
    losses["loss"].backward()
    for name, net in (("enc", lat.enc), ("pri", lat.pri), ("dec", lat.dec)):
        grads = [q.grad for q in net.parameters()]
        assert all(g is not None for g in grads) and any(float(g.abs().sum()) > 0 for g in grads), name
    expected = losses["action"] + 0.005 * losses["regu"] + 0.01 * losses["kl"]
    assert float(losses["loss"].detach()) == pytest.approx(float(expected), rel=1e-5)


def test_zero_residual_decodes_the_prior_mean_and_residual_is_linear():
    lat = tiny_latent(1)
    obs = random_obs(5, seed=2)
    mu_p = lat.prior(obs).mean
    zero = torch.zeros(5, 3)
    assert torch.equal(lat.to_latent(obs, zero), mu_p)
    assert torch.equal(lat.decode_action(obs, lat.to_latent(obs, zero)), lat.decode_action(obs, mu_p))
    r1, r2 = torch.randn(5, 3), torch.randn(5, 3)
    assert close(lat.to_latent(obs, r1 + r2) - mu_p, r1 + r2, atol=1e-6)
    assert lat.task_action_space == Box((3,), exploration_sigma=0.22)
    # PPO's Gaussian starts at that sigma when the spec leaves log_std_init unset (issue 27 item 8: it was dead)
    from mocap.rl.ppo import initial_log_std

    assert initial_log_std(None, lat.task_action_space) == pytest.approx(math.log(0.22))
    assert initial_log_std(-2.0, lat.task_action_space) == -2.0
    assert initial_log_std(None, Box((3,))) == -1.2
    absolute = tiny_latent(1, task_action="absolute")
    assert torch.equal(absolute.to_latent(obs, r1), r1)
    standard = tiny_latent(1, prior="standard")
    assert standard.pri is None and torch.equal(standard.to_latent(obs, r1), r1)
    assert torch.equal(standard.prior(obs).mean, torch.zeros(5, 3)) and torch.equal(standard.prior(obs).std, torch.ones(5, 3))


def test_standard_prior_uses_the_standard_normal_kl():
    lat = tiny_latent(2, prior="standard")
    obs = random_obs(3, lead=(2,))
    torch.manual_seed(0)
    out = lat.distill_losses(obs, torch.zeros(2, 3, A_DIM), torch.ones(2, 3, dtype=torch.bool), 1.0)
    with torch.no_grad():
        p, g, _ = lat._inputs(obs)
        mu, lv = lat._posterior(p, g)
    assert float(out["kl"].detach()) == pytest.approx(float(standard_normal_kl(mu, lv).mean()), rel=1e-5)
    assert float(out["regu"]) == 0.0 and float(out["beta"]) == pytest.approx(0.001)


def test_sphere_variant_and_prior_sampling():
    lat = tiny_latent(3, latent_kind="sphere")
    obs = random_obs(4)
    for z in (lat.encoder(obs, sample=True).z, lat.to_latent(obs, torch.randn(4, 3)), lat.sample_prior(obs)):
        assert close(z.norm(dim=-1), torch.ones(4), atol=1e-5)
    gauss = tiny_latent(3)
    assert torch.equal(gauss.sample_prior(obs, noise_scale=0.0), gauss.prior(obs).mean)
    g1, g2 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    assert torch.equal(gauss.random_action(obs, 0.5, g1), gauss.random_action(obs, 0.5, g2))
    assert close(project_to_sphere(torch.tensor([[3.0, 4.0]])), torch.tensor([[0.6, 0.8]]))


def test_decoder_maps_through_the_attached_imitator():
    lat = tiny_latent()
    obs = random_obs(2)
    z = torch.zeros(2, 3)
    with pytest.raises(RuntimeError, match="attach_imitator"):
        lat.decoder(obs, z)

    class Teacher:
        def to_pd_targets(self, obs, out):
            return 2.0 * out + 1.0

    lat.attach_imitator(Teacher())  # type: ignore[arg-type]
    assert torch.equal(lat.decoder(obs, z), 2.0 * lat.decode_action(obs, z) + 1.0)


def test_normalizers_running_teacher_and_none():
    from mocap.rl.normalizer import RunningNormalizer

    lat = tiny_latent()
    obs = random_obs(50, seed=3)
    lat.update_normalizers(Observations(proprio=obs.proprio * 3 + 1, goal=obs.goal))
    assert float(lat.proprio_norm.count) == 50 and float(lat.proprio_norm.mean.mean()) == pytest.approx(1.0, abs=0.5)

    class Policy:
        obs_norm = RunningNormalizer((P_DIM + G_DIM,))

    class Teacher:
        policy = Policy()

    Teacher.policy.obs_norm.update(torch.randn(100, P_DIM + G_DIM, dtype=F64) * 2 + 3)
    frozen = tiny_latent(normalizer="teacher")
    frozen.init_from_teacher(Teacher())
    assert torch.equal(frozen.proprio_norm.mean, Teacher.policy.obs_norm.mean[:P_DIM])
    assert torch.equal(frozen.goal_norm.var, Teacher.policy.obs_norm.var[P_DIM:])
    before = frozen.proprio_norm.mean.clone()
    frozen.update_normalizers(obs)
    assert torch.equal(frozen.proprio_norm.mean, before) and frozen.proprio_norm.frozen
    with pytest.raises(ValueError, match="normalizer='running'"):
        tiny_latent(normalizer="teacher").init_from_teacher(type("NoPolicy", (), {"policy": None})())  # Imitator.policy default
    raw = tiny_latent(normalizer="none")
    raw.update_normalizers(obs)
    assert float(raw.proprio_norm.count) == 0


def test_params_validation_and_refusals():
    # the RL term and the VQ latent are built (tests/test_pulse_ablations.py); their bad combinations are refused
    assert PulseParams(rl_term=True).rl_term and PulseParams(latent_kind="vq", latent_dim=64).latent_kind == "vq"
    with pytest.raises(ValidationError, match="vq_partitions"):
        PulseParams(latent_kind="vq", latent_dim=32, vq_partitions=5)
    with pytest.raises(ValidationError, match="beta_anneal"):
        PulseParams(beta_anneal=(0.6, 0.5))
    with pytest.raises(ValidationError):
        PulseParams(bogus=1)
    for name, field in PulseParams.model_fields.items():
        assert field.description, name


def test_registry_dims_and_checkpoint_round_trip(amp, tmp_path):
    from mocap.distill_files import save_latent
    from mocap.testing import use_plugins

    with use_plugins(("latent_pulse", mocap_pulse.plugin)) as pset:
        comp = pset.get("latent", "pulse")
        small = {"latent_dim": 4, "encoder_hidden": [8], "prior_hidden": [8], "decoder_hidden": [8]}
        lat = comp.build(small, skeleton=amp)
    assert isinstance(lat, PulseLatent)
    assert (lat.proprio_dim, lat.goal_dim, lat.action_dim) == (15 * amp.num_bodies - 2, 24 * amp.num_bodies, amp.num_dofs)
    assert make_pulse(PulseParams(**small, goal_obs="keypoint"), skeleton=amp).goal_dim == 9 * amp.num_bodies
    lat.proprio_norm.update(torch.randn(10, lat.proprio_dim))
    save_latent(tmp_path / "latent.pt", lat)
    loaded = make_pulse(PulseParams(**small, alpha=0.1), skeleton=amp, checkpoint=tmp_path / "latent.pt")  # loss params may differ
    assert not loaded.training
    for (k, a), (_, b) in zip(lat.state_dict().items(), loaded.state_dict().items()):
        if isinstance(a, torch.Tensor):
            assert torch.equal(a, b), k
    with pytest.raises(ValueError, match="latent_dim"):
        make_pulse(PulseParams(**{**small, "latent_dim": 5}), skeleton=amp, checkpoint=tmp_path / "latent.pt")


def test_distillation_kl_is_the_posterior_to_prior_kl_at_the_call_site():
    """Issue 27 item 11: the loss's KL term equals KL(posterior || prior) written out here (the
    direction of Eq. 3), not the reverse."""
    lat = tiny_latent(2)
    obs = random_obs(6, seed=4)
    starts = torch.zeros(3, 2, dtype=torch.bool)
    starts[0] = True
    out = lat.distill_losses(obs, torch.randn(6, A_DIM), starts, progress=0.0)
    p, g, _ = lat._inputs(obs)
    mu_q, lv_q = lat._posterior(p, g)
    mu_p, lv_p = lat._prior(p)
    forward = 0.5 * (lv_p - lv_q + (lv_q.exp() + (mu_q - mu_p) ** 2) / lv_p.exp() - 1.0).sum(-1).mean()
    reverse = 0.5 * (lv_q - lv_p + (lv_p.exp() + (mu_q - mu_p) ** 2) / lv_q.exp() - 1.0).sum(-1).mean()
    assert torch.allclose(out["kl"], forward.detach(), rtol=1e-5, atol=1e-6)
    assert not torch.allclose(forward, reverse, rtol=1e-3)


@settings(max_examples=30, deadline=None)
@given(seed=seeds, T=st.integers(2, 6), N=st.integers(1, 4), form=st.sampled_from(["paper", "code"]))
def test_regularizer_is_the_mean_over_valid_pairs_only(seed, T, N, form):
    """L_regu averages over the pairs that do not cross an episode start: adding starts removes
    exactly those pairs from both the sum and the count."""
    from mocap_pulse.losses import temporal_regularizer

    g = torch.Generator().manual_seed(seed)
    mu = torch.randn(T, N, 3, generator=g, dtype=F64)
    starts = torch.rand(T, N, generator=g) < 0.4
    diff = mu[1:] - (mu[:-1] if form == "paper" else 0.99 * mu[:-1])
    per = diff.square().sum(-1) if form == "paper" else diff.square().sum(-1).add(1e-12).sqrt()
    valid = ~starts[1:]
    expect = per[valid].mean() if bool(valid.any()) else torch.zeros((), dtype=F64)
    assert torch.allclose(temporal_regularizer(mu, starts, form), expect, atol=1e-12)
