"""Properties of the Hybrid-RVQ latent space (paper Sec. 4.1-4.3, Alg. 1, Eqs. 5-6): quantizers, the
Marginal Quantization composer, the loss terms and their stop-gradients, the task side, checkpoints."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.interfaces import Box, MultiDiscrete
from mocap.state import Observations
from mocap_hybrid_rvq import plugin as hybrid_plugin
from mocap_hybrid_rvq.model import (
    HybridLatent,
    HybridParams,
    gaussian_kl,
    make_hybrid,
    marginal_quantize,
    mm_loss,
    ramp,
    save_hybrid,
    temporal_reg,
)
from mocap.quantizers import ResidualVQ, VectorQuantizer

FAST = settings(max_examples=25, deadline=None, derandomize=True)
P, G, A, D = 5, 4, 3, 4


def rvq_with_codes(n: int, k: int, d: int, seed: int, zero_code: bool = False, **kw) -> ResidualVQ:  # type: ignore[no-untyped-def]
    gen = torch.Generator().manual_seed(seed)
    q = ResidualVQ(d, n, k, **kw).double()
    for lvl, level in enumerate(q.levels):
        codes = torch.randn(k, d, generator=gen, dtype=torch.float64) / (lvl + 1)
        if zero_code:
            codes[0] = 0.0
        level.set_codebook(codes)
    return q


def batch(b: int, d: int, seed: int) -> torch.Tensor:
    return torch.randn(b, d, generator=torch.Generator().manual_seed(seed + 1000), dtype=torch.float64)


sizes = st.tuples(
    st.integers(1, 32),  # B
    st.integers(1, 8),  # D
    st.integers(1, 16),  # K
    st.integers(1, 5),  # N
    st.integers(0, 2**16),  # seed
)


# ------------------------------------------------------------------------------------ quantizers
@FAST
@given(sizes)
def test_eval_output_equals_decoded_indices_and_indices_in_range(args) -> None:  # type: ignore[no-untyped-def]
    b, d, k, n, seed = args
    q = rvq_with_codes(n, k, d, seed).eval()
    x = batch(b, d, seed)
    out = q(x)
    assert out.indices.shape == (b, n) and out.indices.dtype == torch.long
    assert bool(((out.indices >= 0) & (out.indices < k)).all())
    torch.testing.assert_close(out.quantized, q.decode(out.indices), rtol=0, atol=1e-12)
    # reconstruction identity: Σ_n B_n[k_n]
    manual = sum(q.codebooks[i][out.indices[:, i]] for i in range(n))
    torch.testing.assert_close(out.quantized, manual)
    # n_active = m: levels > m report -1 and the output is the m-level reconstruction
    m = seed % (n + 1)
    part = q(x, n_active=m)
    assert bool((part.indices[:, m:] == -1).all())
    torch.testing.assert_close(part.indices[:, :m], out.indices[:, :m])
    torch.testing.assert_close(part.quantized, q.decode(part.indices[:, :m]), rtol=0, atol=1e-12)


@FAST
@given(sizes)
def test_greedy_choice_is_nearest_code_per_level(args) -> None:  # type: ignore[no-untyped-def]
    b, d, k, n, seed = args
    q = rvq_with_codes(n, k, d, seed).eval()
    x = batch(b, d, seed)
    idx = q(x).indices
    r = x
    for lvl in range(n):
        dist = (r.unsqueeze(1) - q.codebooks[lvl].unsqueeze(0)).square().sum(-1)  # (B, K) brute force
        chosen = dist.gather(1, idx[:, lvl : lvl + 1]).squeeze(1)
        assert bool((chosen <= dist.min(1).values + 1e-9).all())
        r = r - q.codebooks[lvl][idx[:, lvl]]


@FAST
@given(sizes)
def test_residual_norms_non_increasing_with_zero_code(args) -> None:  # type: ignore[no-untyped-def]
    b, d, k, n, seed = args
    q = rvq_with_codes(n, k, d, seed, zero_code=True).eval()
    x = batch(b, d, seed)
    idx = q(x).indices
    norms = [(x - q.decode(idx[:, :m])).norm(dim=-1) for m in range(n + 1)]
    for prev, cur in itertools.pairwise(norms):
        assert bool((cur <= prev + 1e-9).all())


def test_residual_norms_can_grow_without_zero_code() -> None:
    """The unconditional version of the previous property is false: Eq. 5's greedy residuals can grow
    (our note; the paper states no such property)."""
    q = ResidualVQ(1, 2, 1).double().eval()
    q.levels[0].set_codebook(torch.tensor([[1.0]], dtype=torch.float64))
    q.levels[1].set_codebook(torch.tensor([[5.0]], dtype=torch.float64))
    x = torch.tensor([[1.0]], dtype=torch.float64)
    idx = q(x).indices
    assert (x - q.decode(idx)).norm() > (x - q.decode(idx[:, :1])).norm()


@FAST
@given(sizes, st.booleans())
def test_straight_through_gradient_is_identity(args, train) -> None:  # type: ignore[no-untyped-def]
    b, d, k, n, seed = args
    q = rvq_with_codes(n, k, d, seed)
    x = batch(b, d, seed).requires_grad_(True)
    w = batch(b, d, seed + 7)
    out = q(x, train=train)
    (w * out.quantized).sum().backward()
    assert torch.equal(x.grad, w)
    assert all(not buf.requires_grad for buf in q.buffers())
    assert not any(True for _ in q.parameters())  # EMA codebooks are buffers: no gradient path


@FAST
@given(sizes)
def test_commitment_formulas(args) -> None:  # type: ignore[no-untyped-def]
    b, d, k, n, seed = args
    x = batch(b, d, seed).requires_grad_(True)
    q = rvq_with_codes(n, k, d, seed, commitment="per_level").eval()
    out = q(x)
    residuals = [x.detach() - q.decode(out.indices[:, :m]) for m in range(1, n + 1)]  # r_1 .. r_N
    expected = sum(r.square().mean() for r in residuals)
    torch.testing.assert_close(out.losses["commit"], expected)
    assert float(out.losses["commit"].detach()) >= 0.0
    out.losses["commit"].backward()
    torch.testing.assert_close(x.grad, 2.0 / x.numel() * sum(residuals))
    q_total = rvq_with_codes(n, k, d, seed, commitment="total").eval()
    out_t = q_total(x.detach())
    torch.testing.assert_close(out_t.losses["commit"], (x.detach() - out_t.quantized).square().mean())


def _seeded_vq(k: int, d: int, seed: int, threshold: float, decay: float = 0.9) -> VectorQuantizer:
    gen = torch.Generator().manual_seed(seed)
    vq = VectorQuantizer(d, k, decay=decay, dead_threshold=threshold).double()
    vq.set_codebook(torch.randn(k, d, generator=gen, dtype=torch.float64))
    sizes_ = torch.rand(k, generator=gen, dtype=torch.float64) * 5 + 0.5
    vq.cluster_size.copy_(sizes_)
    vq.embed_sum.copy_(vq.embed * sizes_.unsqueeze(-1))
    return vq


@FAST
@given(sizes, st.floats(0.5, 0.999))
def test_ema_update_is_a_convex_combination(args, decay) -> None:  # type: ignore[no-untyped-def]
    b, d, k, _, seed = args
    vq = _seeded_vq(k, d, seed, threshold=0.0, decay=decay)
    x = batch(b, d, seed)
    cs0, es0, old_mean = vq.cluster_size.clone(), vq.embed_sum.clone(), vq.embed_sum / vq.cluster_size.unsqueeze(-1)
    idx = vq(x, train=True).indices[:, 0]
    counts = torch.bincount(idx, minlength=k).double()
    sums = torch.zeros(k, d, dtype=torch.float64).index_add_(0, idx, x)
    torch.testing.assert_close(vq.cluster_size, decay * cs0 + (1 - decay) * counts)
    torch.testing.assert_close(vq.embed_sum, decay * es0 + (1 - decay) * sums)
    # the unsmoothed code m_k / N_k is a convex combination of the old code and the batch mean
    used = counts > 0
    w = (decay * cs0 / (decay * cs0 + (1 - decay) * counts))[used].unsqueeze(-1)
    assert bool(((w >= 0) & (w <= 1)).all())
    batch_mean = sums[used] / counts[used].unsqueeze(-1)
    torch.testing.assert_close((vq.embed_sum / vq.cluster_size.unsqueeze(-1))[used], w * old_mean[used] + (1 - w) * batch_mean)
    # Laplace-smoothed codes
    total = vq.cluster_size.sum()
    smoothed = (vq.cluster_size + vq.eps) / (total + k * vq.eps) * total
    torch.testing.assert_close(vq.embed, vq.embed_sum / smoothed.unsqueeze(-1))


@FAST
@given(sizes, st.floats(0.5, 4.0))
def test_dead_code_reset_leaves_no_dead_code(args, threshold) -> None:  # type: ignore[no-untyped-def]
    b, d, k, _, seed = args
    vq = _seeded_vq(k, d, seed, threshold=threshold)
    x = batch(b, d, seed)
    idx = vq.nearest(x)
    vq.ema_update(x, idx)
    before = vq.embed.clone()
    was_dead = vq.cluster_size < threshold
    dead = vq.reset_dead(x)
    if int(was_dead.sum()) <= b:  # enough rows: no unused code after the reset
        assert bool((vq.cluster_size >= threshold).all()) and torch.equal(dead, was_dead)
    else:  # more dead codes than rows: len(x) of them replaced now, by distinct rows
        assert int(dead.sum()) == b and bool((dead <= was_dead).all())
        assert len({tuple(c.tolist()) for c in vq.embed[dead]}) == len({tuple(r.tolist()) for r in x})
    torch.testing.assert_close(vq.embed[~dead], before[~dead], rtol=0, atol=0)  # other codes untouched
    for code in vq.embed[dead]:  # reset codes come from the batch
        assert bool((x == code).all(-1).any())
    # the same through a training forward pass, when the batch has at least as many rows as codes
    if b >= k:
        vq2 = _seeded_vq(k, d, seed, threshold=threshold)
        vq2(x, train=True)
        assert bool((vq2.cluster_size >= threshold).all())


@FAST
@given(st.integers(1, 6), st.integers(1, 40), st.booleans(), st.integers(0, 1000))
def test_dropout_depth_in_range_and_prefix(n, b, per_sample, seed) -> None:  # type: ignore[no-untyped-def]
    torch.manual_seed(seed)
    q = rvq_with_codes(n, 4, 2, seed, dropout=True, dropout_per_sample=per_sample, dead_threshold=0.0).train()
    idx = q(batch(b, 2, seed)).indices
    valid = idx >= 0
    depth = valid.sum(-1)
    assert bool(((depth >= 1) & (depth <= n)).all())
    # a prefix of levels: level n used implies level n-1 used
    assert bool((valid[:, 1:] <= valid[:, :-1]).all())
    if not per_sample:
        assert bool((depth == depth[0]).all())
    depths = q.sample_depth(b)
    assert bool(((depths >= 1) & (depths <= n)).all())


def test_dropout_depth_is_uniform() -> None:
    torch.manual_seed(0)
    n, draws = 6, 60000
    q = ResidualVQ(2, n, 4, dropout=True)
    counts = torch.bincount(q.sample_depth(draws), minlength=n + 1)[1:].double()
    expected = draws / n
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < 20.5  # chi-square, 5 dof, p ≈ 0.001


def test_unused_levels_are_not_updated() -> None:
    torch.manual_seed(0)
    q = rvq_with_codes(4, 8, 3, 1).train()
    snapshot = {k: v.clone() for k, v in q.state_dict().items() if k.startswith(("levels.2", "levels.3"))}
    q(batch(64, 3, 1), n_active=2)
    for key, value in snapshot.items():
        assert torch.equal(q.state_dict()[key], value), key
    assert not torch.equal(q.levels[0].cluster_size, torch.ones(8, dtype=torch.float64))


def test_first_training_batch_initializes_codebooks() -> None:
    torch.manual_seed(0)
    for init in ("kmeans", "random"):
        q = ResidualVQ(3, 2, 8, init=init, dropout=False).double()
        x = batch(200, 3, 0)
        q(x)
        assert all(bool(lvl.initialized) for lvl in q.levels)
        q.eval()
        assert float((x - q(x).quantized).square().mean()) < float(x.square().mean())


# ------------------------------------------------------------------------------------ the model
def tiny_params(**kw) -> HybridParams:  # type: ignore[no-untyped-def]
    base: dict[str, object] = {
        "latent_dim": D,
        "num_codebooks": 3,
        "codebook_size": 6,
        "single_codebook_size": 12,
        "encoder_hidden": [8],
        "prior_hidden": [8],
        "decoder_hidden": [8],
        "proprio_dim": P,
        "goal_dim": G,
        "action_dim": A,
        "dead_threshold": 0.0,
    }
    base.update(kw)
    return HybridParams.model_validate(base)


def tiny_model(seed: int = 0, **kw) -> HybridLatent:  # type: ignore[no-untyped-def]
    torch.manual_seed(seed)
    return HybridLatent(tiny_params(**kw), P, G, A).double()


def chunk(t: int, n: int, seed: int = 0) -> tuple[Observations, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    obs = Observations(
        proprio=torch.randn(t, n, P, generator=gen, dtype=torch.float64),
        goal=torch.randn(t, n, G, generator=gen, dtype=torch.float64),
    )
    teacher = torch.randn(t, n, A, generator=gen, dtype=torch.float64)
    starts = torch.zeros(t, n, dtype=torch.bool)
    starts[0] = True
    return obs, teacher, starts


@FAST
@given(st.integers(1, 16), st.integers(1, 6), st.integers(0, 1000))
def test_marginal_quantization_values_and_gradients(b, d, seed) -> None:  # type: ignore[no-untyped-def]
    q = rvq_with_codes(3, 5, d, seed).eval()
    z = batch(b, d, seed).requires_grad_(True)
    z_p = batch(b, d, seed + 1).requires_grad_(True)
    z_bar, _, idx, _ = marginal_quantize(z, z_p, q)
    y_hat = q.decode(idx)
    torch.testing.assert_close(z_bar, y_hat + z_p)  # z̄ = ŷ_q + z_p
    w = batch(b, d, seed + 2)
    (w * z_bar).sum().backward()
    assert torch.equal(z.grad, w)  # ∂z̄/∂z = I
    assert z_p.grad is None or not bool(z_p.grad.any())  # ∂z̄/∂z_p = 0
    z.grad = None
    z_bar, _, _, _ = marginal_quantize(z, z_p, q)
    mm = mm_loss(z_bar, z_p)
    torch.testing.assert_close(mm, y_hat.square().mean())  # value ‖ŷ_q‖²
    mm.backward()
    torch.testing.assert_close(z_p.grad, -2 * y_hat / y_hat.numel())  # trains the prior toward z̄
    torch.testing.assert_close(z.grad, 2 * y_hat / y_hat.numel())  # shrinks the margin (straight-through)


def _grad_norms(model: HybridLatent) -> dict[str, float]:
    def norm(module: torch.nn.Module | None) -> float:
        if module is None:
            return 0.0
        return sum(float(p.grad.abs().sum()) for p in module.parameters() if p.grad is not None)

    return {"prior": norm(model.prior_net), "encoder": norm(model.posterior), "decoder": norm(model.decoder_net)}


#: which networks each loss term trains (True) or must not reach (False) — derived from Alg. 1 (Sec. 4.1) and Eq. 6 (Sec. 4.3.1)
HYBRID_GRADIENTS = {
    "action": {"prior": False, "encoder": True, "decoder": True},
    "commit": {"prior": False, "encoder": True, "decoder": False},
    "mm": {"prior": True, "encoder": True, "decoder": False},
    "reg": {"prior": True, "encoder": True, "decoder": False},
}


@pytest.mark.parametrize("variant", ["hybrid", "hybrid_vq"])
def test_loss_terms_reach_the_right_networks(variant: str) -> None:
    model = tiny_model(variant=variant).train()
    obs, teacher, starts = chunk(3, 5)
    terms = model.distill_losses(obs, teacher, starts, progress=0.5)
    for name, expected in HYBRID_GRADIENTS.items():
        model.zero_grad(set_to_none=True)
        terms[name].backward(retain_graph=True)
        got = _grad_norms(model)
        for net, reaches in expected.items():
            assert (got[net] > 0) == reaches, f"{variant}: {name} -> {net}: grad {got[net]}"
    gamma = ramp(0.1, 1.0, 0.5)
    expected_total = 10 * terms["action"] + 0.05 * terms["reg"] + 1.0 * terms["commit"] + gamma * terms["mm"]
    torch.testing.assert_close(terms["loss"], expected_total)
    torch.testing.assert_close(terms["mm_weight"].double(), torch.tensor(gamma, dtype=torch.float64))


def test_mm_weight_ramps_from_0_1_to_1() -> None:
    assert ramp(0.1, 1.0, 0.0) == pytest.approx(0.1)
    assert ramp(0.1, 1.0, 1.0) == pytest.approx(1.0)
    assert ramp(0.1, 1.0, 0.5, fraction=0.25) == pytest.approx(1.0)
    assert ramp(0.1, 1.0, 0.25) == pytest.approx(0.325)


def test_temporal_reg_is_masked_at_starts_and_detaches_the_previous_step() -> None:
    x = torch.randn(4, 3, 2, dtype=torch.float64, requires_grad=True)
    starts = torch.tensor([[1, 1, 1], [0, 1, 0], [0, 0, 0], [1, 0, 0]], dtype=torch.bool)
    reg = temporal_reg(x, starts)
    diff = (x[1:] - x[:-1]).square().mean(-1).detach()
    valid = ~starts[1:]
    torch.testing.assert_close(reg.detach(), diff[valid].mean())
    reg.backward()
    assert not bool(x.grad[3, 0].any())  # a pair that would cross a start contributes nothing
    all_starts = temporal_reg(x, torch.ones(4, 3, dtype=torch.bool))
    assert float(all_starts.detach()) == 0.0
    # the previous step is a constant: only x_t receives gradient from the pair (t-1, t)
    y = torch.randn(2, 1, 2, dtype=torch.float64, requires_grad=True)
    temporal_reg(y, torch.zeros(2, 1, dtype=torch.bool)).backward()
    assert not bool(y.grad[0].any()) and bool(y.grad[1].any())


@pytest.mark.parametrize("variant", ["hybrid", "discrete", "discrete_plus", "hybrid_vq", "continuous"])
def test_every_variant_distills_and_acts(variant: str) -> None:
    model = tiny_model(variant=variant).train()
    obs, teacher, starts = chunk(3, 4)
    terms = model.distill_losses(obs, teacher, starts, progress=0.2)
    assert torch.isfinite(terms["loss"])
    terms["loss"].backward()
    with torch.no_grad():
        action = model.student_action(Observations(obs.proprio[0], obs.goal[0]))
    assert action.shape == (4, A)
    if variant == "continuous":
        assert "kl" in terms and "commit" not in terms
        assert model.prior_net is not None and model.quantizer is None
    else:
        assert "commit" in terms
        assert ("mm" in terms) == variant.startswith("hybrid")
        assert (model.prior_net is not None) == variant.startswith("hybrid")


def test_student_action_leaves_codebooks_untouched() -> None:
    model = tiny_model().train()
    obs, teacher, starts = chunk(2, 8)
    model.distill_losses(obs, teacher, starts, 0.0)  # initializes the codebooks
    before = {k: v.clone() for k, v in model.state_dict().items() if isinstance(v, torch.Tensor)}
    with torch.no_grad():
        model.student_action(Observations(obs.proprio[0], obs.goal[0]))
    for key, value in model.state_dict().items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, before[key]), key


@FAST
@given(st.floats(-3, 3), st.floats(-2, 1), st.floats(-3, 3), st.floats(-2, 1))
def test_gaussian_kl_matches_torch(mu_q, ls_q, mu_p, ls_p) -> None:  # type: ignore[no-untyped-def]
    t = lambda v: torch.tensor([v], dtype=torch.float64)
    kl = gaussian_kl(t(mu_q), t(ls_q), t(mu_p), t(ls_p))
    ref = torch.distributions.kl_divergence(torch.distributions.Normal(t(mu_q), t(ls_q).exp()), torch.distributions.Normal(t(mu_p), t(ls_p).exp()))
    torch.testing.assert_close(kl, ref)
    assert float(kl) >= -1e-12
    assert float(gaussian_kl(t(mu_q), t(ls_q), t(mu_q), t(ls_q))) == pytest.approx(0.0, abs=1e-12)


# ------------------------------------------------------------------------------------ task side
@FAST
@given(st.integers(1, 3), st.integers(1, 8), st.integers(0, 1000))
def test_to_latent_with_zero_codebooks_is_the_prior(m, n, seed) -> None:  # type: ignore[no-untyped-def]
    model = tiny_model(seed, task_codebooks=m).freeze()
    assert model.quantizer is not None
    for level in model.quantizer._levels():
        level.set_codebook(torch.zeros_like(level.embed))
    gen = torch.Generator().manual_seed(seed)
    obs = Observations(torch.randn(n, P, generator=gen, dtype=torch.float64))
    codes = model.sample_task_action(n, generator=gen)
    assert codes.shape == (n, m)
    z_p = model.prior(obs).mean
    torch.testing.assert_close(model.to_latent(obs, codes), z_p)
    torch.testing.assert_close(model.to_latent(obs, codes[:, :0]), z_p)  # M = 0
    assert not any(p.requires_grad for p in model.parameters())


def test_to_latent_adds_the_chosen_codes_to_the_prior() -> None:
    model = tiny_model(task_codebooks=2).freeze()
    obs = Observations(torch.randn(5, P, dtype=torch.float64))
    codes = model.sample_task_action(5)
    assert model.quantizer is not None
    books = model.quantizer.codebooks
    expected = model.prior(obs).mean + books[0][codes[:, 0]] + books[1][codes[:, 1]]
    torch.testing.assert_close(model.to_latent(obs, codes), expected)
    z = model.generate(obs, n_active=3)
    assert z.shape == (5, D)


@pytest.mark.parametrize(
    "variant, m, expected",
    [
        ("hybrid", 1, MultiDiscrete((6,))),
        ("hybrid", 2, MultiDiscrete((6, 6))),
        ("discrete_plus", 3, MultiDiscrete((6, 6, 6))),
        ("discrete", 1, MultiDiscrete((12,))),
        ("hybrid_vq", 1, MultiDiscrete((12,))),
        ("continuous", 1, Box((D,))),
    ],
)
def test_task_action_space(variant: str, m: int, expected: object) -> None:
    model = tiny_model(variant=variant, task_codebooks=m).freeze()
    assert model.task_action_space == expected
    obs = Observations(torch.randn(4, P, dtype=torch.float64))
    action = model.sample_task_action(4)
    if isinstance(expected, MultiDiscrete):
        assert action.shape == (4, len(expected.nvec))
        assert bool(((action >= 0) & (action < torch.tensor(expected.nvec))).all())
    assert model.to_latent(obs, action).shape == (4, D)


def test_params_reject_more_task_codebooks_than_levels() -> None:
    with pytest.raises(ValueError):
        tiny_params(task_codebooks=4)
    with pytest.raises(ValueError):
        tiny_params(variant="discrete", task_codebooks=2)


# ------------------------------------------------------------------------- checkpoints, plugin
def test_checkpoint_round_trip_through_the_factory(tmp_path: Path, amp) -> None:  # type: ignore[no-untyped-def]
    params = tiny_params()
    model = make_hybrid(params, skeleton=amp)
    obs, teacher, starts = chunk(2, 6)
    obs = Observations(obs.proprio.float(), obs.goal.float())
    model.update_normalizers(obs)
    model.distill_losses(obs, teacher.float(), starts, 0.3)  # initializes and updates the codebooks
    path = tmp_path / "latent.pt"
    save_hybrid(path, model)
    loaded = make_hybrid(params, skeleton=amp, checkpoint=path)
    ob = Observations(obs.proprio[1], obs.goal[1])
    model.eval()
    torch.testing.assert_close(loaded.student_action(ob), model.student_action(ob))
    torch.testing.assert_close(loaded.proprio_norm.mean, model.proprio_norm.mean)
    assert model.quantizer is not None and loaded.quantizer is not None
    torch.testing.assert_close(loaded.quantizer.codebooks, model.quantizer.codebooks)
    # a trainer checkpoint holding only our state_dict (and config) loads too
    torch.save({"model": model.state_dict(), "config": model.config}, tmp_path / "trainer.pt")
    again = make_hybrid(params, skeleton=amp, checkpoint=tmp_path / "trainer.pt")
    torch.testing.assert_close(again.student_action(ob), model.student_action(ob))
    with pytest.raises(ValueError, match="latent_dim"):
        make_hybrid(tiny_params(latent_dim=D + 1), skeleton=amp, checkpoint=path)


def test_normalizers_running_and_from_teacher() -> None:
    from types import SimpleNamespace

    from mocap.rl.normalizer import RunningNormalizer

    model = tiny_model()
    obs, _, _ = chunk(3, 4)
    model.update_normalizers(obs)  # (T, N, ...) chunk
    torch.testing.assert_close(model.proprio_norm.mean, obs.proprio.reshape(-1, P).mean(0))
    torch.testing.assert_close(model.goal_norm.var, obs.goal.reshape(-1, G).var(0, unbiased=False))
    teacher_norm = RunningNormalizer((P + G,))
    teacher_norm.update(torch.randn(50, P + G, dtype=torch.float64) * 3 + 1)
    taught = tiny_model(normalizer="teacher")
    taught.init_from_teacher(SimpleNamespace(policy=SimpleNamespace(obs_norm=teacher_norm)))
    torch.testing.assert_close(taught.proprio_norm.mean, teacher_norm.mean[:P])
    torch.testing.assert_close(taught.goal_norm.var, teacher_norm.var[P:])
    taught.update_normalizers(obs)  # frozen: no change
    torch.testing.assert_close(taught.goal_norm.mean, teacher_norm.mean[P:])
    with pytest.raises(ValueError):
        taught.init_from_teacher(SimpleNamespace(policy=None))


def test_plugin_registers_the_latent_space(amp) -> None:  # type: ignore[no-untyped-def]
    from mocap.testing import use_plugins

    with use_plugins(("latent_hybrid_rvq", hybrid_plugin)) as pset:
        component = pset.get("latent", "hybrid_rvq")
        model = component.build({"latent_dim": 8, "num_codebooks": 2, "codebook_size": 16, "encoder_hidden": [16]}, skeleton=amp)
    assert isinstance(model, HybridLatent)
    assert model.task_action_space == MultiDiscrete((16,))
    assert model.action_dim == amp.num_dofs


def test_relative_dead_threshold_scales_with_the_batch() -> None:
    """'relative': a code is dead below threshold x (batch rows / K), the same fraction of the mean
    use per code at every batch size; 'absolute' ignores the batch (vector-quantize-pytorch)."""
    from mocap.quantizers import VectorQuantizer

    rel = VectorQuantizer(4, 1024, dead_threshold=0.5, dead_threshold_mode="relative")
    assert rel.effective_threshold(512) == pytest.approx(0.25)
    assert rel.effective_threshold(4096) == pytest.approx(2.0)
    ab = VectorQuantizer(4, 1024, dead_threshold=2.0)
    assert ab.effective_threshold(512) == ab.effective_threshold(4096) == 2.0
    # EMA sizes around the mean use (0.5 at B = 512): absolute 2.0 calls them all dead, relative 0.5 none
    torch.manual_seed(0)
    for vq in (ab, rel):
        vq.initialized.fill_(True)
        vq.cluster_size.fill_(0.5)
    x = torch.randn(512, 4)
    assert int(ab.reset_dead(x).sum()) == 512  # capped at the batch's rows
    assert int(rel.reset_dead(x).sum()) == 0
    with pytest.raises(ValueError, match="dead_threshold_mode"):
        VectorQuantizer(4, 8, dead_threshold_mode="fraction")  # type: ignore[arg-type]


@settings(max_examples=25, deadline=None)
@given(b=st.integers(8, 64), seed=st.integers(0, 2**31 - 1))
def test_training_output_equals_decoded_indices_with_per_sample_dropout(b: int, seed: int) -> None:
    """quantized == decode(indices) also in training mode, with per-sample quantizer dropout (levels
    a sample skipped report -1 and add nothing); codebooks frozen so that decode sees the codes used."""
    torch.manual_seed(seed)
    rvq = ResidualVQ(4, num_quantizers=4, codebook_size=16, decay=1.0, dead_threshold=0.0, dropout=True, dropout_per_sample=True)
    rvq.train()
    x = torch.randn(b, 4)
    out = rvq(x)
    assert bool((out.indices == -1).any()) or b < 16  # some samples used fewer levels
    torch.testing.assert_close(out.quantized.detach(), rvq.decode(out.indices), atol=1e-6, rtol=0)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 40), k=st.integers(1, 24), seed=st.integers(0, 2**31 - 1))
def test_kmeans_centres_are_rows_or_means_inside_the_data(n: int, k: int, seed: int) -> None:
    """k-means initialization never leaves a centre at zero or outside the data: each centre is a
    batch row (an empty cluster keeps its row; with fewer rows than codes every centre is a row) or
    a mean of rows, so it lies in the data's bounding box; data far from the origin shows a zero."""
    from mocap.quantizers import kmeans

    torch.manual_seed(seed)
    x = torch.randn(n, 3, dtype=torch.float64) + 10.0
    centres, counts = kmeans(x, k, iters=5)
    assert centres.shape == (k, 3) and int(counts.sum()) == n
    lo, hi = x.min(0).values, x.max(0).values
    assert bool(((centres >= lo - 1e-9) & (centres <= hi + 1e-9)).all())
    assert bool((centres.abs().sum(-1) > 0).all())
    if n == 1:  # a single row: every centre is that row
        torch.testing.assert_close(centres, x.expand(k, 3))
