"""VMP stage I (plugin ``latent_vmp``): features, windows, standardization, the VAE's loss and
schedules (VMP Sec. 3.1, Eqs. 2-4; Sec. 4.1 and Table 1), a tiny training run on the bundled walk clip and
exact resume of the ``supervised`` trainer."""

from __future__ import annotations

import dataclasses
import io
import json
import math
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from rich.console import Console

torch.set_num_threads(1)

import mocap_vmp.plugin
from mocap.interfaces import Box
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap.motion.library import MotionLibrary
from mocap.rotations import (
    heading_angle,
    matrix_to_sixd,
    quat_apply,
    quat_from_axis_angle,
    quat_mul,
    quat_normalize,
    quat_to_matrix,
    sixd_to_matrix,
)
from mocap.runlog import MetricsLogger
from mocap.state import Observations
from mocap.testing import use_plugins
from mocap_vmp.features import FeatureLayout, destandardize, feature_stats, standardize, window_rows
from mocap_vmp.latent import VmpLatent, VmpParams, make_vmp
from mocap_vmp.trainer import SupervisedParams, SupervisedTrainer
from mocap_vmp.vae import (
    cyclical_beta,
    kl_divergence,
    per_frame_errors,
    reconstruction_loss,
    sgdr_lr,
)

TINY = {"window_half": 6, "latent_dim": 8, "channels": 16, "res_blocks": 1, "downsample": 1}
f64 = torch.float64


@pytest.fixture(scope="module")
def walk(amp):
    return DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp)


@pytest.fixture(scope="module")
def walk_lib(amp, walk):
    return MotionLibrary(walk, amp, dtype=f64)


quats = st.lists(st.floats(-1, 1), min_size=4, max_size=4).map(lambda v: torch.tensor(v, dtype=f64)).filter(lambda q: float(q.norm()) > 0.1)
vec3 = st.lists(st.floats(-3, 3), min_size=3, max_size=3).map(lambda v: torch.tensor(v, dtype=f64))


# ------------------------------------------------------------------------- 6-D and Gram-Schmidt
@settings(max_examples=50, deadline=None)
@given(q=quats, a=st.floats(0.1, 10), c=st.floats(-5, 5))
def test_sixd_round_trip_and_gram_schmidt(q, a, c):
    R = quat_to_matrix(quat_normalize(q))
    x = matrix_to_sixd(R)
    assert torch.allclose(sixd_to_matrix(x), R, atol=1e-10)
    # scaling b1 by a positive factor and adding a multiple of b1 to the second column: same matrix
    y = torch.cat((a * x[:3], x[3:] + c * x[:3]))
    assert torch.allclose(sixd_to_matrix(y), R, atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(v=st.lists(st.floats(-5, 5), min_size=6, max_size=6))
def test_gram_schmidt_orthonormal(v):
    x = torch.tensor(v, dtype=f64)
    a1, a2 = x[:3], x[3:]
    assume(float(a1.norm()) > 1e-2 and float(torch.linalg.cross(a1, a2).norm()) > 1e-2 * float(a2.norm()) and float(a2.norm()) > 1e-2)
    R = sixd_to_matrix(x)
    assert torch.allclose(R.T @ R, torch.eye(3, dtype=f64), atol=1e-9)
    assert float(torch.linalg.det(R)) == pytest.approx(1.0, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(q1=quats, q2=quats, g=quats)
def test_rotation_distance_in_loss(q1, q2, g):
    """theta's per-frame error is ||R1 - R2||_F^2 = 2(3 - tr(R1^T R2)) in [0, 8], invariant to a common rotation."""
    layout = FeatureLayout(0, ())
    R1, R2, G = (quat_to_matrix(quat_normalize(q)) for q in (q1, q2, g))

    def err(A, B):
        x = torch.zeros(1, 1, layout.dim, dtype=f64)
        y = x.clone()
        x[..., layout.theta], y[..., layout.theta] = matrix_to_sixd(A), matrix_to_sixd(B)
        return float(per_frame_errors(x, y, layout)["theta"])

    e = err(R1, R2)
    assert e == pytest.approx(2 * (3 - float(torch.trace(R1.T @ R2))), abs=1e-9)
    assert -1e-12 <= e <= 8 + 1e-9
    assert err(G @ R1, G @ R2) == pytest.approx(e, abs=1e-9) and err(R1 @ G, R2 @ G) == pytest.approx(e, abs=1e-9)
    assert err(R2, R1) == pytest.approx(e, abs=1e-12)


# --------------------------------------------------------------------------- heading invariance
@settings(max_examples=8, deadline=None)
@given(yaw=st.floats(-math.pi, math.pi), dx=st.floats(-20, 20), dy=st.floats(-20, 20), centre=st.integers(0, 38))
def test_windows_invariant_to_global_yaw_and_planar_translation(amp, walk, walk_lib, yaw, dx, dy, centre):
    clip = walk.clips[0]
    qz = quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0], dtype=f64), torch.tensor(yaw, dtype=f64))
    rp = torch.from_numpy(np.asarray(clip.root_pos)).to(f64)
    rr = torch.from_numpy(np.asarray(clip.root_rot)).to(f64)
    rp2 = quat_apply(qz.expand(len(rp), 4), rp) + torch.tensor([dx, dy, 0.0], dtype=f64)
    rr2 = quat_mul(qz.expand(len(rr), 4), rr)
    moved = dataclasses.replace(clip, root_pos=rp2.numpy(), root_rot=rr2.numpy())
    lib2 = MotionLibrary([moved], amp, dtype=f64)
    latent = VmpLatent(VmpParams(**TINY), amp)
    c = torch.tensor([centre])
    w1, w2 = latent.windows(walk_lib, c), latent.windows(lib2, c)
    assert torch.allclose(w1, w2, atol=1e-8)
    s = latent.layout.slices
    rows = window_rows(walk_lib, c, latent.params.window_half)[0]
    # h, q, qd are the raw values; the centre frame's root yaw is 0 in its own heading frame
    assert torch.allclose(w1[0, :, s["h"]][:, 0], walk_lib.root_pos[rows, 2])
    assert torch.equal(w1[0, :, s["q"]], walk_lib.dof_pos[rows]) and torch.equal(w1[0, :, s["qd"]], walk_lib.dof_vel[rows])
    from mocap.rotations import matrix_to_quat

    mid = latent.params.window_half
    assert float(heading_angle(matrix_to_quat(sixd_to_matrix(w1[0, mid, s["theta"]])))) == pytest.approx(0.0, abs=1e-9)


# ------------------------------------------------------------------------------ standardization
@settings(max_examples=40, deadline=None)
@given(
    data=st.lists(st.lists(st.floats(-100, 100), min_size=12, max_size=12), min_size=2, max_size=30),
    const=st.floats(-5, 5),
)
def test_standardization(data, const):
    layout = FeatureLayout(1, ())  # 1 + 6 + 6 + 1 + 1 = 15 dims
    x = torch.tensor(data, dtype=f64)
    x = torch.cat((x[:, :1], torch.full((len(x), 1), const, dtype=f64), x[:, 1:]), 1)  # ... and one constant
    x = torch.cat((x[:, :14], torch.full((len(x), 1), const, dtype=f64)), 1)
    mean, std = feature_stats(x, layout, 1e-6)
    z = standardize(x, mean, std)
    assert torch.isfinite(z).all()
    assert torch.allclose(destandardize(z, mean, std), x, atol=1e-9)
    assert torch.equal(z[:, layout.theta], x[:, layout.theta])  # orientation untouched
    varying = x.std(0, unbiased=False) > 1e-3
    varying[layout.theta] = False
    if not bool(varying.any()):
        return
    assert torch.allclose(z[:, varying].mean(0), torch.zeros(int(varying.sum()), dtype=f64), atol=1e-9)
    assert torch.allclose(z[:, varying].std(0, unbiased=False), torch.ones(int(varying.sum()), dtype=f64), atol=1e-6)


# ------------------------------------------------------------------------------------ windowing
@settings(max_examples=40, deadline=None)
@given(lengths=st.lists(st.integers(1, 12), min_size=1, max_size=5), half=st.integers(0, 6))
def test_window_rows(lengths, half):
    n = torch.tensor(lengths)
    lib = types.SimpleNamespace(num_frames=n, frame_clip=torch.repeat_interleave(torch.arange(len(lengths)), n))
    total = int(n.sum())
    rows = window_rows(lib, torch.arange(total), half)
    assert rows.shape == (total, 2 * half + 1)  # a clip of L frames yields L windows
    assert torch.equal(rows[:, half], torch.arange(total))  # the centre is m_t
    assert torch.equal(lib.frame_clip[rows], lib.frame_clip[:, None].expand_as(rows))  # never mixes clips
    start = 0
    for L in lengths:
        w = rows[start : start + L]
        for f in range(L):
            expect = [start + min(max(f + o, 0), L - 1) for o in range(-half, half + 1)]
            assert w[f].tolist() == expect  # edge padding repeats frame 0 and frame L-1
        start += L


# ----------------------------------------------------------------------------------------- loss
@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), T=st.integers(1, 9), scale=st.one_of(st.just(0.0), st.floats(1e-3, 2.0)))
def test_reconstruction_loss_zero_iff_equal_and_mean_over_frames(seed, T, scale):
    layout = FeatureLayout(2, ("a",))
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(3, T, layout.dim, generator=g, dtype=f64)
    loss, _ = reconstruction_loss(x, x, layout)
    assert float(loss) == pytest.approx(0.0, abs=1e-12)
    d = torch.zeros_like(x)
    d[..., layout.slices["q"]] = scale  # the same per-frame error 2 scale^2 in every frame, for any T
    loss, _ = reconstruction_loss(x + d, x, layout)
    assert float(loss) == pytest.approx(2 * scale**2, rel=1e-9, abs=1e-12)
    assert (float(loss) > 0) == (scale > 0)
    # a theta change that Gram-Schmidt maps to the same rotation costs nothing; a real rotation does
    y = x.clone()
    th = x[..., layout.theta]
    y[..., layout.theta] = torch.cat((2.0 * th[..., :3], th[..., 3:] + 0.5 * th[..., :3]), -1)
    assert float(reconstruction_loss(y, x, layout)[0]) == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(mu=st.lists(st.floats(-3, 3), min_size=4, max_size=4), lv=st.lists(st.floats(-3, 3), min_size=4, max_size=4))
def test_kl(mu, lv):
    mu, lv = torch.tensor([mu], dtype=f64), torch.tensor([lv], dtype=f64)
    kl = float(kl_divergence(mu, lv))
    assert kl >= -1e-12
    assert float(kl_divergence(torch.zeros_like(mu), torch.zeros_like(lv))) == 0.0
    if float(mu.abs().max()) > 1e-3 or float(lv.abs().max()) > 1e-3:
        assert kl > 0
    p = torch.distributions.Normal(mu, torch.exp(0.5 * lv))
    ref = torch.distributions.kl_divergence(p, torch.distributions.Normal(torch.zeros_like(mu), torch.ones_like(mu))).sum()
    assert kl == pytest.approx(float(ref), rel=1e-9, abs=1e-12)


# ------------------------------------------------------------------------------------ schedules
@settings(max_examples=60, deadline=None)
@given(step=st.integers(0, 49_999))
def test_cyclical_beta_range_and_period(step):
    N, M, beta, R = 50_000, 7, 0.002, 0.5
    period = math.ceil(N / M)
    b = cyclical_beta(step, N, beta, M, R)
    assert 0.0 <= b <= beta
    if step + period < N:
        assert cyclical_beta(step + period, N, beta, M, R) == b
    tau = (step % period) / (N / M)
    if tau >= R:
        assert b == beta
    elif step % period + 1 < period:
        assert cyclical_beta(step + 1, N, beta, M, R) >= b  # non-decreasing within the ramp


def test_cyclical_beta_cycle_count():
    N, M = 50_000, 7
    starts = [s for s in range(N) if cyclical_beta(s, N, 0.002, M, 0.5) == 0.0]
    assert len(starts) == 7 and starts[1] == math.ceil(N / M)


def test_sgdr_restarts_and_torch_agreement():
    lr0 = 3e-3
    for s in (0, 1000, 6000, 31_000):
        assert sgdr_lr(s, lr0, 1000, 5) == lr0
    assert sgdr_lr(50_000, lr0, 1000, 5) == pytest.approx(2.832e-3, abs=5e-7)
    assert all(sgdr_lr(s, lr0, 1000, 5) <= lr0 for s in range(0, 50_000, 97))
    w = torch.nn.Parameter(torch.zeros(1))
    opt = torch.optim.RAdam([w], lr=lr0)
    sched = torch.optim.lr_scheduler.CosineAnnealingWarmRestarts(opt, T_0=1000, T_mult=5)
    checks = {0, 1, 999, 1000, 1001, 3500, 5999, 6000, 7000}
    for s in range(7001):
        if s in checks:
            assert opt.param_groups[0]["lr"] == pytest.approx(sgdr_lr(s, lr0, 1000, 5), rel=1e-9, abs=1e-15)
        opt.step()
        sched.step()


# ----------------------------------------------------------------------------- latent interface
def test_latent_interface(amp, walk_lib):
    latent = VmpLatent(VmpParams(**TINY), amp)
    assert latent.layout.end_effectors == ("right_hand", "left_hand", "right_foot", "left_foot")
    assert latent.layout.dim == 25 + 2 * amp.num_dofs
    w = latent.windows(walk_lib, torch.arange(4)).float()
    obs = Observations(proprio=torch.zeros(4, 5), extra={"window": w})
    post = latent.encoder(obs)
    assert post.mean.shape == (4, 8) and torch.equal(post.z, post.mean)
    prior = latent.prior(obs)
    assert torch.equal(prior.mean, torch.zeros(4, 8)) and torch.equal(prior.std, torch.ones(4, 8))
    assert latent.task_action_space == Box((8,))
    a = torch.randn(4, 8)
    assert torch.equal(latent.to_latent(obs, a), a)
    with pytest.raises(NotImplementedError, match="stage II"):
        latent.decoder(obs, a)
    with pytest.raises(KeyError, match="window"):
        latent.encoder(Observations(proprio=torch.zeros(4, 5)))
    out = latent.decode_window(post.z)
    R = sixd_to_matrix(out[..., latent.layout.theta])
    assert torch.allclose(R.transpose(-1, -2) @ R, torch.eye(3).expand_as(R), atol=1e-5)


def test_plugin_registers():
    with use_plugins(("latent_vmp", mocap_vmp.plugin)) as pset:
        assert pset.get("latent", "vmp").build is not None
        assert isinstance(pset.get("trainer", "supervised").build({"num_iterations": 3}), SupervisedTrainer)


# ------------------------------------------------------------------------------------- training
@dataclass
class FakeContext:
    """The part of :class:`mocap.pipeline.StageContext` the supervised trainer uses."""

    workdir: Path
    skeleton: Any
    motions: Any
    seed: int = 0
    stop_after: int | None = None
    device: torch.device = torch.device("cpu")
    console: Console = field(default_factory=lambda: Console(file=io.StringIO()))
    calls: int = 0

    def __post_init__(self) -> None:
        self.log = MetricsLogger(self.workdir / "metrics.jsonl", "latent")

    def stage_component(self, stage: str | None = None, checkpoint: Path | None = None) -> Any:
        return make_vmp(VmpParams(**TINY), skeleton=self.skeleton, checkpoint=checkpoint)

    def build(self, path: str, **kwargs: Any) -> Any:
        assert path == "motions"
        return types.SimpleNamespace(load=lambda skeleton: self.motions)

    def should_stop(self) -> bool:
        self.calls += 1
        return self.stop_after is not None and self.calls >= self.stop_after

    def spec_yaml(self) -> str:
        return "name: fake\n"

    def publish(self, name: str) -> Path:
        path = self.workdir / "published" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path


def _run(ctx: FakeContext, params: SupervisedParams):
    try:
        return SupervisedTrainer(params).run(ctx)
    finally:
        ctx.log.close()


def test_tiny_training_reduces_reconstruction(amp, walk, tmp_path):
    params = SupervisedParams(num_iterations=100, batch_size=32, lr=1e-2, sgdr_t0=1000, checkpoint_every=50, print_every=50)
    ctx = FakeContext(tmp_path, amp, walk)
    result = _run(ctx, params)
    recs = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in recs] == list(range(1, 101))
    first = np.mean([r["rec_loss"] for r in recs[:5]])
    last = np.mean([r["rec_loss"] for r in recs[-5:]])
    assert last < 0.7 * first, (first, last)
    assert result.checkpoint == tmp_path / "vae.pt" and result.metrics["steps"] == 100
    table = (tmp_path / "published" / "vmp_reconstruction.md").read_text()
    assert "| walk | 39 |" in table and "q MAE" in table
    loaded = make_vmp(VmpParams(**TINY), skeleton=amp, checkpoint=result.checkpoint)
    assert loaded.frame_latents.shape == (39, 8) and loaded.clip_names == ["walk"]
    lib = MotionLibrary(walk, amp)
    assert torch.allclose(loaded.encode_library(lib), loaded.frame_latents, atol=1e-5)
    assert not torch.allclose(loaded.feat_std, torch.ones_like(loaded.feat_std))  # statistics saved
    with pytest.raises(ValueError, match="does not match"):
        make_vmp(VmpParams(**{**TINY, "channels": 8}), skeleton=amp, checkpoint=result.checkpoint)


def test_exact_resume(amp, walk, tmp_path):
    params = SupervisedParams(num_iterations=12, batch_size=8, checkpoint_every=100, sgdr_t0=5, sgdr_t_mult=2, kl_cycles=3)
    a = _run(FakeContext(tmp_path / "a", amp, walk), params)
    ctx = FakeContext(tmp_path / "b", amp, walk, stop_after=5)
    stopped = _run(ctx, params)
    assert stopped.checkpoint == tmp_path / "b" / "vmp.pt" and stopped.metrics["steps"] == 5
    b = _run(FakeContext(tmp_path / "b", amp, walk), params)
    sa, sb = torch.load(a.checkpoint, weights_only=False), torch.load(b.checkpoint, weights_only=False)
    for k, v in sa["latent"].items():
        assert torch.equal(v, sb["latent"][k]), k
    assert torch.equal(sa["frame_latents"], sb["frame_latents"])
    la = [json.loads(x) for x in (tmp_path / "a" / "metrics.jsonl").read_text().splitlines()]
    lb = [json.loads(x) for x in (tmp_path / "b" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lb] == list(range(1, 13))
    assert [r["loss"] for r in la] == [r["loss"] for r in lb]
