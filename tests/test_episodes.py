"""The shared episode layer (mocap.episodes): named weighted rewards, named terminations, reference
starts and the end-of-step protocol every env uses."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.episodes import EpisodeBook, ReferenceStarts, RewardTerms, TerminationTerms

weights_st = st.dictionaries(st.sampled_from(["a", "b", "c", "d"]), st.floats(-5, 5, allow_nan=False), min_size=1)


@settings(max_examples=60, deadline=None)
@given(weights=weights_st, seed=st.integers(0, 10_000))
def test_reward_is_the_weighted_sum_of_the_named_terms_and_each_term_is_logged_unweighted(weights, seed):
    g = torch.Generator().manual_seed(seed)
    terms = {k: torch.randn(7, generator=g, dtype=torch.float64) for k in weights}
    total, info = RewardTerms(weights)(terms)
    expected = sum(w * terms[k] for k, w in weights.items())
    torch.testing.assert_close(total, expected, rtol=1e-12, atol=1e-12)
    assert set(info) == {f"reward/{k}" for k in weights}
    for k in weights:
        assert torch.equal(info[f"reward/{k}"], terms[k])


def test_unstable_or_non_finite_steps_get_zero_reward():
    terms = {"a": torch.tensor([1.0, float("nan"), 2.0, 3.0]), "b": torch.tensor([1.0, 1.0, float("inf"), 1.0])}
    total, _ = RewardTerms({"a": 1.0, "b": 0.5})(terms, unstable=torch.tensor([False, False, False, True]))
    assert total.tolist() == [1.5, 0.0, 0.0, 0.0]
    raw = RewardTerms({"a": 1.0, "b": 0.5}).weighted_sum(terms)  # before zeroing: what an env ends episodes on
    assert raw[0] == 1.5 and raw[1].isnan() and raw[2].isinf() and raw[3] == 3.5


def test_spec_overrides_replace_declared_weights_and_unknown_names_are_refused():
    rt = RewardTerms({"imitation": 1.0, "energy": 1.0}, {"energy": 0.25})
    assert rt.weights == {"imitation": 1.0, "energy": 0.25}
    total, _ = rt({"imitation": torch.tensor([1.0]), "energy": torch.tensor([-2.0])})
    assert total.item() == pytest.approx(0.5)
    with pytest.raises(ValueError, match="unknown term.*amp.*the terms are imitation, energy"):
        RewardTerms({"imitation": 1.0, "energy": 1.0}, {"amp": 0.5}, owner="phc.reward_terms")


def test_terms_that_do_not_match_the_declaration_are_an_error():
    with pytest.raises(ValueError, match="missing \\['b'\\]"):
        RewardTerms({"a": 1.0, "b": 1.0})({"a": torch.zeros(2)})
    with pytest.raises(ValueError, match="do not match"):
        TerminationTerms(("x",))({"y": torch.zeros(2, dtype=torch.bool)})


@settings(max_examples=40, deadline=None)
@given(bits=st.lists(st.tuples(st.booleans(), st.booleans(), st.booleans()), min_size=1, max_size=12), off=st.booleans())
def test_termination_is_the_or_of_the_enabled_terms_and_each_is_logged(bits, off):
    x = torch.tensor([b[0] for b in bits])
    y = torch.tensor([b[1] for b in bits])
    z = torch.tensor([b[2] for b in bits])
    tt = TerminationTerms(("x", "y", "z"), {"y": False} if off else None)
    done, info = tt({"x": x, "y": y, "z": z})
    assert torch.equal(done, x | z if off else x | y | z)
    assert torch.equal(info["terminated/y"], y.float())  # logged even when switched off


class _Lib:
    """The slice of MotionLibrary that ReferenceStarts uses: three clips, one looping."""

    device = torch.device("cpu")
    clip_names = ["a", "b", "c"]
    durations = torch.tensor([1.0, 0.05, 2.0], dtype=torch.float64)
    durations64 = durations
    loops = torch.tensor([False, False, True])

    def sample(self, n, generator=None):
        ids = torch.randint(0, 3, (n,), generator=generator)
        return ids, torch.rand(n, generator=generator, dtype=torch.float64) * self.durations[ids]


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), grid=st.booleans(), loops=st.booleans())
def test_reference_starts_leave_a_step_in_non_looping_clips_and_sit_on_the_control_grid(seed, grid, loops):
    dt = 1.0 / 30.0
    rs = ReferenceStarts(_Lib(), dt, control_grid=grid, loops=loops)  # type: ignore[arg-type]
    clips, t0 = rs.sample(200, torch.Generator().manual_seed(seed))
    dur = _Lib.durations[clips]
    looping = _Lib.loops[clips] & loops
    assert bool((t0 >= 0).all())
    assert bool((t0[~looping] <= (dur[~looping] - dt).clamp_min(0) + 1e-9).all())
    assert bool((t0[looping] < dur[looping] + 1e-9).all())
    if grid:
        j = t0 / dt
        assert torch.allclose(j, j.round(), atol=1e-6)
    # the clip-end rule: a non-looping clip is over past its duration, a looping one never
    assert torch.equal(rs.clip_over(clips, dur + 0.01), ~looping)


def test_conclude_resets_finished_envs_reports_their_episodes_and_keeps_final_obs():
    book = EpisodeBook(4)
    resets: list[list[int]] = []
    state = torch.arange(4, dtype=torch.float32)

    def observe(ids):
        return (state if ids is None else state[ids])[:, None].clone()

    def reset(ids):
        resets.append(ids.tolist())
        state[ids] = -1.0
        book.start(ids)

    for _ in range(3):
        res = book.conclude(torch.ones(4), torch.zeros(4, dtype=torch.bool), torch.zeros(4, dtype=torch.bool), observe, reset)
    assert res.episodes == {} and book.steps.tolist() == [3, 3, 3, 3]
    term = torch.tensor([True, False, True, False])
    trunc = torch.tensor([True, True, False, False])  # env 0 both: it terminated
    res = book.conclude(torch.full((4,), 0.5), term, trunc, observe, reset, on_finish=lambda ids, t: {"n": t.float()})
    assert resets == [[0, 1, 2]]
    assert res.terminated.tolist() == [True, False, True, False] and res.truncated.tolist() == [False, True, False, False]
    assert res.episodes["return"].tolist() == [3.5, 3.5, 3.5] and res.episodes["length"].tolist() == [4, 4, 4]
    assert res.episodes["success"].tolist() == [0.0, 1.0, 0.0] and res.episodes["n"].tolist() == [1.0, 0.0, 1.0]
    assert res.final_obs[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0]  # before the reset
    assert res.obs[:, 0].tolist() == [-1.0, -1.0, -1.0, 3.0]  # the reset envs' first observation
    assert book.steps.tolist() == [0, 0, 0, 4]


def test_episode_book_state_round_trips_and_refuses_another_env_count():
    book = EpisodeBook(3)
    book.tick()
    book.returns += torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    other = EpisodeBook(3)
    other.load_state_dict(book.state_dict())
    assert torch.equal(other.steps, book.steps) and torch.equal(other.returns, book.returns)
    with pytest.raises(ValueError, match="expected \\(2,\\)"):
        EpisodeBook(2).load_state_dict(book.state_dict())


def test_reference_starts_reach_the_last_start_frame_of_every_bundled_clip(amp):
    """The clamp at ``duration - dt`` and the grid compare float64 durations: with the library's
    float32 durations, clips whose duration rounds down never started at their last frame pair."""
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins

    lib = MotionLibrary(get_plugins().get("motion_source", "deepmimic").build(None).load(amp), amp)
    dt = 1.0 / 30.0
    rs = ReferenceStarts(lib, dt, control_grid=True, loops=False)
    dur = lib.durations64
    rounded_down = (lib.durations.double() < dur).tolist()
    assert any(rounded_down)  # the case the bug needs exists in the bundled clips
    clips, t0 = rs.sample(20_000, torch.Generator().manual_seed(0))
    for c in range(len(lib.clip_names)):
        last = torch.floor((dur[c] - dt) / dt + 1e-9) * dt
        got = t0[clips == c]
        assert got.numel() > 0 and torch.isclose(got.max(), last, atol=1e-9), (lib.clip_names[c], float(got.max()), float(last))
