"""Noisy references (mocap.noisy): the noise model's statistics, dropped frames, and the protocol."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.noisy import DEFAULT_LEVELS, NoiseLevel, delivered_frames, noisy_clip, noisy_library, parse_levels
from mocap.plugins import get_plugins
from mocap.rotations import quat_conjugate, quat_mul, quat_to_rotvec


@pytest.fixture(scope="module")
def amp():
    plugins = get_plugins()
    skeleton = plugins.get("humanoid", "amp").build({})
    clips = plugins.get("motion_source", "deepmimic").build({"clips": ["walk", "kick"]}).load(skeleton).clips
    return skeleton, clips


@given(st.integers(1, 300), st.floats(0.0, 0.95), st.integers(0, 2**31 - 1))
@settings(max_examples=60, deadline=None)
def test_delivered_frames_hold_the_last_delivered_one(n, p, seed):
    idx = delivered_frames(n, p, np.random.default_rng(seed))
    assert idx.shape == (n,) and idx[0] == 0
    for k in range(1, n):  # each frame is itself (delivered) or the previous delivered one (lost)
        assert idx[k] == k or idx[k] == idx[k - 1]
    assert np.all(np.diff(idx) >= 0)
    if p == 0:
        assert np.array_equal(idx, np.arange(n))


def test_dropped_share_matches_probability():
    idx = delivered_frames(200_000, 0.1, np.random.default_rng(0))
    lost = np.mean(idx[1:] != np.arange(1, 200_000))
    assert abs(lost - 0.1) < 0.005


def test_level_zero_is_the_clean_clip(amp):
    _, clips = amp
    assert noisy_clip(clips[0], NoiseLevel(), np.random.default_rng(0)) is clips[0]


def test_joint_jitter_has_the_stated_std(amp):
    """log(q_noisy q_clean^-1) per component ~ N(0, sigma^2): sample std within 5%, mean ~ 0."""
    _, clips = amp
    clip = clips[1]
    level = NoiseLevel(joint_deg=5.0)
    noisy = noisy_clip(clip, level, np.random.default_rng(1))
    assert np.array_equal(noisy.root_pos, clip.root_pos) and np.allclose(noisy.root_rot, clip.root_rot)
    d = quat_to_rotvec(quat_mul(torch.from_numpy(noisy.joint_rot), quat_conjugate(torch.from_numpy(clip.joint_rot)))).numpy()
    sigma = math.radians(5.0)
    assert abs(d.std() / sigma - 1.0) < 0.05
    assert abs(d.mean()) < 0.05 * sigma
    assert np.allclose(np.linalg.norm(noisy.joint_rot, axis=-1), 1.0)


def test_root_jitter_and_drops(amp):
    _, clips = amp
    clip = clips[1]  # kick: not looping
    level = NoiseLevel(root_m=0.05, root_deg=3.0, drop_prob=0.3)
    noisy = noisy_clip(clip, level, np.random.default_rng(2))
    assert noisy.num_frames == clip.num_frames
    held = np.all(noisy.root_pos[1:] == noisy.root_pos[:-1], axis=-1)  # a lost frame repeats the previous one
    assert 0.15 < held.mean() < 0.45
    fresh = np.concatenate(([True], ~held))
    dp = noisy.root_pos[fresh] - clip.root_pos[fresh]
    assert abs(dp.std() / 0.05 - 1.0) < 0.25  # std of the root jitter, on the delivered frames


def test_looping_clip_keeps_its_cycle_offset(amp):
    _, clips = amp
    walk = clips[0]
    assert walk.loop
    noisy = noisy_clip(walk, DEFAULT_LEVELS[3], np.random.default_rng(3))
    assert np.allclose(noisy.root_pos[-1] - noisy.root_pos[0], walk.root_pos[-1] - walk.root_pos[0])
    assert np.allclose(noisy.joint_rot[-1], noisy.joint_rot[0])
    assert not np.allclose(noisy.root_pos, walk.root_pos)


def test_parse_levels():
    assert parse_levels("0,3") == [DEFAULT_LEVELS[0], DEFAULT_LEVELS[3]]
    assert parse_levels("1:2:0.03:0.1") == [NoiseLevel(joint_deg=1, root_deg=2, root_m=0.03, drop_prob=0.1)]
    from mocap.cli import UserError

    for bad in ("7", "1:2", "a,b", "1:2:3:1.5"):
        with pytest.raises(UserError):
            parse_levels(bad)


def test_observed_library_changes_only_what_the_policy_sees(amp):
    """PD replay of the reference: with the clean library as `observed` the table is unchanged;
    with noisy references the errors (against the clean clip) grow."""
    from mocap.baselines import PDReplay
    from mocap.evaluation import ImitationEvalParams
    from mocap.imitation_eval import evaluate_imitator
    from mocap.metrics import default_metrics
    from mocap.motion.library import MotionLibrary

    skeleton, clips = amp
    plugins = get_plugins()
    lib = MotionLibrary(clips[:1], skeleton)
    sim_c = plugins.get("simulator", "mujoco")

    def make_sim(n):
        return sim_c.build({}, skeleton=skeleton, num_envs=n, seed=0)

    policy = PDReplay()
    params = ImitationEvalParams(num_envs=4, horizon=None, video=False)
    clean = evaluate_imitator(policy, lib, make_sim, params, default_metrics())
    same = evaluate_imitator(policy, lib, make_sim, params, default_metrics(), observed=MotionLibrary(clips[:1], skeleton))
    assert same["aggregate"]["mpjpe_g"] == pytest.approx(clean["aggregate"]["mpjpe_g"], rel=1e-6)
    noisy = evaluate_imitator(policy, lib, make_sim, params, default_metrics(), observed=noisy_library(lib, DEFAULT_LEVELS[3], 0))
    assert noisy["aggregate"]["mpjpe_l"] > clean["aggregate"]["mpjpe_l"] + 5.0


def _pd_replay_spec(tmp_path: Path) -> Path:
    spec = tmp_path / "spec.yaml"
    spec.write_text(
        "spec_version: 1\nname: noisy-cmd\nhumanoid: {name: amp}\n"
        "motions: {name: deepmimic, params: {clips: [walk]}}\nsimulator: {name: mujoco}\nimitator: {name: pd_replay}\n"
    )
    return spec


def test_eval_noisy_command(tmp_path: Path):
    from mocap.testing import invoke

    spec = _pd_replay_spec(tmp_path)
    out = tmp_path / "noisy.json"
    result = invoke(["eval-noisy", spec, "--levels", "0,2", "--json", out])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert [r["level"] for r in data["levels"]] == [0, 2]
    assert data["levels"][1]["noise"] == DEFAULT_LEVELS[2].model_dump()
    assert "MPJPE-g" in result.stdout
    bad = invoke(["eval-noisy", spec, "--levels", "9"])
    assert bad.exit_code == 2 and "Traceback" not in bad.output and "level 9" in bad.stderr


def _toy_clip(T: int, positions: np.ndarray, angles: np.ndarray, loop: bool = False):
    """A clip with 2 bodies: root at ``positions`` (T, 3), the child rotated ``angles`` (T,) about z."""
    from mocap.motion.clip import Clip

    joint = np.zeros((T, 1, 4))
    joint[:, 0, 0], joint[:, 0, 3] = np.cos(angles / 2), np.sin(angles / 2)
    root = np.tile([1.0, 0.0, 0.0, 0.0], (T, 1))
    return Clip("toy", "toy", 30.0, positions, root, joint, loop=loop)


@given(st.floats(0.05, 1.0), st.integers(2, 40), st.floats(-2.5, 2.5))
@settings(max_examples=40, deadline=None)
def test_smoothing_is_the_exponential_filter(alpha, T, theta):
    """A step from 0 to x at frame 1: after k frames the filter is at x (1 - (1 - a)^k), for the
    root position and for a rotation about a fixed axis (slerp is linear in the angle there)."""
    from mocap.noisy import smooth_clip

    pos = np.zeros((T, 3))
    pos[1:, 0] = 1.5
    ang = np.zeros(T)
    ang[1:] = theta
    out = smooth_clip(_toy_clip(T, pos, ang), alpha)
    k = np.arange(T)
    expect = np.where(k == 0, 0.0, 1.0 - (1.0 - alpha) ** k)
    assert np.allclose(out.root_pos[:, 0], 1.5 * expect, atol=1e-9)
    got = 2 * np.arctan2(out.joint_rot[:, 0, 3], out.joint_rot[:, 0, 0])
    assert np.allclose(got, theta * expect, atol=1e-6)


def test_smoothing_keeps_constant_clips_and_the_loop_wrap():
    from mocap.noisy import smooth_clip

    T = 10
    pos = np.tile([0.5, -0.2, 0.9], (T, 1))
    const = smooth_clip(_toy_clip(T, pos, np.full(T, 0.7)), 0.3)
    assert np.allclose(const.root_pos, pos) and np.allclose(2 * np.arctan2(const.joint_rot[:, 0, 3], const.joint_rot[:, 0, 0]), 0.7)
    walk = pos.copy()
    walk[:, 0] = np.linspace(0.0, 2.0, T)
    looped = smooth_clip(_toy_clip(T, walk, np.zeros(T), loop=True), 0.3)
    assert np.allclose(looped.root_pos[-1] - looped.root_pos[0], [2.0, 0.0, 0.0])
    assert looped.root_pos[-2, 0] < walk[-2, 0]  # it lags behind the ramp
    clip = _toy_clip(T, pos, np.zeros(T))
    assert smooth_clip(clip, 1.0) is clip
    with pytest.raises(ValueError):
        smooth_clip(clip, 0.0)


def test_velocity_override_smooths_what_the_policy_sees(amp):
    """`velocities="central_smoothed"`: the observed library's velocities are PHC's code's (the clean
    library keeps its own), and the root-velocity noise of a jittered stream falls several-fold."""
    from mocap.motion.library import MotionLibrary

    skeleton, clips = amp
    lib = MotionLibrary(clips[:1], skeleton)
    level = NoiseLevel(root_m=0.01)
    clean_v = lib.body_lin_vel[:, 0]
    raw = noisy_library(lib, level, 3)
    smoothed = noisy_library(lib, level, 3, velocities="central_smoothed", velocity_sigma=2.0)
    assert raw.velocities == "forward" and smoothed.velocities == "central_smoothed" and lib.velocities == "forward"
    err_raw = (raw.body_lin_vel[:, 0] - clean_v).norm(dim=-1).mean()
    err_smooth = (smoothed.body_lin_vel[:, 0] - clean_v).norm(dim=-1).mean()
    assert err_raw > 0.3  # 1 cm at 30 fps: ~0.4 m/s per axis pair through forward differences
    assert err_smooth < err_raw / 3


def test_eval_noisy_velocities_option(tmp_path: Path):
    from mocap.testing import invoke

    spec = _pd_replay_spec(tmp_path)
    out = tmp_path / "noisy.json"
    result = invoke(["eval-noisy", spec, "--levels", "0", "--velocities", "central_smoothed", "--json", out])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert data["velocities"] == "central_smoothed" and data["velocity_sigma"] == 2.0
    assert "velocities central_smoothed" in result.stdout
    bad = invoke(["eval-noisy", spec, "--velocities", "backward"])
    assert bad.exit_code != 0 and "Traceback" not in bad.output and "--velocities" in bad.stderr
