"""The motion library's control-rate grid (:meth:`MotionLibrary.use_control_grid`): a lookup gives
what interpolation gives (to float32 rounding) at the grid times, everywhere the grid reaches, and falls back to
interpolation elsewhere (between grid times, past a looping clip's stored cycles, past a clip's end)."""

from __future__ import annotations

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap.motion.library import GRID_FIELDS, MotionLibrary
from mocap.motion.sources import MotionSet

DT = 1.0 / 30.0


@pytest.fixture(scope="module")
def libs(amp):
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource

    clips = DeepMimicSource(DeepMimicParams(clips=["walk", "backflip", "punch"])).load(amp)
    plain = MotionLibrary(clips.clips if isinstance(clips, MotionSet) else clips, amp)
    gridded = MotionLibrary(clips.clips if isinstance(clips, MotionSet) else clips, amp)
    assert gridded.use_control_grid(DT, steps_past_end=40)
    return plain, gridded


def _assert_same(a, b, atol=2e-6):
    """Equal up to float32 rounding (vectorized kernels round batches of different sizes differently)."""
    for name in GRID_FIELDS:
        torch.testing.assert_close(getattr(a, name), getattr(b, name), atol=atol, rtol=0, msg=name)
    assert torch.equal(a.clip_ids, b.clip_ids)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_grid_lookup_equals_interpolation(libs, data):
    plain, gridded = libs
    n = data.draw(st.integers(1, 12))
    clips = torch.tensor(data.draw(st.lists(st.integers(0, plain.num_clips - 1), min_size=n, max_size=n)))
    # grid steps up to well past every clip's end (walk loops: past the stored cycles too)
    steps = torch.tensor(data.draw(st.lists(st.integers(0, 200), min_size=n, max_size=n)), dtype=torch.float64)
    off_grid = torch.tensor(data.draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    t = steps * DT + torch.where(off_grid, 0.37 * DT, 0.0)
    _assert_same(gridded.frames(clips, t), plain.frames(clips, t))


def test_grid_covers_starts_and_episode_of_looping_clips(libs):
    plain, gridded = libs
    g = gridded._grid
    assert g is not None
    walk = plain.clip_index("walk")
    period_steps = int(float(plain._dur64[walk]) / DT + 1e-9)
    assert int(g.lengths[walk]) == period_steps + 1 + 40
    # a non-looping clip stores its grid times plus its end time (later times clamp to it)
    flip = plain.clip_index("punch")
    assert not bool(plain.loops[flip])
    assert int(g.lengths[flip]) == int(float(plain._dur64[flip]) / DT + 1e-9) + 2
    t = torch.tensor([float(plain.durations[flip]) + 5 * DT], dtype=torch.float64)
    _assert_same(gridded.frames(torch.tensor([flip]), t), plain.frames(torch.tensor([flip]), t))


def test_grid_lookup_never_aliases_the_table(libs):
    _, gridded = libs
    f = gridded.frames(torch.tensor([0]), torch.tensor([0.0], dtype=torch.float64))
    f.body_pos += 100.0
    again = gridded.frames(torch.tensor([0]), torch.tensor([0.0], dtype=torch.float64))
    assert float(again.body_pos.abs().max()) < 50.0


def test_grid_over_its_memory_budget_is_not_built(amp):
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource

    lib = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp), amp)
    assert not lib.use_control_grid(DT, max_bytes=1000)
    assert lib._grid is None
    assert lib.use_control_grid(DT)
    assert not lib.use_control_grid(None) and lib._grid is None
