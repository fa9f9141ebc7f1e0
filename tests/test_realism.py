"""The fixed realism judge (``mocap.realism``, issue 61): the committed judge scores the motion data
high and spoilt motion low, worse with more noise; it round-trips through its file; the naturalness
recorder and task-eval report its score."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from test_naturalness import DT, clip_frames, noisy, setup  # noqa: F401  (fixture)

from mocap.errors import CheckpointError
from mocap.naturalness import NaturalnessRecorder
from mocap.realism import RealismJudge, default_judge_path, load_judge, real_transitions, save_judge, spoilt_transitions, transitions

JUDGE = default_judge_path()
needs_judge = pytest.mark.skipif(not JUDGE.is_file(), reason="checkpoints/realism_judge/judge.pt is committed with the repository")


def test_spoilt_transitions_are_finite_features_of_the_data_shape(setup) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    _, lib, dataset = setup
    gen = torch.Generator().manual_seed(0)
    real, bad = real_transitions(lib, 50, DT, gen), spoilt_transitions(lib, 52, DT, gen)
    assert real.shape == (50, dataset.shape[1]) and bad.shape == (52, dataset.shape[1])
    assert bool(torch.isfinite(real).all()) and bool(torch.isfinite(bad).all())
    # the features are the motion-matching ones: a pair one control step apart is a dataset row
    walk = clip_frames(lib, "walk")
    row = transitions(walk[3], walk[4])[0]
    assert float((dataset - row).abs().max(-1).values.min()) < 1e-5


def test_a_judge_round_trips_through_its_file_and_a_wrong_file_is_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    torch.manual_seed(0)
    judge = RealismJudge(6, (8,), mean=torch.arange(6.0), std=torch.full((6,), 2.0))
    save_judge(tmp_path / "j.pt", judge)
    again = load_judge(tmp_path / "j.pt")
    x = torch.randn(10, 6)
    assert torch.equal(judge.score(x), again.score(x))
    torch.save({"format": "something/1"}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError):
        load_judge(tmp_path / "other.pt")


@needs_judge
def test_the_committed_judge_scores_data_high_and_spoilt_motion_low(setup) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    _, lib, _ = setup
    judge = load_judge(JUDGE)
    gen = torch.Generator().manual_seed(123)  # not the training stream
    real = float(judge.score(real_transitions(lib, 2000, DT, gen)).mean())
    bad = float(judge.score(spoilt_transitions(lib, 2000, DT, gen)).mean())
    assert real > 0.8 and bad < 0.3, (real, bad)


@needs_judge
def test_realism_of_a_replayed_clip_falls_with_noise_and_for_a_frozen_pose(setup) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    amp, lib, dataset = setup
    judge = load_judge(JUDGE)

    def realism(frames):  # type: ignore[no-untyped-def]
        rec = NaturalnessRecorder(amp, dataset, DT, judge=judge)
        for f in frames:
            rec.add(f)
        return rec.result()["realism"]

    walk = clip_frames(lib, "walk")
    scores = [realism(noisy(walk, sigma, seed=3)) for sigma in (0.0, 0.02, 0.05, 0.1)]
    assert scores[0] > 0.8 and all(a > b for a, b in zip(scores, scores[1:])), scores
    still = dataclasses.replace(walk[10], body_lin_vel=torch.zeros_like(walk[10].body_lin_vel), body_ang_vel=torch.zeros_like(walk[10].body_ang_vel))
    assert realism([still] * 20) < scores[0] - 0.3
    rec = NaturalnessRecorder(amp, dataset, DT)  # no judge: no realism key
    for f in walk[:3]:
        rec.add(f)
    assert "realism" not in rec.result() and not math.isnan(rec.result()["mm_distance"])
