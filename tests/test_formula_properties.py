"""Properties that pin formulas directly (issue 27 item 11): each fails for the small faults an
audit injected (a wrong root body, masked frames that leak into a mean, a reflection accepted by
Procrustes, a PPO clip on the wrong side, a KL annealing peak in the wrong place)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap.metrics import acceleration_error, mpjpe_global, mpjpe_local, pa_mpjpe, procrustes_align, velocity_error
from mocap.state import Trajectories

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 2**32 - 1)
F64 = torch.float64


def _tr(rng: np.random.Generator, T: int, N: int, B: int, mask=None) -> Trajectories:
    sim = torch.as_tensor(rng.normal(0, 0.5, (T, N, B, 3)), dtype=F64)
    ref = torch.as_tensor(rng.normal(0, 0.5, (T, N, B, 3)), dtype=F64)
    return Trajectories(sim=sim, ref=ref, fps=30.0, mask=mask)


# ------------------------------------------------------------------------------------ MPJPE
@SETTINGS
@given(seed=seeds, B=st.integers(2, 8))
def test_mpjpe_l_equals_mpjpe_g_when_the_roots_coincide(seed, B):
    """Root-relative error subtracts body 0 of each side: with equal roots it is the global error,
    and with another body as root it would not be."""
    rng = np.random.default_rng(seed)
    tr = _tr(rng, 6, 3, B)
    tr.ref[..., 0, :] = tr.sim[..., 0, :]
    torch.testing.assert_close(mpjpe_local(tr), mpjpe_global(tr), atol=1e-9, rtol=0)


@SETTINGS
@given(seed=seeds, extra=st.integers(1, 5))
def test_masked_out_frames_change_no_metric(seed, extra):
    """Frames after an episode's end (mask False) with arbitrary, non-zero error leave every metric unchanged."""
    rng = np.random.default_rng(seed)
    T, N, B = 7, 3, 5
    tr = _tr(rng, T, N, B)
    more = _tr(rng, T + extra, N, B)
    more.sim[:T], more.ref[:T] = tr.sim, tr.ref
    more.ref[T:] += 10.0  # large errors in the masked-out tail
    mask = torch.zeros(T + extra, N, dtype=torch.bool)
    mask[:T] = True
    more = Trajectories(more.sim, more.ref, 30.0, mask)
    for fn in (mpjpe_global, mpjpe_local, pa_mpjpe, velocity_error, acceleration_error):
        torch.testing.assert_close(fn(more), fn(tr), atol=1e-9, rtol=0, msg=fn.__name__)


@SETTINGS
@given(seed=seeds, hole=st.integers(1, 5))
def test_velocity_and_acceleration_skip_pairs_touching_a_hole(seed, hole):
    """A hole in the middle of the mask: only frame pairs (triples) that are all valid count."""
    rng = np.random.default_rng(seed)
    T = 8
    tr = _tr(rng, T, 1, 4)
    mask = torch.ones(T, 1, dtype=torch.bool)
    mask[hole] = False
    trm = Trajectories(tr.sim, tr.ref, 30.0, mask)
    dv = (tr.sim[1:] - tr.sim[:-1]) - (tr.ref[1:] - tr.ref[:-1])
    per = torch.linalg.vector_norm(dv, dim=-1).mean(-1)[:, 0]
    keep = [t for t in range(T - 1) if t != hole and t + 1 != hole]
    assert float(velocity_error(trm)[0]) == pytest.approx(1000.0 * float(per[keep].mean()))

    def acc(p):
        return p[:-2] - 2 * p[1:-1] + p[2:]

    pa = torch.linalg.vector_norm(acc(tr.sim) - acc(tr.ref), dim=-1).mean(-1)[:, 0]
    keep3 = [t for t in range(T - 2) if hole not in (t, t + 1, t + 2)]
    assert float(acceleration_error(trm)[0]) == pytest.approx(1000.0 * float(pa[keep3].mean()))


@SETTINGS
@given(seed=seeds, B=st.integers(4, 10))
def test_procrustes_never_aligns_by_a_reflection(seed, B):
    """A mirrored (chiral) pose cannot be matched by a proper rotation: PA-MPJPE > 0, and the map
    found is a rotation with det +1 (its action on the centred points preserves orientation)."""
    rng = np.random.default_rng(seed)
    x = torch.as_tensor(rng.normal(0, 0.5, (B, 3)), dtype=F64)
    mirrored = x * torch.tensor([-1.0, 1.0, 1.0], dtype=F64)
    xc = x - x.mean(0)
    if torch.linalg.matrix_rank(xc) < 3:
        return
    aligned = procrustes_align(x, mirrored)
    err = torch.linalg.vector_norm(aligned - mirrored, dim=-1).mean()
    assert float(err) > 1e-6
    # recover the linear map from the centred points: A = pinv(xc) (aligned - mean)
    ac = aligned - aligned.mean(0)
    lin = torch.linalg.lstsq(xc, ac).solution  # xc @ lin = ac, lin = s R^T
    assert float(torch.linalg.det(lin)) > 0
    # a proper rigid motion of x itself is aligned exactly
    th = 0.7
    rot = torch.tensor([[math.cos(th), -math.sin(th), 0.0], [math.sin(th), math.cos(th), 0.0], [0.0, 0.0, 1.0]], dtype=F64)
    moved = x @ rot.T * 1.3 + torch.tensor([0.2, -0.1, 0.5], dtype=F64)
    torch.testing.assert_close(procrustes_align(x, moved), moved, atol=1e-9, rtol=0)


# -------------------------------------------------------------------------------------- PPO
@SETTINGS
@given(adv=st.floats(-10.0, -1e-3), eps=st.floats(0.05, 0.4), r=st.floats(0.01, 3.0))
def test_clipped_surrogate_for_negative_advantages(adv, eps, r):
    """A < 0: L = (1 - eps) A and flat in r below 1 - eps; r A (unclipped) above 1 + eps."""
    from mocap.rl.ppo import clipped_surrogate

    ratio = torch.tensor([r], dtype=F64, requires_grad=True)
    a = torch.tensor([adv], dtype=F64)
    out = clipped_surrogate(ratio, a, eps)
    out.sum().backward()
    assert ratio.grad is not None
    if r < 1 - eps:
        assert float(out) == pytest.approx((1 - eps) * adv)
        assert float(ratio.grad) == 0.0
    elif r > 1 + eps:
        assert float(out) == pytest.approx(r * adv)
        assert float(ratio.grad) == pytest.approx(adv)
    else:
        assert float(out) == pytest.approx(r * adv)


def test_an_update_with_all_advantages_equal_stays_finite():
    from mocap.interfaces import Box
    from mocap.rl.ppo import PPOParams, PPOTrainer

    torch.manual_seed(0)
    trainer = PPOTrainer(PPOParams(num_envs=4, horizon=8, minibatch_size=16, epochs=2, torch_threads=1))
    model = trainer.build_model(5, Box((2,)))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    obs = torch.randn(8, 4, 5)
    with torch.no_grad():
        act, logp, val = model.act(obs.reshape(32, 5))
    adv = torch.full((8, 4), 0.7)
    stats = trainer._update(model, opt, obs, act.reshape(8, 4, 2), logp.reshape(8, 4), val.reshape(8, 4), adv, adv + val.reshape(8, 4))
    assert stats and all(math.isfinite(v) for v in stats.values())
    assert all(bool(torch.isfinite(p).all()) for p in model.parameters())


# ------------------------------------------------------------------------------------- VMP
@SETTINGS
@given(ratio=st.floats(0.1, 0.9), cycles=st.integers(1, 5), beta=st.floats(0.01, 2.0))
def test_cyclical_beta_peaks_exactly_at_the_ratio(ratio, cycles, beta):
    """Fu et al. 2019: beta ramps linearly from 0 at each cycle's start to beta at tau = ratio, then holds."""
    from mocap_vmp.vae import cyclical_beta

    total = 1000 * cycles
    period = total // cycles
    for c in range(cycles):
        start = c * period
        assert cyclical_beta(start, total, beta, cycles, ratio) == 0.0
        peak = start + math.ceil(ratio * period)
        assert cyclical_beta(peak, total, beta, cycles, ratio) == pytest.approx(beta)
        before = start + int(ratio * period * 0.5)
        assert cyclical_beta(before, total, beta, cycles, ratio) == pytest.approx(beta * ((before - start) / period) / ratio)
        assert cyclical_beta(start + period - 1, total, beta, cycles, ratio) == pytest.approx(beta)


@SETTINGS
@given(seed=seeds, rows=st.integers(2, 9), d=st.integers(1, 6))
def test_vmp_kl_is_the_batch_mean_of_per_row_kls(seed, rows, d):
    from mocap_vmp.vae import kl_divergence

    g = torch.Generator().manual_seed(seed)
    mu = torch.randn(rows, d, generator=g, dtype=F64)
    lv = torch.empty(rows, d, dtype=F64).uniform_(-3, 2, generator=g)
    per_row = [0.5 * float((mu[i] ** 2 + lv[i].exp() - lv[i] - 1).sum()) for i in range(rows)]
    assert float(kl_divergence(mu, lv)) == pytest.approx(sum(per_row) / rows, rel=1e-12)


def test_vmp_vae_samples_with_std_exp_half_logvar(monkeypatch):
    """forward(sample=True) draws z = mu + exp(logvar / 2) eps: the sample moments match (4000 draws)."""
    from mocap_vmp.vae import MotionVAE

    torch.manual_seed(0)
    vae = MotionVAE(feature_dim=4, window=8, latent_dim=3, channels=8, res_blocks=1, downsample=1)
    x = torch.randn(1, 8, 4).expand(4000, 8, 4).contiguous()
    seen: list[torch.Tensor] = []
    monkeypatch.setattr(vae, "decode", lambda z: seen.append(z.detach()) or torch.zeros(z.shape[0], 8, 4))
    with torch.no_grad():
        _, mu, logvar = vae(x, sample=True)
    z = seen[0]
    torch.testing.assert_close(z.mean(0), mu[0], atol=0.1 * float(torch.exp(0.5 * logvar[0]).max()), rtol=0)
    torch.testing.assert_close(z.std(0), torch.exp(0.5 * logvar[0]), rtol=0.08, atol=0)
    with torch.no_grad():
        vae(x[:2], sample=False)
    torch.testing.assert_close(seen[1], mu[:2])
