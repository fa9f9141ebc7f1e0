"""The recovery-rate protocol (``mocap_phc.recovery_eval``, ``mocap recover``) and the fallen states it starts from."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from test_distill import walk  # noqa: F401  (fixture)

from mocap.interfaces import Imitator
from mocap.state import Observations
from mocap_phc.recovery import FailStateParams, generate_fall_states
from mocap_phc.recovery_eval import (
    RecoveryEvalParams,
    best_trial,
    evaluate_recovery,
    pick_clip,
    pick_still_frame,
    recovery_summary,
    still_reference,
)


def test_summary_counts_the_first_step_within_the_threshold():
    inf = 9.0
    err = torch.tensor(
        [
            [inf, inf, 0.1],  # step 0 (the fallen start) never counts
            [inf, inf, inf],
            [0.4, inf, inf],
            [0.6, 0.7, inf],
        ],
        dtype=torch.float64,
    )
    root = torch.tensor([[3.0, 3.0, 0.0], [2.0, 0.3, 3.0], [0.2, 3.0, 3.0], [0.2, 3.0, 3.0]], dtype=torch.float64)
    s = recovery_summary(err, root, dt=0.1, threshold=0.5)
    assert s["recovered"] == [True, False, False]
    assert s["recovery_rate"] == pytest.approx(1 / 3) and s["time_to_recover_s"] == pytest.approx(0.2)
    assert s["root_back_rate"] == pytest.approx(2 / 3) and s["tracking_at_end"] == 0.0
    assert math.isnan(recovery_summary(err[:, 1:2], root[:, 1:2], 0.1, 0.01)["time_to_recover_s"])


@given(st.integers(1, 6), st.integers(2, 12), st.floats(0.05, 2.0), st.integers(0, 2**31 - 1))
def test_summary_rates_are_monotone_in_the_threshold(n, t, thr, seed):
    g = torch.Generator().manual_seed(seed)
    err = torch.rand(t, n, generator=g, dtype=torch.float64) * 2
    root = torch.rand(t, n, generator=g, dtype=torch.float64) * 2
    lo, hi = recovery_summary(err, root, 0.1, thr), recovery_summary(err, root, 0.1, thr * 1.5)
    assert 0 <= lo["recovery_rate"] <= hi["recovery_rate"] <= 1
    assert lo["root_back_rate"] <= hi["root_back_rate"]


def test_pick_clip():
    assert pick_clip(["run", "walk"], [True, True], None) == 1
    assert pick_clip(["getup", "run"], [False, True], None) == 1
    assert pick_clip(["getup", "kick"], [False, False], None) == 0
    assert pick_clip(["getup", "kick"], [False, False], "kick") == 1
    with pytest.raises(ValueError, match="no clip 'spin'"):
        pick_clip(["getup", "kick"], [False, False], "spin")


class HoldPose(Imitator):
    """A stand-in policy: PD targets = the zero pose (it never gets up)."""

    def __init__(self, dofs: int):
        self.dofs = dofs

    def observe(self, state, ref):
        return Observations(proprio=state.dof_pos)

    def act(self, obs, deterministic=True):
        return torch.zeros(obs.proprio.shape[0], self.dofs)


def test_fallen_states_are_valid(amp):
    from mocap_sim_mujoco.simulator import MujocoSimulator

    sim = MujocoSimulator(skeleton=amp, num_envs=3, seed=0)
    try:
        s = generate_fall_states(sim, amp, 5, FailStateParams(settle_steps=45), torch.Generator().manual_seed(1))
    finally:
        sim.close()
    for name in ("root_pos", "root_rot", "dof_pos", "body_pos", "body_rot"):
        assert bool(torch.isfinite(getattr(s, name)).all()), name
    assert s.root_pos.shape == (5, 3)
    assert bool((s.root_pos[:, 2] < 0.5).all())  # on the ground (standing root height ~0.9 m)
    assert bool((s.body_pos[..., 2] > -0.05).all())  # no body origin sunk into the floor
    assert torch.allclose(torch.linalg.vector_norm(s.root_rot.double(), dim=-1), torch.ones(5, dtype=torch.float64), atol=1e-5)
    assert float(s.dof_vel.abs().max()) == 0.0 and float(s.root_lin_vel.abs().max()) == 0.0


def test_best_trial_is_the_first_to_recover_else_the_closest():
    inf = 9.0
    err = torch.tensor([[0.0, 0.0, 0.0], [inf, 0.7, inf], [inf, 0.6, 0.4], [0.3, 0.6, 0.4]], dtype=torch.float64)
    assert best_trial(err, 0.5) == 2  # recovers at step 2, trial 0 only at step 3; step 0 never counts
    assert best_trial(err, 0.2) == 0  # nobody within 0.2 m: trial 0 comes closest (0.3 m)
    assert best_trial(err[:, 1:2], 0.5) == 0


@given(st.integers(2, 6), st.integers(1, 8), st.integers(0, 2**31 - 1))
def test_best_trial_properties(t, n, seed):
    g = torch.Generator().manual_seed(seed)
    err = torch.rand(t, n, generator=g, dtype=torch.float64)
    i = best_trial(err, 0.5)
    hit = err[1:] <= 0.5
    if bool(hit.any()):
        first = [int(hit[:, j].float().argmax()) if bool(hit[:, j].any()) else t for j in range(n)]
        assert bool(hit[:, i].any()) and first[i] == min(first)
    else:
        assert float(err[1:, i].min()) == float(err[1:].min())


class _Frames:
    """A recorder that keeps what it is given."""

    def __init__(self):
        self.frames = []

    def add_frame(self, pose, ghost=None):
        self.frames.append((pose, ghost))


@pytest.mark.parametrize("reference", ["still", "clip"])
def test_evaluate_recovery_with_a_policy_that_never_gets_up(amp, walk, reference):  # noqa: F811
    from mocap.motion.library import MotionLibrary
    from mocap_sim_mujoco.simulator import MujocoSimulator

    lib = MotionLibrary(walk, amp)
    params = RecoveryEvalParams(trials=4, seconds=0.3, reference=reference, far_prob=0.5, seed=3, fall=FailStateParams(settle_steps=20))

    def make_sim(n):
        return MujocoSimulator(skeleton=amp, num_envs=n, seed=0)

    res = evaluate_recovery(HoldPose(amp.num_dofs), lib, make_sim, amp, params)
    assert res["protocol"] == "mocap-recovery-v2" and res["trials"] == 4 and res["clip"] == "walk"
    assert res["reference"] == reference
    assert res["recovery_rate"] == 0.0 and res["root_back_rate"] <= 0.5  # lying still: never back on the reference
    assert res["fallen_near_trials"] + res["fallen_far_trials"] == 4
    assert res["start_root_height_m"] < 0.5
    rec = _Frames()
    again = evaluate_recovery(HoldPose(amp.num_dofs), lib, make_sim, amp, params, recorder=rec, video_trial="best")
    assert {k: v for k, v in again.items() if not k.startswith("video_trial")} == res  # seeded: the same fallen states and offsets
    assert len(rec.frames) == round(0.3 * 30) and 0 <= again["video_trial"] < 4
    assert again["video_trial_min_error_m"] > 0.5  # it never got up
    (rp, rr, dp), (gp, gr, gd) = rec.frames[-1]
    assert rp.shape == (3,) and rr.shape == (4,) and dp.shape == (amp.num_dofs,) and gd.shape == (amp.num_dofs,)
    with pytest.raises(ValueError, match="video trial"):
        evaluate_recovery(HoldPose(amp.num_dofs), lib, make_sim, amp, params, recorder=_Frames(), video_trial=4)


@pytest.fixture(scope="module")
def bundled(amp):
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary

    return MotionLibrary(DeepMimicSource(DeepMimicParams()).load(amp), amp)


def test_still_frame_of_the_bundled_clips_is_a_standing_rest_pose(bundled):
    clip, t = pick_still_frame(bundled)
    name = bundled.clip_names[clip]
    assert name.startswith("getup_")  # the get-ups end standing at rest; every other clip moves
    assert t == pytest.approx(float(bundled.durations[clip]))
    ref = still_reference(bundled, clip, t, 3)
    assert bool((ref.root_pos[:, 2] > 0.7).all())  # standing (root ~0.85 m)
    for k in ("root_lin_vel", "root_ang_vel", "dof_vel", "body_lin_vel", "body_ang_vel"):
        assert float(getattr(ref, k).abs().max()) == 0.0, k
    frame = bundled.frames(torch.tensor([clip]), torch.tensor([t], dtype=bundled.dtype))
    torch.testing.assert_close(ref.body_pos[1], frame.body_pos[0])  # the clip's own pose, copied n times
    # every other first/last frame that stands moves faster than the chosen one
    n = bundled.num_clips
    for times in (torch.zeros(n, dtype=bundled.dtype), bundled.durations):
        f = bundled.frames(torch.arange(n), times)
        speed = torch.linalg.vector_norm(f.body_lin_vel.double(), dim=-1).mean(-1)
        standing = f.root_pos[:, 2] >= 0.7
        chosen = torch.linalg.vector_norm(frame.body_lin_vel.double(), dim=-1).mean()
        assert bool((speed[standing] >= chosen - 1e-12).all())


def test_still_reference_with_a_named_clip_holds_its_last_frame(amp, bundled):
    from mocap_sim_mujoco.simulator import MujocoSimulator

    params = RecoveryEvalParams(trials=2, seconds=0.1, reference="still", clip="walk", far_prob=0.0, fall=FailStateParams(settle_steps=5))
    res = evaluate_recovery(HoldPose(amp.num_dofs), bundled, lambda n: MujocoSimulator(skeleton=amp, num_envs=n, seed=0), amp, params)
    assert res["clip"] == "walk" and res["reference_time_s"] == pytest.approx(float(bundled.durations[bundled.clip_names.index("walk")]))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 32), prob=st.floats(0.0, 1.0), lo=st.floats(0.0, 4.0), width=st.floats(0.0, 3.0))
def test_far_shift_puts_near_starts_under_the_reference_and_far_ones_in_range(seed, n, prob, lo, width):
    from mocap_phc.recovery_eval import far_shift

    gen = torch.Generator().manual_seed(seed)
    ref = torch.randn(n, 2, generator=gen, dtype=torch.float64)
    fallen = torch.randn(n, 2, generator=gen, dtype=torch.float64)
    shift, far = far_shift(gen, n, ref, fallen, prob, (lo, lo + width))
    assert shift.shape == (n, 3) and far.shape == (n,) and bool((shift[:, 2] == 0).all())
    dist = torch.linalg.vector_norm(fallen + shift[:, :2] - ref, dim=-1)
    assert torch.allclose(dist[~far], torch.zeros_like(dist[~far]), atol=1e-12)
    assert bool((dist[far] >= lo - 1e-9).all()) and bool((dist[far] <= lo + width + 1e-9).all())
    if prob == 0.0:
        assert not bool(far.any())
