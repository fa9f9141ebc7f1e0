"""The dead-code reset of the EMA vector quantizer (``mocap.quantizers``, module docstring "Dead-code
reset"): a code replaced by a batch residual e restarts its statistics at N = threshold and
m = threshold · e, so that it is a code with the weight of ``threshold`` samples: the next EMA step
keeps it where it was put, even when no sample uses it."""

from __future__ import annotations

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.quantizers import VectorQuantizer


@settings(max_examples=30, deadline=None, derandomize=True)
@given(k=st.integers(2, 12), d=st.integers(1, 6), threshold=st.floats(0.5, 8.0), decay=st.floats(0.5, 0.99), seed=st.integers(0, 10_000))
def test_a_reset_code_has_threshold_weight_and_stays_put_for_one_unused_ema_step(k, d, threshold, decay, seed):
    gen = torch.Generator().manual_seed(seed)
    vq = VectorQuantizer(d, k, decay=decay, eps=1e-12, dead_threshold=threshold).double()
    vq.set_codebook(torch.randn(k, d, generator=gen, dtype=torch.float64))
    sizes = torch.full((k,), threshold + 1.0, dtype=torch.float64)
    sizes[0] = threshold / 2  # code 0 is dead, the others alive
    vq.cluster_size.copy_(sizes)
    vq.embed_sum.copy_(vq.embed * sizes.unsqueeze(-1))
    x = 10.0 + torch.randn(3, d, generator=gen, dtype=torch.float64)  # far from every code
    dead = vq.reset_dead(x)
    assert dead.tolist() == [True] + [False] * (k - 1)
    put = vq.embed[0].clone()
    assert bool((x == put).all(-1).any())  # the new code is a batch row
    torch.testing.assert_close(vq.cluster_size[0], torch.tensor(threshold, dtype=torch.float64))
    torch.testing.assert_close(vq.embed_sum[0], threshold * put)
    # one EMA step in which no sample picks code 0: every sample sits on code 1
    batch = vq.embed[1].expand(5, d).clone()
    idx = vq.nearest(batch)
    assert bool((idx == 1).all())
    vq.ema_update(batch, idx)
    torch.testing.assert_close(vq.cluster_size[0], torch.tensor(decay * threshold, dtype=torch.float64))
    torch.testing.assert_close(vq.embed[0], put, rtol=1e-9, atol=1e-9)
