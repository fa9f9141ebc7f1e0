"""The get-up planner's pose clock (``getup_clock: pose``): the get-up clip's clock is paced by the
humanoid's pose: faster while the humanoid is ahead of it, slower (with ``pose_lead_s``) while it lags."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from test_recovery_eval import bundled  # noqa: F401  (fixture)
from test_recovery_planner import DT, frame, moved_turned

from mocap.motion.transform import yaw_frames
from mocap_phc.recovery_planner import GETUP, GetUpPlanner, GetUpPlannerParams, pose_clock_rate, pose_features

NAME = "getup_facedown"


def started(lib, **kw) -> tuple[GetUpPlanner, object]:
    """A planner that has just started the get-up clip NAME for a humanoid lying like its first frame."""
    planner = GetUpPlanner(lib, GetUpPlannerParams(**kw), 1, DT)
    still = frame(lib, "walk", 0.0)
    planner.reference(1, moved_turned(frame(lib, NAME, 0.0), 0.7, (2.0, -1.0)), still)
    assert int(planner.mode[0]) == GETUP and lib.clip_names[int(planner.clip[0])] == NAME
    return planner, still


def laid(lib, planner: GetUpPlanner, t: float):
    """The clip NAME at time ``t``, turned and moved as the planner laid it onto the humanoid."""
    return yaw_frames(frame(lib, NAME, t), planner.yaw, planner.pivot, planner.target)


def clock(planner: GetUpPlanner, k: int) -> float:
    return float(planner._clip_time(k)[0])


def test_under_perfect_tracking_the_pose_clock_runs_like_the_time_clock(bundled):  # noqa: F811
    lib = bundled
    planners = {c: started(lib, getup_clock=c) for c in ("time", "pose")}
    state = {c: laid(lib, planners[c][0], DT) for c in planners}
    for k in range(2, 60):
        outs = {c: planners[c][0].reference(k, state[c], planners[c][1]) for c in planners}
        torch.testing.assert_close(outs["pose"].body_pos, outs["time"].body_pos)
        torch.testing.assert_close(outs["pose"].body_lin_vel, outs["time"].body_lin_vel)
        state = outs
    assert float(planners["pose"][0].pose_rate[0]) == 1.0


def test_a_humanoid_ahead_of_the_clip_speeds_its_clock_up_and_the_reference_moves_at_that_rate(bundled):  # noqa: F811
    lib = bundled
    planner, still = started(lib, getup_clock="pose")  # pose_tau_s 0.3, pose_max_rate 1.5
    planner.reference(2, laid(lib, planner, DT), still)  # on the clock: rate 1
    assert float(planner.pose_rate[0]) == 1.0 and clock(planner, 2) == pytest.approx(2 * DT)
    out = planner.reference(3, laid(lib, planner, 2 * DT + 0.1), still)  # 0.1 s ahead of the clock (2 dt)
    rate = 1.0 + 0.1 / 0.3
    assert float(planner.pose_rate[0]) == pytest.approx(rate, abs=1e-6)
    t = 2 * DT + rate * DT
    assert clock(planner, 3) == pytest.approx(t, abs=1e-9)
    plain = laid(lib, planner, t)
    torch.testing.assert_close(out.body_pos, plain.body_pos.to(out.body_pos))
    torch.testing.assert_close(out.body_lin_vel, rate * plain.body_lin_vel.to(out.body_lin_vel))  # velocities at the rate it is played


@pytest.mark.parametrize("lead", [None, 0.2])
def test_a_humanoid_stuck_mid_get_up_stops_the_clock_only_with_a_lead_limit(bundled, lead):  # noqa: F811
    lib = bundled
    planner, still = started(lib, getup_clock="pose", pose_lead_s=lead, pose_tau_s=0.2)
    stuck_at = 1.2
    for k in range(2, 91):  # it tracks the clip perfectly up to the pose of 1.2 s, then holds it
        planner.reference(k, laid(lib, planner, min((k - 1) * DT, stuck_at)), still)
    if lead is None:  # the clock never slows: it runs on at rate 1 (3 s after the start)
        assert clock(planner, 90) == pytest.approx(90 * DT, abs=1e-6)
    else:  # it slows as it leads the held pose by more than 0.2 s and stops at a lead of 0.2 + 0.2 s
        assert clock(planner, 90) == pytest.approx(stuck_at + 0.4, abs=0.01)
        assert float(planner.pose_rate[0]) < 0.05


@settings(max_examples=50, deadline=None)
@given(
    a=st.floats(-2.0, 2.0),
    b=st.floats(-2.0, 2.0),
    lead_s=st.one_of(st.none(), st.floats(0.0, 1.0)),
    tau=st.floats(0.01, 1.0),
    top=st.floats(1.0, 3.0),
)
def test_the_pose_clock_rate_falls_with_the_lead_is_one_on_pace_and_stays_in_bounds(a, b, lead_s, tau, top):
    lo, hi = sorted((a, b))
    r = pose_clock_rate(torch.tensor([lo, hi], dtype=torch.float64), lead_s, tau, top)
    assert float(r[0]) >= float(r[1]) - 1e-12  # more lead, no faster
    assert 0.0 <= float(r.min()) and float(r.max()) <= top + 1e-12
    limit = math.inf if lead_s is None else lead_s
    for lead, rate in zip((lo, hi), r.tolist(), strict=True):
        if 0.0 <= lead <= limit:
            assert rate == 1.0
        if lead_s is not None and lead >= lead_s + tau:
            assert rate == 0.0


@settings(max_examples=25, deadline=None)
@given(yaw=st.floats(-math.pi, math.pi), dx=st.floats(-5, 5), dy=st.floats(-5, 5), t=st.floats(0.0, 2.5))
def test_pose_features_ignore_a_turn_about_the_vertical_and_a_move_on_the_ground(bundled, yaw, dx, dy, t):  # noqa: F811
    f = frame(bundled, NAME, t)
    g = moved_turned(f, yaw, (dx, dy))
    a, b = pose_features(f.root_pos, f.root_rot, f.dof_pos), pose_features(g.root_pos, g.root_rot, g.dof_pos)
    torch.testing.assert_close(a, b, atol=1e-5, rtol=0)
    lifted = pose_features(f.root_pos + torch.tensor([0.0, 0.0, 0.1]), f.root_rot, f.dof_pos)
    assert float(((lifted - a) ** 2).sum()) == pytest.approx(10.0 * 0.1**2, rel=1e-4)  # HEIGHT_WEIGHT x dh^2


@settings(max_examples=20, deadline=None)
@given(j=st.integers(15, 80), lag=st.integers(-15, 7))
def test_the_pose_match_finds_the_exact_frame_anywhere_in_its_window(bundled, j, lag):  # noqa: F811
    """The humanoid in the clip's pose at grid time (j + lag) dt, the clock at j dt: the matched
    time is that pose's, for lags within [-pose_back_s, +pose_ahead_s] (0.5 s, 0.25 s)."""
    lib = bundled
    planner, _ = started(lib, getup_clock="pose")
    s = (j + lag) * DT
    matched = planner.matched_times(torch.tensor([0]), torch.tensor([j * DT], dtype=torch.float64), laid(lib, planner, s))
    assert float(matched[0]) == pytest.approx(s, abs=1e-9)
