"""Naturalness metrics (``mocap.naturalness``, issue 61): every bundled clip replayed kinematically
scores best, scores get monotonically worse with noise, a frozen pose matches the data worse than a
walk, and each formula on hand-made motion (a cubic root path, a sliding foot, a low pelvis)."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.generation_eval import dataset_transitions
from mocap.motion.library import MotionLibrary
from mocap.naturalness import NaturalnessParams, NaturalnessRecorder, nearest_per_feature
from mocap.plugins import get_plugins
from mocap.state import HumanoidState

DT = 1.0 / 30.0


@pytest.fixture(scope="module")
def setup():  # type: ignore[no-untyped-def]
    plugins = get_plugins()
    amp = plugins.get("humanoid", "amp").build(None)
    lib = MotionLibrary(plugins.get("motion_source", "deepmimic").build(None).load(amp), amp)
    return amp, lib, dataset_transitions(lib, DT)


def clip_frames(lib: MotionLibrary, name: str) -> list[HumanoidState]:
    """The clip at the control rate from t = 0, one (1-env) state per frame: the frames the dataset holds."""
    c = lib.clip_index(name)
    n = int(math.floor(float(lib.durations[c]) / DT + 1e-6)) + 1
    frames = lib.frames(torch.full((n,), c, dtype=torch.long), torch.arange(n, dtype=torch.float64) * DT)
    return [frames.index(slice(i, i + 1)) for i in range(n)]


def noisy(frames: list[HumanoidState], sigma: float, seed: int) -> list[HumanoidState]:
    """Every body position (root included) moved by sigma x a fixed standard-normal draw per frame."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for f in frames:
        eps = torch.randn(f.body_pos.shape, generator=g, dtype=torch.float64).to(f.body_pos.dtype)
        body = f.body_pos + sigma * eps
        out.append(dataclasses.replace(f, body_pos=body, root_pos=body[:, 0].clone()))
    return out


def score(setup, frames: list[HumanoidState], params: NaturalnessParams | None = None) -> dict[str, float]:  # type: ignore[no-untyped-def]
    amp, _, dataset = setup
    rec = NaturalnessRecorder(amp, dataset, DT, params)
    for f in frames:
        rec.add(f)
    return rec.result()


def test_every_bundled_clip_replayed_scores_best(setup) -> None:  # type: ignore[no-untyped-def]
    _, lib, _ = setup
    for name in lib.clip_names:
        clean = score(setup, clip_frames(lib, name))
        assert clean["mm_distance"] == pytest.approx(0.0, abs=1e-6) and clean["mm_within"] == 1.0, name
        worse = score(setup, noisy(clip_frames(lib, name), 0.03, seed=1))
        assert worse["mm_distance"] > clean["mm_distance"] + 1e-3, name
        assert worse["root_jerk"] > clean["root_jerk"], name
        if not math.isnan(clean["foot_skating"]):
            assert worse["foot_skating"] > clean["foot_skating"], name


@settings(max_examples=6, deadline=None, derandomize=True)
@given(clip=st.sampled_from(["walk", "run", "punch", "dance_a"]), seed=st.integers(0, 1000))
def test_scores_get_worse_as_noise_grows(setup, clip: str, seed: int) -> None:  # type: ignore[no-untyped-def]
    _, lib, _ = setup
    frames = clip_frames(lib, clip)
    scores = [score(setup, noisy(frames, sigma, seed)) for sigma in (0.0, 0.01, 0.03, 0.1)]
    for key in ("mm_distance", "root_jerk", "foot_skating"):
        values = [s[key] for s in scores]
        assert all(a < b for a, b in zip(values, values[1:])), (key, values)
    within = [s["mm_within"] for s in scores]
    assert all(a >= b for a, b in zip(within, within[1:])) and within[-1] < within[0], within


def test_a_frozen_pose_matches_the_data_worse_than_a_walk(setup) -> None:  # type: ignore[no-untyped-def]
    _, lib, _ = setup
    walk = clip_frames(lib, "walk")
    still = dataclasses.replace(
        walk[10],
        body_lin_vel=torch.zeros_like(walk[10].body_lin_vel),
        body_ang_vel=torch.zeros_like(walk[10].body_ang_vel),
        root_lin_vel=torch.zeros_like(walk[10].root_lin_vel),
        root_ang_vel=torch.zeros_like(walk[10].root_ang_vel),
    )
    frozen = score(setup, [still] * len(walk))
    assert frozen["mm_distance"] > score(setup, walk)["mm_distance"] + 0.01
    assert frozen["root_jerk"] < 0.01 and frozen["foot_skating"] == 0.0  # frozen is smooth, just not like the data (float32 rounding)


def test_formulas_on_hand_made_motion(setup) -> None:  # type: ignore[no-untyped-def]
    """A root on x = a t³ has jerk 6a; a foot sliding in contact at v reads v; a pelvis below 0.8 x
    the rest height is crouched; a new episode breaks the windows and pairs."""
    amp, lib, _ = setup
    base = clip_frames(lib, "walk")[0]
    feet = [amp.body_names.index(f) for f in amp.feet]
    a, v = 0.7, 0.4
    frames = []
    for i in range(8):
        t = i * DT
        body = base.body_pos.clone()
        body[:, :, 0] += a * t**3  # the whole body moves on the cubic
        body[:, feet, 0] = base.body_pos[:, feet, 0] + v * t  # the feet slide at v instead
        body[:, feet, 2] = 0.05  # on the ground (rest height 0.05 m)
        frames.append(dataclasses.replace(base, body_pos=body, root_pos=body[:, 0].clone()))
    out = score(setup, frames)
    assert out["root_jerk"] == pytest.approx(6 * a, rel=1e-3)
    assert out["foot_skating"] == pytest.approx(v, rel=1e-4)
    assert out["crouch_share"] == 0.0  # the walk's pelvis is at about 0.86 m
    low = [dataclasses.replace(f, root_pos=f.root_pos - torch.tensor([0.0, 0.0, 0.3])) for f in frames]
    assert score(setup, low)["crouch_share"] == 1.0  # 0.56 m < 0.8 x 0.88 m
    lifted = [dataclasses.replace(f, body_pos=f.body_pos + torch.tensor([0.0, 0.0, 0.2])) for f in frames]
    assert math.isnan(score(setup, lifted)["foot_skating"])  # no foot on the ground
    # every frame a new episode: no pair, no window
    amp_, _, dataset = setup
    rec = NaturalnessRecorder(amp_, dataset, DT)
    for f in frames:
        rec.add(f, fresh=torch.ones(1, dtype=torch.bool))
    broken = rec.result()
    assert math.isnan(broken["mm_distance"]) and math.isnan(broken["root_jerk"]) and math.isnan(broken["foot_skating"])


@settings(max_examples=20, deadline=None, derandomize=True)
@given(features=st.integers(2, 12), seed=st.integers(0, 1000))
def test_nearest_per_feature_is_the_standardized_squared_distance_over_f(features: int, seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    data = torch.randn(30, features, generator=g, dtype=torch.float64)
    query = torch.randn(5, features, generator=g, dtype=torch.float64)
    z = lambda x: (x - data.mean(0)) / data.std(0)  # noqa: E731
    expect = ((z(query)[:, None] - z(data)[None]) ** 2).sum(-1).min(-1).values / features
    torch.testing.assert_close(nearest_per_feature(query, data), expect)
    torch.testing.assert_close(nearest_per_feature(data[:3], data), torch.zeros(3, dtype=torch.float64), rtol=0, atol=1e-12)
