"""The amp humanoid's ``shoulder_turns`` and what goes with it: hinges that may wind more than a
turn, the motion library's per-cycle DoF winding of looping clips for them, and scratch's action
map over one turn. The bug it fixes: at +-180 deg the bundled clips' unwrapped shoulder references
leave the hinge range (the PD target is clamped there), in five of the six clips v4 failed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.humanoids import AmpParams, make_amp
from mocap.humanoids.amp import FREE_SHOULDER_TURNS, amp_skeleton
from mocap.kinematics import local_rotations_from_dofs
from mocap.motion.clip import Clip
from mocap.motion.deepmimic import DeepMimicSource
from mocap.motion.library import MotionLibrary
from mocap.task_env import ScratchLatent
from mocap.hierarchy import ScratchParams

SHOULDER_YZ = ("right_shoulder_y", "right_shoulder_z", "left_shoulder_y", "left_shoulder_z")


@pytest.fixture(scope="module")
def free():
    return amp_skeleton(shoulder_turns=FREE_SHOULDER_TURNS)


def _ranges(skeleton) -> tuple[torch.Tensor, torch.Tensor]:
    lo = torch.tensor([h.range[0] for h in skeleton.hinges], dtype=torch.float64)
    hi = torch.tensor([h.range[1] for h in skeleton.hinges], dtype=torch.float64)
    return lo, hi


def test_shoulder_turns_sets_only_the_shoulders_y_and_z(amp, free):
    assert AmpParams().shoulder_turns == 0.5
    assert make_amp(AmpParams()).hinges == amp.hinges  # the default humanoid is unchanged
    for a, b in zip(amp.hinges, free.hinges):
        if a.name in SHOULDER_YZ:
            assert a.range == (-math.pi, math.pi)
            assert b.range == pytest.approx((-16 * math.pi, 16 * math.pi))
        else:
            assert a == b


def test_shoulder_order_xzy(amp):
    xzy = amp_skeleton(shoulder_turns=FREE_SHOULDER_TURNS, shoulder_order="xzy")
    names = list(xzy.dof_names)
    i = names.index("right_shoulder_x")
    assert names[i : i + 3] == ["right_shoulder_x", "right_shoulder_z", "right_shoulder_y"]
    ranges = {h.name: h.range for h in xzy.hinges}
    assert ranges["left_shoulder_z"] == pytest.approx((-math.pi / 2, math.pi / 2))
    assert ranges["left_shoulder_x"] == pytest.approx((-16 * math.pi, 16 * math.pi))
    others = [h for h in xzy.hinges if "shoulder" not in h.name]
    assert others == [h for h in amp.hinges if "shoulder" not in h.name]
    with pytest.raises(ValueError, match="shoulder_order"):
        amp_skeleton(shoulder_order="zyx")


def _shoulder_speed(skeleton) -> dict[str, float]:
    """Per bundled clip, the fastest shoulder hinge of the reference, rad/s."""
    lib = MotionLibrary(DeepMimicSource().load(skeleton), skeleton, dtype=torch.float64)
    cols = _shoulder_cols(skeleton)
    out = {}
    for c, name in enumerate(lib.clip_names):
        d = lib.dof_pos[lib.frame_clip == c][:, cols]
        out[name] = float(d.diff(dim=0).abs().max() * lib.fps[c])
    return out


def test_xzy_shoulders_ask_for_slower_references(amp):
    """yxz passes near its singularity (an arm raised sideways): up to 81 rad/s; xzy at most 35."""
    yxz = _shoulder_speed(amp)
    xzy = _shoulder_speed(amp_skeleton(shoulder_order="xzy"))
    assert max(yxz.values()) > 75.0
    assert max(xzy.values()) < 35.0
    assert sum(v > 25.0 for v in yxz.values()) >= 6 and sum(v > 25.0 for v in xzy.values()) <= 2


def _shoulder_cols(skeleton) -> list[int]:
    return [i for i, h in enumerate(skeleton.hinges) if "shoulder" in h.name]


def test_bundled_shoulder_references_fit_the_free_shoulders_only(amp, free):
    """The bug: with +-180 deg shoulders, the reference leaves the range in six clips (and the PD
    target is clamped there); with free shoulders no shoulder reference does."""
    outside = {}
    for skeleton in (amp, free):
        lib = MotionLibrary(DeepMimicSource().load(skeleton), skeleton, dtype=torch.float64)
        lo, hi = _ranges(skeleton)
        cols = _shoulder_cols(skeleton)
        out = ((lib.dof_pos < lo) | (lib.dof_pos > hi))[:, cols].any(1)
        outside[skeleton is free] = {lib.clip_names[c] for c in lib.frame_clip[out].unique().tolist()}
    assert outside[False] == {"punch", "spinkick", "backflip", "dance_a", "dance_b", "spin"}
    assert outside[True] == set()
    xzy = amp_skeleton(shoulder_turns=FREE_SHOULDER_TURNS, shoulder_order="xzy")
    lib = MotionLibrary(DeepMimicSource().load(xzy), xzy, dtype=torch.float64)
    lo, hi = _ranges(xzy)
    assert not bool(((lib.dof_pos < lo) | (lib.dof_pos > hi))[:, _shoulder_cols(xzy)].any())


def test_bundled_references_are_the_same_motion_on_both_humanoids(amp, free):
    """Only the hinge ranges differ: DoFs, bodies and cycle-0 frames are identical."""
    a = MotionLibrary(DeepMimicSource().load(amp), amp, dtype=torch.float64)
    b = MotionLibrary(DeepMimicSource().load(free), free, dtype=torch.float64)
    torch.testing.assert_close(a.dof_pos, b.dof_pos)
    torch.testing.assert_close(a.body_pos, b.body_pos)
    # in the other hinge order the DoFs differ, but they reproduce the same bodies
    xzy = amp_skeleton(shoulder_turns=FREE_SHOULDER_TURNS, shoulder_order="xzy")
    c = MotionLibrary(DeepMimicSource().load(xzy), xzy, dtype=torch.float64)
    torch.testing.assert_close(c.body_pos, a.body_pos, atol=1e-9, rtol=0)
    assert not bool(a.cycle_dof_winding.any())  # one-turn hinges never wind
    winding = {b.clip_names[c] for c in range(b.num_clips) if bool(b.cycle_dof_winding[c].any())}
    assert winding == {"spinkick", "backflip", "dance_a", "dance_b", "spin"}
    assert bool(b.loops[[b.clip_index(n) for n in winding]].all())
    turns = b.cycle_dof_winding / (2 * math.pi)
    torch.testing.assert_close(turns, turns.round())


def _winding_clip(skeleton, turns: int, frames: int, loop: bool = True) -> Clip:
    """A looping clip whose right upper arm twists about its own axis (z) by ``turns`` full turns per cycle."""
    joint_rot = np.tile([1.0, 0.0, 0.0, 0.0], (frames, skeleton.num_bodies - 1, 1))
    angle = np.linspace(0.0, 2 * math.pi * turns, frames)
    joint_rot[:, skeleton.body_index("right_upper_arm") - 1] = np.stack([np.cos(angle / 2), 0 * angle, 0 * angle, np.sin(angle / 2)], -1)
    root = np.tile([0.0, 0.0, 0.9], (frames, 1))
    return Clip("twirl", "amp", 30.0, root, np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1)), joint_rot, loop=loop)


@settings(max_examples=25, deadline=None)
@given(turns=st.sampled_from([-2, -1, 1, 2]), frames=st.integers(13, 40), k=st.integers(-3, 3), u=st.floats(0.0, 0.999))
def test_looping_winding_continues_per_cycle(turns, frames, k, u):
    free = amp_skeleton(shoulder_turns=FREE_SHOULDER_TURNS)
    lib = MotionLibrary([_winding_clip(free, turns, frames)], free, dtype=torch.float64)
    col = free.dof_names.index("right_shoulder_z")
    wind = float(lib.cycle_dof_winding[0, col])
    assert wind == pytest.approx(2 * math.pi * turns)
    d = float(lib.durations64[0])
    c = torch.zeros(2, dtype=torch.long)
    f = lib.frames(c, torch.tensor([u * d, (k + u) * d], dtype=torch.float64))
    assert float(f.dof_pos[1, col] - f.dof_pos[0, col]) == pytest.approx(k * wind, abs=1e-9)
    # the same rotation either way (whole turns), and the same bodies
    q0, q1 = local_rotations_from_dofs(free, f.dof_pos)
    assert float((q0 * q1).sum(-1).abs().min()) == pytest.approx(1.0, abs=1e-9)
    torch.testing.assert_close(f.body_pos[1] - f.body_pos[1, :1], f.body_pos[0] - f.body_pos[0, :1])
    # continuous across the cycle boundary (the last frame is the next cycle's first)
    g = lib.frames(c, torch.tensor([d - 1e-7, d + 1e-7], dtype=torch.float64))
    assert float((g.dof_pos[1] - g.dof_pos[0]).abs().max()) < 1e-4


def test_winding_needs_a_loop_and_a_hinge_wider_than_a_turn(amp, free):
    for skeleton, loop, wind in ((amp, True, False), (free, False, False), (free, True, True)):
        lib = MotionLibrary([_winding_clip(skeleton, 1, 20, loop=loop)], skeleton, dtype=torch.float64)
        assert bool(lib.cycle_dof_winding.any()) is wind
        d = float(lib.durations64[0])
        f = lib.frames(torch.zeros(2, dtype=torch.long), torch.tensor([0.3 * d, 2.3 * d], dtype=torch.float64))
        jump = float((f.dof_pos[1] - f.dof_pos[0]).abs().max())
        # looping: two whole cycles later, wound twice or restarted; not looping: clamped to the last frame
        expected = 4 * math.pi if wind else (0.0 if loop else 0.7 * 2 * math.pi)
        assert jump == pytest.approx(expected, abs=1e-9)


def test_control_grid_carries_the_winding(free):
    lib = MotionLibrary([_winding_clip(free, 1, 20)], free, dtype=torch.float64)
    d = float(lib.durations64[0])
    dt = 1.0 / 30.0
    times = torch.arange(0, 40, dtype=torch.float64) * dt
    exact = lib.frames(torch.zeros(40, dtype=torch.long), times)
    assert lib.use_control_grid(dt, steps_past_end=25)
    grid = lib.frames(torch.zeros(40, dtype=torch.long), times)
    torch.testing.assert_close(grid.dof_pos, exact.dof_pos)
    assert float(grid.dof_pos[-1, free.dof_names.index("right_shoulder_z")]) > 2 * math.pi * (39 * dt / d) - 0.5


def test_scratch_maps_a_free_hinge_over_one_turn(amp, free):
    params = ScratchParams()
    old, new = ScratchLatent(params, amp), ScratchLatent(params, free)
    cols = [free.dof_names.index(n) for n in SHOULDER_YZ]
    others = [i for i in range(free.num_dofs) if i not in cols]
    torch.testing.assert_close(new.offset[others], old.offset[others])
    torch.testing.assert_close(new.scale[others], old.scale[others])
    # the free hinges get the +-180 deg shoulders' map
    torch.testing.assert_close(new.offset[cols], old.offset[cols])
    torch.testing.assert_close(new.scale[cols], old.scale[cols])


# ------------------------------------------------------------------ checkpoint humanoid params
def _checkpoint(tmp_path, spec_yaml: str | None):
    from mocap.checkpoint import save_checkpoint

    path = tmp_path / "policy.pt"
    save_checkpoint(path, {"format": "toy/1"}, spec_yaml=spec_yaml)
    return path


def test_checkpoint_on_other_humanoid_params_is_refused(tmp_path, amp, free):
    from mocap.checkpoint import CheckpointError
    from mocap.eval_targets import check_trained_humanoid
    from mocap.plugins import get_plugins

    plugins = get_plugins()
    trained_free = _checkpoint(tmp_path, "humanoid:\n  name: amp\n  params: {shoulder_turns: 8.0}\n")
    check_trained_humanoid(trained_free, free, plugins)  # the same humanoid: accepted
    with pytest.raises(CheckpointError, match=r"shoulder_turns: 8\.0.*right_shoulder_y\.range"):
        check_trained_humanoid(trained_free, amp, plugins)
    # omitted params are the defaults, and a checkpoint without a spec is not judged
    (tmp_path / "d").mkdir()
    default = _checkpoint(tmp_path / "d", "humanoid: {name: amp}\n")
    check_trained_humanoid(default, amp, plugins)
    with pytest.raises(CheckpointError, match="the defaults"):
        check_trained_humanoid(default, free, plugins)
    (tmp_path / "n").mkdir()
    check_trained_humanoid(_checkpoint(tmp_path / "n", None), free, plugins)


def test_skeleton_difference_names_what_differs(amp):
    from mocap.humanoid_match import skeleton_difference

    assert skeleton_difference(amp, amp) == ""
    stiff = amp_skeleton(gain_scale=2.0)
    text = skeleton_difference(amp, stiff, limit=2)
    assert text.startswith("chest_y.kp") and text.endswith("more")
    assert "friction" in skeleton_difference(amp, amp_skeleton(friction=0.5))
