"""PULSE's Table 3 ablation switches and App. C.3 latent variants (issue 6, item 5): the unit-sphere
latent, the VQ latent (the hybrid plugin's quantizer, partitioned), the RL term added to
distillation (PPO on the imitation reward), their math, and a tiny distillation run with each. The
tiny distillation runs are in ``test_pulse_ablations_distill.py``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

torch.set_num_threads(1)

from mocap.interfaces import Box, MultiDiscrete
from mocap.rl.ppo import compute_gae
from mocap.state import Observations
from mocap.quantizers import VectorQuantizer
from mocap_pulse.latent import PulseLatent, PulseParams, make_pulse
from mocap_pulse.rl_term import (
    RL_KEYS,
    PulseRLHook,
    gaussian_log_prob,
    normalize_advantages,
    policy_gradient_loss,
)
from mocap_pulse.vq import PartitionedVQ

F64 = torch.float64
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
P_DIM, G_DIM, A_DIM = 7, 5, 4
seeds = st.integers(0, 2**31 - 1)

#: every variant of the ablation matrix, as PulseParams overrides
VARIANTS: dict[str, dict[str, Any]] = {
    "full": {},
    "standard_prior": {"prior": "standard", "task_action": "absolute"},
    "no_residual": {"task_action": "absolute"},
    "no_regu": {"regu": False},
    "rl_decoder": {"rl_term": True},
    "rl_encoder": {"rl_term": True, "rl_policy": "encoder"},
    "sphere": {"latent_kind": "sphere"},
    "sphere_standard": {"latent_kind": "sphere", "prior": "standard"},
    "vq": {
        "latent_kind": "vq",
        "latent_dim": 8,
        "vq_partitions": 4,
        "vq_codebook_size": 8,
    },
    "vq_uniform_separate": {
        "latent_kind": "vq",
        "latent_dim": 8,
        "vq_partitions": 4,
        "vq_codebook_size": 8,
        "prior": "standard",
        "vq_shared_codebook": False,
    },
    "vq_rl": {
        "latent_kind": "vq",
        "latent_dim": 8,
        "vq_partitions": 4,
        "vq_codebook_size": 8,
        "rl_term": True,
    },
}


def tiny(**overrides: Any) -> PulseParams:
    base = {
        "latent_dim": 3,
        "encoder_hidden": [16],
        "prior_hidden": [16],
        "decoder_hidden": [16],
        "rl_critic_hidden": [16],
    }
    return PulseParams(**{**base, **overrides})


def tiny_latent(seed: int = 0, **overrides: Any) -> PulseLatent:
    torch.manual_seed(seed)
    return PulseLatent(tiny(**overrides), P_DIM, G_DIM, A_DIM)


def random_obs(n: int, seed: int = 0, lead: tuple[int, ...] = ()) -> Observations:
    g = torch.Generator().manual_seed(seed)
    return Observations(
        proprio=torch.randn(*lead, n, P_DIM, generator=g),
        goal=torch.randn(*lead, n, G_DIM, generator=g),
    )


def fake_rl_extras(lat: PulseLatent, obs: Observations, seed: int = 0) -> dict[str, torch.Tensor]:
    """Rollout tensors as the hook makes them, for a (T, N) chunk of observations, with random
    rewards and episode ends."""
    T, N = obs.proprio.shape[:2]
    hook = PulseRLHook(lat)
    infos = [hook.act(Observations(proprio=obs.proprio[t], goal=obs.goal[t]))[1] for t in range(T)]
    stacked = {k: torch.stack([i[k] for i in infos]) for k in infos[0]}
    g = torch.Generator().manual_seed(seed)
    term = torch.rand(T, N, generator=g) < 0.1
    trunc = (torch.rand(T, N, generator=g) < 0.1) & ~term
    last = Observations(proprio=obs.proprio[-1], goal=obs.goal[-1])
    return hook.finish(stacked, torch.rand(T, N, generator=g), term, trunc, last)


# ------------------------------------------------------------------------------------ switches
def test_every_switch_is_selectable_and_bad_combinations_are_refused():
    for name, kw in VARIANTS.items():
        assert isinstance(tiny(**kw), PulseParams), name
    with pytest.raises(ValidationError, match="multiple of vq_partitions"):
        PulseParams(latent_kind="vq", latent_dim=30, vq_partitions=8)
    with pytest.raises(ValidationError, match="deterministic"):
        PulseParams(latent_kind="vq", latent_dim=64, rl_term=True, rl_policy="encoder")
    for name, f in PulseParams.model_fields.items():
        assert f.description, name


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_each_variant_builds_its_loss_is_finite_and_gradients_flow(variant):
    lat = tiny_latent(1, **VARIANTS[variant])
    obs = random_obs(4, seed=2, lead=(5,))
    starts = torch.zeros(5, 4, dtype=torch.bool)
    starts[0] = True
    if lat.params.rl_term:
        obs.extra.update(fake_rl_extras(lat, obs))
    lat.train()
    losses = lat.distill_losses(obs, torch.randn(5, 4, A_DIM), starts, progress=0.3)
    assert all(bool(torch.isfinite(torch.as_tensor(v)).all()) for v in losses.values()), losses
    losses["loss"].backward()
    nets = {"enc": lat.enc, "dec": lat.dec}
    if lat.pri is not None:
        nets["pri"] = lat.pri
    if lat.code_prior is not None:
        nets["code_prior"] = lat.code_prior
    if lat.critic is not None:
        nets["critic"] = lat.critic
        assert {"rl_policy", "rl_value", "rl_ratio"} <= set(losses)
    for name, net in nets.items():
        grads = [q.grad for q in net.parameters()]
        assert all(g is not None for g in grads) and any(float(g.abs().sum()) > 0 for g in grads), (variant, name)
    # the total is the sum of its weighted terms
    pp = lat.params
    expected = losses["action"] + (pp.alpha if pp.regu else 0.0) * losses["regu"]
    if pp.latent_kind == "vq":
        expected = expected + pp.vq_commit_weight * losses["commit"] + (pp.vq_prior_weight * losses["kl"] if pp.prior == "learned" else 0.0)
    else:
        expected = expected + losses["beta"] * losses["kl"]
    if pp.rl_term:
        expected = expected + pp.rl_weight * losses["rl_policy"] + pp.rl_value_coef * losses["rl_value"]
    assert float(losses["loss"].detach()) == pytest.approx(float(expected), rel=1e-5, abs=1e-6)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_each_variant_decodes_maps_task_actions_and_generates(variant):
    lat = tiny_latent(3, **VARIANTS[variant]).eval()
    obs = random_obs(6, seed=4)
    space = lat.task_action_space
    g = torch.Generator().manual_seed(0)
    if isinstance(space, MultiDiscrete):
        assert lat.params.latent_kind == "vq" and space.nvec == (8,) * 4
        action = torch.stack([torch.randint(0, k, (6,), generator=g) for k in space.nvec], -1)
    else:
        assert isinstance(space, Box) and space.shape == (lat.latent_dim,)
        action = torch.randn(6, lat.latent_dim, generator=g)
    z = lat.to_latent(obs, action)
    assert z.shape == (6, lat.latent_dim) and bool(torch.isfinite(z).all())
    assert lat.decode_action(obs, z).shape == (6, A_DIM)
    g1, g2 = torch.Generator().manual_seed(7), torch.Generator().manual_seed(7)
    r1, r2 = (
        lat.random_action(Observations(proprio=obs.proprio), 1.0, g1),
        lat.random_action(Observations(proprio=obs.proprio), 1.0, g2),
    )
    assert r1.shape == (6, A_DIM) and torch.equal(r1, r2)
    assert lat.student_action(obs).shape == (6, A_DIM)


# ----------------------------------------------------------------------------------- unit sphere
@SETTINGS
@given(
    seed=seeds,
    prior=st.sampled_from(["learned", "standard"]),
    scale=st.floats(0.0, 3.0),
)
def test_sphere_latents_have_unit_norm(seed, prior, scale):
    lat = tiny_latent(seed % 7, latent_kind="sphere", prior=prior)
    obs = random_obs(5, seed=seed)
    g = torch.Generator().manual_seed(seed)
    residual = torch.randn(5, 3, generator=g) * 10.0
    for z in (
        lat.encoder(obs, sample=True).z,
        lat.encoder(obs).z,
        lat.prior(obs).z,
        lat.to_latent(obs, residual),
        lat.sample_prior(obs, noise_scale=scale, generator=g),
        lat._to_decoder_latent(torch.randn(5, 3, generator=g)),
    ):
        assert torch.allclose(z.norm(dim=-1), torch.ones(5), atol=1e-5)


def test_sphere_standard_prior_samples_are_uniform_on_the_sphere():
    """Projected N(0, I) is uniform on S^{Z-1}: for Z = 3 each coordinate is uniform on [-1, 1]
    (Archimedes), so its mean is 0 and its variance 1/3."""
    lat = tiny_latent(0, latent_kind="sphere", prior="standard")
    obs = Observations(proprio=torch.randn(20000, P_DIM))
    z = lat.sample_prior(obs, generator=torch.Generator().manual_seed(1))
    assert torch.allclose(z.mean(0), torch.zeros(3), atol=0.02)
    assert torch.allclose(z.var(0), torch.full((3,), 1 / 3), atol=0.02)


# ------------------------------------------------------------------------------------------ VQ
@SETTINGS
@given(seed=seeds, shared=st.booleans())
def test_vq_straight_through_passes_the_gradient_unchanged(seed, shared):
    vq = PartitionedVQ(6, 3, 5, shared=shared)
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(4, 6, generator=g, dtype=torch.float32, requires_grad=True)
    w = torch.randn(4, 6, generator=g)
    out = vq(x, train=False)
    (out.quantized * w).sum().backward()
    assert torch.allclose(x.grad, w)  # ∂z/∂x = I
    assert torch.allclose(out.quantized.detach(), vq.decode(out.indices))  # forward value = the codes
    # each partition's code is its nearest one
    for b in range(4):
        for p in range(3):
            book = vq.books[0 if shared else p].embed
            d = (x[b, 2 * p : 2 * p + 2].detach() - book).square().sum(-1)
            assert float(d[out.indices[b, p]]) <= float(d.min()) + 1e-6


@SETTINGS
@given(seed=seeds, shared=st.booleans(), delta=st.floats(1e-3, 1.0))
def test_vq_commitment_is_zero_iff_the_encoder_output_equals_its_code(seed, shared, delta):
    vq = PartitionedVQ(6, 3, 5, shared=shared)
    g = torch.Generator().manual_seed(seed)
    idx = torch.randint(0, 5, (4, 3), generator=g)
    codes = vq.decode(idx)
    assert float(vq(codes, train=False).commit) == 0.0
    assert torch.equal(vq(codes, train=False).quantized, codes)
    # moving one coordinate by delta toward no other code leaves a positive commitment loss
    x = codes.clone()
    x[0, 0] += delta
    out = vq(x, train=False)
    assert float(out.commit) > 0.0
    assert float(out.commit) == pytest.approx(float((x - vq.decode(out.indices)).square().mean()), rel=1e-5)


def test_vq_reuses_the_hybrid_quantizer_and_updates_codebooks_only_in_training():
    lat = tiny_latent(0, **VARIANTS["vq"])
    assert lat.vq is not None and all(isinstance(b, VectorQuantizer) for b in lat.vq.books) and len(lat.vq.books) == 1
    assert len(tiny_latent(0, **VARIANTS["vq_uniform_separate"]).vq.books) == 4
    obs = random_obs(16, seed=1, lead=(3,))
    before = lat.vq.books[0].embed.clone()
    lat.eval()
    lat.student_action(obs)
    lat.distill_losses(obs, torch.zeros(3, 16, A_DIM), torch.zeros(3, 16, dtype=torch.bool), 0.0)
    assert torch.equal(lat.vq.books[0].embed, before) and not bool(lat.vq.books[0].initialized)
    lat.train()
    lat.student_action(obs)  # rollouts never touch the codebooks
    assert torch.equal(lat.vq.books[0].embed, before)
    lat.distill_losses(obs, torch.zeros(3, 16, A_DIM), torch.zeros(3, 16, dtype=torch.bool), 0.0)
    assert bool(lat.vq.books[0].initialized) and not torch.equal(lat.vq.books[0].embed, before)


def test_vq_prior_loss_is_the_cross_entropy_of_the_codes_and_generation_modes():
    lat = tiny_latent(2, **VARIANTS["vq"]).eval()
    obs = random_obs(5, seed=3, lead=(2,))
    out = lat.distill_losses(obs, torch.zeros(2, 5, A_DIM), torch.zeros(2, 5, dtype=torch.bool), 0.5)
    with torch.no_grad():
        p, g, _ = lat._inputs(obs)
        idx = lat.vq(lat._posterior(p, g)[0]).indices
        logp = torch.log_softmax(lat._code_logits(p), -1)
        ce = -logp.gather(-1, idx.unsqueeze(-1)).squeeze(-1).sum(-1).mean()
    assert float(out["kl"]) == pytest.approx(float(ce), rel=1e-5) and float(out["beta"]) == 0.0
    # temperature 0: the most likely code per partition = prior().z; uniform prior: every code appears
    flat = Observations(proprio=obs.proprio[0])
    assert torch.equal(lat.sample_prior(flat, noise_scale=0.0), lat.prior(flat).z)
    assert torch.equal(lat.vq.decode(lat.prior(flat).indices), lat.prior(flat).z)
    uni = tiny_latent(2, **VARIANTS["vq_uniform_separate"]).eval()
    many = Observations(proprio=torch.randn(400, P_DIM))
    z = uni.sample_prior(many, generator=torch.Generator().manual_seed(0))
    codes = torch.stack(
        [(z[:, 2 * p : 2 * p + 2, None] == uni.vq.books[p].embed.t()[None]).all(1).float().argmax(-1) for p in range(4)],
        -1,
    )
    assert torch.equal(uni.vq.decode(codes), z) and len(codes[:, 0].unique()) == 8
    assert torch.equal(uni.prior(flat).z, torch.zeros(5, 8)) and uni.prior(flat).indices is None


def test_vq_checkpoint_round_trip_keeps_the_codebooks(amp, tmp_path):
    from mocap.distill_files import save_latent

    params = PulseParams(
        latent_kind="vq",
        latent_dim=8,
        vq_partitions=4,
        vq_codebook_size=8,
        encoder_hidden=[8],
        prior_hidden=[8],
        decoder_hidden=[8],
    )
    lat = make_pulse(params, skeleton=amp)
    with torch.no_grad():
        lat.vq.books[0].set_codebook(torch.randn(8, 2))
    save_latent(tmp_path / "latent.pt", lat)
    loaded = make_pulse(params, skeleton=amp, checkpoint=tmp_path / "latent.pt")
    assert torch.equal(loaded.vq.books[0].embed, lat.vq.books[0].embed) and bool(loaded.vq.books[0].initialized)
    with pytest.raises(ValueError, match="vq_codebook_size"):
        make_pulse(
            params.model_copy(update={"vq_codebook_size": 16}),
            skeleton=amp,
            checkpoint=tmp_path / "latent.pt",
        )


# -------------------------------------------------------------------------------------- RL term
@SETTINGS
@given(
    logp_old=st.floats(-5, 5),
    adv=st.floats(-3, 3).filter(lambda a: abs(a) > 1e-3),
    step=st.floats(1e-4, 0.15),
)
def test_rl_term_direction_raising_advantage_weighted_log_prob_lowers_the_loss(logp_old, adv, step):
    """Inside the clip range (|ρ − 1| < ε) moving log π in the advantage's direction lowers the loss;
    past it (ρ > 1 + ε with Â > 0) the loss is flat: no incentive to move further."""
    old, a = torch.tensor([logp_old], dtype=F64), torch.tensor([adv], dtype=F64)
    base = policy_gradient_loss(old, old, a, 0.2)
    assert float(base) == pytest.approx(-adv)
    moved = policy_gradient_loss(old + math.copysign(step, adv), old, a, 0.2)
    assert float(moved) < float(base)
    new = old.clone().requires_grad_(True)
    policy_gradient_loss(new, old, a, 0.2).backward()
    assert float(new.grad) == pytest.approx(-adv)  # ∂L/∂log π = −Â ρ at ρ = 1
    if adv > 0:
        far = policy_gradient_loss(old + 0.5, old, a, 0.2)
        farther = policy_gradient_loss(old + 1.0, old, a, 0.2)
        assert float(far) == pytest.approx(float(farther)) == pytest.approx(-1.2 * adv)


@SETTINGS
@given(seed=seeds, z=st.integers(1, 5))
def test_gaussian_log_prob_matches_torch_and_advantage_normalization(seed, z):
    g = torch.Generator().manual_seed(seed)
    x, mu = (
        torch.randn(6, z, generator=g, dtype=F64),
        torch.randn(6, z, generator=g, dtype=F64),
    )
    lv = torch.empty(6, z, dtype=F64).uniform_(-3, 2, generator=g)
    ref = torch.distributions.Normal(mu, torch.exp(0.5 * lv)).log_prob(x).sum(-1)
    assert torch.allclose(gaussian_log_prob(x, mu, lv), ref, rtol=1e-10, atol=1e-10)
    adv = torch.randn(10, generator=g, dtype=F64) * 3 + 1
    n = normalize_advantages(adv)
    assert abs(float(n.mean())) < 1e-9 and float(n.std()) == pytest.approx(1.0, rel=1e-6)


def test_rl_hook_log_probs_are_reproduced_by_the_loss_and_gae_bootstraps_truncations():
    """At the rollout's parameters the loss recomputes the rollout's log π exactly (ρ = 1), for both
    policy forms; GAE uses V(s_t) for truncated steps, 0 for terminated ones, V(next obs) at the end."""
    for policy in ("decoder", "encoder"):
        lat = tiny_latent(5, rl_term=True, rl_policy=policy, regu=False).eval()
        obs = random_obs(3, seed=6, lead=(4,))
        torch.manual_seed(0)
        ex = fake_rl_extras(lat, obs, seed=1)
        assert set(RL_KEYS) <= set(ex) and ex["rl_adv"].shape == (4, 3)
        obs.extra.update(ex)
        out = lat.distill_losses(obs, torch.zeros(4, 3, A_DIM), torch.zeros(4, 3, dtype=torch.bool), 0.0)
        assert float(out["rl_ratio"]) == pytest.approx(1.0, abs=1e-5), policy
        if policy == "encoder":  # no action noise: the student acts with the decoder mean
            p, g, _ = lat._inputs(Observations(proprio=obs.proprio[0], goal=obs.goal[0]))
            assert torch.allclose(ex["rl_action"][0], lat._decode(p, ex["rl_z"][0]), atol=1e-6)
        else:  # action noise of σ_a around the decoder mean
            assert not torch.allclose(ex["rl_action"], lat.student_action(obs, sample=False))
    hook = PulseRLHook(tiny_latent(0, rl_term=True))
    values = torch.tensor([[1.0], [2.0], [3.0]])
    rewards = torch.tensor([[0.5], [0.25], [1.0]])
    last = Observations(proprio=torch.zeros(1, P_DIM), goal=torch.zeros(1, G_DIM))
    with torch.no_grad():
        p, g, _ = hook.latent._inputs(last)
        v_last = hook.latent.value(p, g)
    for term, trunc, nxt in (
        ([0, 0, 0], [0, 0, 0], [2.0, 3.0, float(v_last)]),
        ([0, 1, 0], [0, 0, 0], [2.0, 3.0, float(v_last)]),
        ([0, 0, 0], [1, 0, 0], [1.0, 3.0, float(v_last)]),
    ):
        te, tr = (
            torch.tensor(term, dtype=torch.bool)[:, None],
            torch.tensor(trunc, dtype=torch.bool)[:, None],
        )
        got = hook.finish({"rl_value": values}, rewards, te, tr, last)
        adv, _ = compute_gae(rewards, values, torch.tensor(nxt)[:, None], te, te | tr, 0.99, 0.95)
        assert torch.allclose(got["rl_adv"], adv)
        assert torch.allclose(got["rl_ret"], adv + values)


@pytest.mark.parametrize("policy", ["decoder", "encoder"])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_gradient_step_on_the_rl_term_moves_log_prob_with_the_advantage(policy, sign):
    """One sample, advantage ±1: an SGD step on the latent's RL policy loss raises (lowers) the
    log-probability of the rollout's action, through the encoder and decoder."""
    from mocap_pulse.rl_term import rl_losses

    lat = tiny_latent(4, rl_term=True, rl_policy=policy, rl_normalize_advantages=False).eval()
    obs = random_obs(1, seed=9, lead=(1,))
    torch.manual_seed(1)
    ex = fake_rl_extras(lat, obs)
    ex["rl_adv"] = torch.full((1, 1), sign)

    def logp_and_loss():
        p, g, _ = lat._inputs(obs)
        mu, lv = lat._posterior(p, g)
        return rl_losses(lat, p, g, mu, lv, ex)

    before = float(logp_and_loss()["rl_ratio"])
    assert before == pytest.approx(1.0, abs=1e-5)
    params = [q for n, q in lat.named_parameters() if not n.startswith("critic")]
    logp_and_loss()["rl_policy"].backward()
    with torch.no_grad():  # one plain SGD step
        for q in params:
            if q.grad is not None:
                q -= 1e-3 * q.grad
    after = float(logp_and_loss()["rl_ratio"])  # = π_new(a|s) / π_old(a|s)
    assert (after - 1.0) * sign > 0, (policy, sign, after)


def test_rl_reward_is_the_phc_imitation_reward(amp):
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary
    from mocap.imitation_rewards import ImitationReward

    lib = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp), amp)
    ref = lib.frames(torch.zeros(3, dtype=torch.long), torch.tensor([0.1, 0.2, 0.3]))
    other = lib.frames(torch.zeros(3, dtype=torch.long), torch.tensor([0.4, 0.5, 0.6]))
    for form in ("paper", "code"):
        hook = PulseRLHook(tiny_latent(0, rl_term=True, rl_reward_form=form))
        assert torch.allclose(hook.reward(ref, ref), torch.ones(3))
        assert torch.allclose(hook.reward(other, ref), ImitationReward(form=form)(other, ref)[0].float())
        assert bool((hook.reward(other, ref) < 1).all())


# ---------------------------------------------------------------------------------- the spec
def test_the_ablation_spec_has_one_cell_per_table3_row_and_latent_variant():
    from mocap.matrix import expand
    from mocap.spec import load_document

    path = Path(__file__).parents[1] / "specs" / "latent" / "pulse_ablations.yaml"
    cells = expand(load_document(path), path.parent, str(path))
    rows = {}
    for cell in cells:
        p = PulseParams(**cell.doc["latent"]["params"])
        rows[p.name] = (
            p.prior == "learned",
            p.task_action == "residual",
            p.regu,
            not p.rl_term,
            p.latent_kind,
        )
        assert cell.name == f"params-{p.name}" and cell.doc["task"]["name"] == "hmd_tracking"
        assert cell.doc["latent"]["trainer"]["params"]["act_with"] == "student"  # the RL term is on-policy
    # Table 3 (Prior, Prior-action, L_regu, No RL) rows 1-6, then App. C.3's variants
    assert rows == {
        "r1_plain": (False, False, False, True, "gaussian"),
        "r2_no_prior": (False, False, True, True, "gaussian"),
        "r3_no_regu": (True, True, False, True, "gaussian"),
        "r4_rl_term": (True, True, True, False, "gaussian"),
        "r5_absolute": (True, False, True, True, "gaussian"),
        "full": (True, True, True, True, "gaussian"),
        "sphere": (True, True, True, True, "sphere"),
        "vq": (True, True, True, True, "vq"),
    }


@SETTINGS
@given(seed=seeds, z=st.integers(1, 6), zero=st.booleans())
def test_project_to_sphere_is_unit_norm_and_keeps_direction(seed, z, zero):
    from mocap_pulse.losses import project_to_sphere

    g = torch.Generator().manual_seed(seed)
    x = torch.zeros(4, z, dtype=F64) if zero else torch.randn(4, z, generator=g, dtype=F64) * 5
    y = project_to_sphere(x)
    assert torch.allclose(y.norm(dim=-1), torch.ones(4, dtype=F64))
    if zero:  # no direction: e_1
        assert torch.equal(y, torch.eye(z, dtype=F64)[0].expand(4, z))
    else:
        assert torch.allclose(y * x.norm(dim=-1, keepdim=True), x)
