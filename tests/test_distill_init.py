"""Continuing a distillation: the distill trainer's ``init_latent`` (start from a latent file's
weights) and ``lr_end`` (a linear learning-rate decay over the stage's progress)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.checkpoint import CheckpointError
from mocap.distill_files import init_from_latent, load_latent_state
from mocap.distill_params import DistillParams, distill_lr
from mocap.export import relative_spec_text
from mocap_pulse.latent import PulseParams, make_pulse
from test_distill import STUDENT, FakeContext, records, run, teacher_file, walk  # noqa: F401  (fixtures)


# ----------------------------------------------------------------------------------- the schedule
@settings(max_examples=200, deadline=None)
@given(
    lr=st.floats(1e-6, 1e-2),
    end=st.floats(1e-7, 1e-2),
    a=st.floats(-0.5, 1.5),
    b=st.floats(-0.5, 1.5),
)
def test_distill_lr_is_linear_between_its_ends_and_constant_without_one(lr, end, a, b):
    assert distill_lr(0.0, lr, end) == pytest.approx(lr) and distill_lr(1.0, lr, end) == pytest.approx(end)
    assert distill_lr(a, lr, None) == lr  # no decay: the rate of the paper and the code
    lo, hi = sorted((a, b))
    x, y = distill_lr(lo, lr, end), distill_lr(hi, lr, end)
    assert min(lr, end) - 1e-12 <= x <= max(lr, end) + 1e-12  # clamped outside [0, 1]
    if end <= lr:
        assert y <= x + 1e-15  # a decay never rises with progress
    mid = min(max(lo, 0.0), 1.0)
    assert x == pytest.approx(lr + (end - lr) * mid, rel=1e-9, abs=1e-15)


# ----------------------------------------------------------------------------------- init_latent
def test_init_from_latent_copies_every_tensor_and_refuses_another_architecture(amp, walk, teacher_file, tmp_path):  # noqa: F811
    params = DistillParams(num_envs=4, horizon=8, total_env_steps=4 * 8 * 2, minibatch_envs=2, eval_every=0)
    trained = run(FakeContext(tmp_path / "a", amp, walk, teacher_file), params).checkpoint
    fresh = make_pulse(PulseParams(**STUDENT), skeleton=amp)
    saved = load_latent_state(trained)["state_dict"]
    assert any(not torch.equal(v, saved[k]) for k, v in fresh.state_dict().items() if isinstance(v, torch.Tensor))
    init_from_latent(fresh, trained)
    assert all(torch.equal(v, saved[k]) for k, v in fresh.state_dict().items() if isinstance(v, torch.Tensor))

    wider = make_pulse(PulseParams(**{**STUDENT, "decoder_hidden": [64, 32]}), skeleton=amp)
    with pytest.raises(CheckpointError, match=r"init_latent does not fit.*3 differing tensors: dec\.2\.bias"):
        init_from_latent(wider, trained)
    with pytest.raises(CheckpointError, match="does not exist"):
        init_from_latent(fresh, tmp_path / "missing.pt")


def test_a_continued_distillation_starts_from_the_file_and_decays_its_rate(amp, walk, teacher_file, tmp_path):  # noqa: F811
    """The first stage's latent.pt is the second's start: with no update (lr 0 throughout) the
    second stage ends with exactly the first one's weights; with lr_end the logged rate falls
    linearly over the stage's own progress."""
    base = DistillParams(num_envs=4, horizon=8, total_env_steps=4 * 8 * 3, minibatch_envs=2, eval_every=0)
    first = run(FakeContext(tmp_path / "first", amp, walk, teacher_file), base).checkpoint
    frozen = base.model_copy(update={"init_latent": first, "lr": 1e-12, "lr_end": 1e-12, "max_grad_norm": 1e-12})
    ctx = FakeContext(tmp_path / "frozen", amp, walk, teacher_file)
    second = run(ctx, frozen).checkpoint
    a, b = load_latent_state(first)["state_dict"], load_latent_state(second)["state_dict"]
    for key, value in a.items():
        if isinstance(value, torch.Tensor) and value.is_floating_point() and "norm" not in key:
            assert torch.allclose(value, b[key], atol=1e-6), key
    assert "starting from" in ctx.console.file.getvalue()

    decayed = base.model_copy(update={"total_env_steps": 4 * 8 * 4, "init_latent": first, "lr": 1e-3, "lr_end": 1e-4})
    run(FakeContext(tmp_path / "decayed", amp, walk, teacher_file), decayed)
    lrs = [r["lr"] for r in records(tmp_path / "decayed")]
    assert lrs == pytest.approx([1e-3 + (1e-4 - 1e-3) * k / 4 for k in range(4)])


def test_a_wrong_init_latent_is_one_stage_error(amp, walk, teacher_file, tmp_path):  # noqa: F811
    from mocap.errors import StageFailed

    params = DistillParams(num_envs=2, horizon=2, total_env_steps=4, minibatch_envs=2, eval_every=0, init_latent=tmp_path / "nope.pt")
    with pytest.raises(StageFailed, match="nope.pt: init_latent does not exist"):
        run(FakeContext(tmp_path, amp, walk, teacher_file), params)


def test_export_makes_init_latent_relative(tmp_path):
    text = "latent:\n  name: pulse\n  trainer:\n    name: distill\n    params:\n      init_latent: /abs/x/checkpoints/p/latent.pt\n"
    out = relative_spec_text(text, tmp_path / "dest", root_map=("/abs/x/", str(tmp_path) + "/"))
    assert "init_latent: ../checkpoints/p/latent.pt" in out


def test_init_latent_is_resolved_against_the_spec_file(tmp_path):
    from mocap.spec import resolve_relative_paths

    p = resolve_relative_paths(DistillParams(init_latent=Path("../ck/latent.pt")), tmp_path / "specs")
    assert isinstance(p, DistillParams) and p.init_latent == (tmp_path / "ck" / "latent.pt").resolve()
