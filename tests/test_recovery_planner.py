"""The get-up planner (``mocap_phc.recovery_planner``, ``mocap recover --planner getup``): which clip
it starts, where and turned how; its modes under perfect tracking; re-falls; the approach's slow start."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from test_recovery_eval import HoldPose, bundled  # noqa: F401  (fixture)

from mocap.motion.transform import yaw_frames
from mocap.state import MotionFrames
from mocap_phc.recovery_planner import APPROACH, GETUP, TRACK, GetUpPlanner, GetUpPlannerParams

DT = 1.0 / 30.0


def frame(lib, name: str, t: float, n: int = 1) -> MotionFrames:
    c = lib.clip_names.index(name)
    return lib.frames(torch.full((n,), c), torch.full((n,), t, dtype=lib.dtype))


def moved_turned(f: MotionFrames, yaw: float, xy: tuple[float, float]) -> MotionFrames:
    n = f.root_pos.shape[0]
    return yaw_frames(f, torch.full((n,), yaw, dtype=torch.float64), f.root_pos[:, :2], torch.tensor([xy] * n, dtype=torch.float64))


def test_a_humanoid_lying_like_a_get_up_start_gets_that_clip_turned_and_moved_onto_it(bundled):  # noqa: F811
    lib = bundled
    for name in ("getup_facedown", "getup_faceup"):
        lying = moved_turned(frame(lib, name, 0.0, 2), 1.0, (3.0, -2.0))
        planner = GetUpPlanner(lib, GetUpPlannerParams(), 2, DT)
        given_ref = frame(lib, "getup_faceup", float(lib.durations[lib.clip_names.index("getup_faceup")]), 2)
        out = planner.reference(1, lying, given_ref)
        assert bool((planner.mode == GETUP).all()) and lib.clip_names[int(planner.clip[0])] == name
        # the clip's first frame, turned and moved, is exactly how the humanoid lies
        first = yaw_frames(frame(lib, name, 0.0, 2), planner.yaw, planner.pivot, planner.target)
        torch.testing.assert_close(first.body_pos.double(), lying.body_pos.double(), atol=1e-4, rtol=0)
        # and the reference given is that clip one control step in, with the same transform
        step = yaw_frames(frame(lib, name, DT, 2), planner.yaw, planner.pivot, planner.target)
        torch.testing.assert_close(out.body_pos, step.body_pos)
        assert int(planner.getups_started.sum()) == 2


def test_a_standing_humanoid_gets_the_reference_it_was_given(bundled):  # noqa: F811
    planner = GetUpPlanner(bundled, GetUpPlannerParams(), 3, DT)
    standing = frame(bundled, "walk", 0.0, 3)
    given_ref = frame(bundled, "walk", DT, 3)
    for k in (1, 2, 3):
        assert planner.reference(k, standing, given_ref) is given_ref
    assert bool((planner.mode == TRACK).all()) and int(planner.getups_started.sum()) == 0


def follow(planner: GetUpPlanner, start: MotionFrames, given_ref: MotionFrames, steps: int) -> tuple[list[int], list[float], MotionFrames]:
    """Perfect tracking: the humanoid is, at each step, the reference it was given the step before."""
    state, modes, dist = start, [], []
    for k in range(1, steps + 1):
        state = planner.reference(k, state, given_ref)
        modes.append(int(planner.mode[0]))
        dist.append(float(torch.linalg.vector_norm(state.root_pos[0, :2] - given_ref.root_pos[0, :2])))
    return modes, dist, state


@pytest.mark.parametrize("approach", ["walk", None])
def test_under_perfect_tracking_it_gets_up_walks_to_the_reference_and_hands_over(bundled, approach):  # noqa: F811
    lib = bundled
    lying = moved_turned(frame(lib, "getup_facedown", 0.0), 2.5, (0.0, 0.0))
    still = moved_turned(frame(lib, "getup_faceup", float(lib.durations[lib.clip_names.index("getup_faceup")])), 0.0, (3.0, 1.0))
    planner = GetUpPlanner(lib, GetUpPlannerParams(approach_clip=approach), 1, DT)
    modes, dist, end = follow(planner, lying, still, 420)
    getup_steps = modes.count(GETUP)
    assert modes[0] == GETUP and getup_steps == pytest.approx(float(lib.durations[lib.clip_names.index("getup_facedown")]) / DT, abs=2)
    assert int(planner.getups_started[0]) == 1  # up at the clip's end: no second get-up
    if approach is None:
        assert modes[getup_steps] == TRACK and end is still
        return
    walk = [d for m, d in zip(modes, dist) if m == APPROACH]
    assert modes[getup_steps] == APPROACH and len(walk) > 30
    assert walk[-1] < walk[0] - 2.0  # it walked toward the reference
    assert modes[-1] == TRACK and dist[-1] <= 0.4 + 0.1  # and handed over within approach_distance (plus one step)


def test_falling_again_starts_another_get_up_after_fallen_steps(bundled):  # noqa: F811
    lib = bundled
    p = GetUpPlannerParams(fallen_steps=5)
    planner = GetUpPlanner(lib, p, 1, DT)
    standing = frame(lib, "walk", 0.0)
    lying = moved_turned(frame(lib, "getup_faceup", 0.0), 0.3, (1.0, 1.0))
    given_ref = frame(lib, "walk", DT)
    assert planner.reference(1, standing, given_ref) is given_ref  # up at the start: no get-up
    for k in range(2, 2 + p.fallen_steps - 1):
        planner.reference(k, lying, given_ref)
        assert int(planner.mode[0]) == TRACK  # not yet: down for fewer than fallen_steps
    planner.reference(2 + p.fallen_steps - 1, lying, given_ref)
    assert int(planner.mode[0]) == GETUP and lib.clip_names[int(planner.clip[0])] == "getup_faceup"
    # still down when the clip has ended: its last frame is held at rest, then another get-up
    dur = round(float(lib.durations[int(planner.clip[0])]) / DT)
    k0 = 2 + p.fallen_steps
    held = planner.reference(k0 + dur, lying, given_ref)
    assert int(planner.mode[0]) == GETUP and float(held.body_lin_vel.abs().max()) == 0.0
    for k in range(k0 + dur + 1, k0 + dur + 2 + p.fallen_steps):
        planner.reference(k, lying, given_ref)
    assert int(planner.getups_started[0]) == 2


@settings(max_examples=30, deadline=None)
@given(r0=st.floats(0.05, 1.0), ramp=st.floats(0.0, 3.0), e=st.floats(0.0, 6.0))
def test_the_approach_warp_starts_slow_and_its_rate_is_its_derivative(bundled, r0, ramp, e):  # noqa: F811
    planner = GetUpPlanner(bundled, GetUpPlannerParams(approach_start_rate=r0, approach_ramp_s=ramp), 1, DT)
    x = torch.tensor([e, e + 1e-6], dtype=torch.float64)
    tau, rate = planner._warp(x)
    assert float(tau[0]) >= r0 * e - 1e-9 and float(tau[0]) <= e + 1e-9
    assert r0 - 1e-9 <= float(rate[0]) <= 1.0 + 1e-9
    curvature = (1.0 - r0) / ramp if ramp > 0 else 0.0  # the forward difference is off by at most h x curvature / 2
    assert float((tau[1] - tau[0]) / 1e-6) == pytest.approx(float(rate[0]), abs=1e-6 + 1e-6 * curvature)
    if e >= ramp:
        assert float(rate[0]) == pytest.approx(1.0)
    assert float(planner._warp(torch.zeros(1, dtype=torch.float64))[0]) == 0.0


@pytest.mark.parametrize("ramp", [5e-324, 1e-12])
def test_a_subnormal_approach_ramp_is_no_ramp(bundled, ramp):  # noqa: F811
    """Found by the property above: a 5e-324 s ramp gave rates of 1.25 and 0.5 at e = 1 s."""
    planner = GetUpPlanner(bundled, GetUpPlannerParams(approach_start_rate=0.25, approach_ramp_s=ramp), 1, DT)
    tau, rate = planner._warp(torch.tensor([1.0], dtype=torch.float64))
    assert float(rate[0]) == 1.0 and float(tau[0]) == 1.0


def test_bad_planner_settings_are_clear_errors(bundled):  # noqa: F811
    with pytest.raises(ValueError, match="no clip matches"):
        GetUpPlanner(bundled, GetUpPlannerParams(clips=["nothing*"]), 1, DT)
    with pytest.raises(ValueError, match="no approach clip"):
        GetUpPlanner(bundled, GetUpPlannerParams(approach_clip="moonwalk"), 1, DT)
    with pytest.raises(ValueError, match="must loop"):
        GetUpPlanner(bundled, GetUpPlannerParams(approach_clip="getup_faceup"), 1, DT)


def test_evaluate_recovery_with_the_planner_reports_it_and_still_measures_the_protocol(amp, bundled):  # noqa: F811
    from mocap_phc.recovery import FailStateParams
    from mocap_phc.recovery_eval import RecoveryEvalParams, evaluate_recovery
    from mocap_sim_mujoco.simulator import MujocoSimulator

    params = RecoveryEvalParams(trials=3, seconds=0.3, far_prob=0.0, seed=2, fall=FailStateParams(settle_steps=45), planner=GetUpPlannerParams())
    res = evaluate_recovery(HoldPose(amp.num_dofs), bundled, lambda n: MujocoSimulator(skeleton=amp, num_envs=n, seed=0), amp, params)
    assert res["planner"]["name"] == "getup" and res["planner"]["approach_clip"] == "walk"
    assert res["recovery_rate"] == 0.0 and res["stood_up_rate"] == 0.0  # a policy that holds its pose never gets up
    assert res["getups_started_mean"] == 1.0 and res["mode_at_end"]["getup"] == 3
    bare = params.model_copy(update={"planner": None})
    plain = evaluate_recovery(HoldPose(amp.num_dofs), bundled, lambda n: MujocoSimulator(skeleton=amp, num_envs=n, seed=0), amp, bare)
    assert plain["planner"] is None and "stood_up_rate" not in plain
    assert math.isfinite(plain["start_root_height_m"]) and plain["start_root_height_m"] == res["start_root_height_m"]
