"""bench/clip_flight.py: flight phases of reference clips (COM fall and angular momentum in flight).

Pinned: the pure math on random inputs (hypothesis): flight segments are exactly the maximal True
runs, the parabola fit recovers an exact parabola, the ballistic flight time inverts a trajectory
generated with g, and replaying at the free-fall frame rate turns the fitted acceleration into g;
then the real clips (jump's flight is ballistic, spin's is not) and the one-line error exit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import load_bench
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
CHECKPOINT = ROOT / "checkpoints" / "imitator" / "policy.pt"
SETTINGS = settings(
    max_examples=50,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
gs = st.floats(-20.0, -1.0)

cf = load_bench("clip_flight")


@SETTINGS
@given(st.lists(st.booleans(), max_size=60))
def test_flight_segments_are_the_maximal_true_runs(mask):
    segs = cf.flight_segments(mask)
    covered = [i for a, b in segs for i in range(a, b + 1)]
    assert covered == [i for i, v in enumerate(mask) if v]  # exactly the True indices, in order, each once
    for a, b in segs:
        assert a <= b
        assert a == 0 or not mask[a - 1]  # maximal: a False (or the edge) on both sides
        assert b == len(mask) - 1 or not mask[b + 1]
    assert all(b1 + 1 < a2 for (_, b1), (a2, _) in zip(segs, segs[1:]))  # disjoint, not even touching


@SETTINGS
@given(st.floats(-20, 20), st.floats(-5, 5), st.floats(-2, 2), st.floats(-3, 3), st.sampled_from([16.0, 24.0, 30.0, 60.0]), st.integers(4, 40))
def test_fit_parabola_recovers_an_exact_parabola(az, v0, z0, t0, fps, n):
    t = t0 + np.arange(n) / fps
    z = z0 + v0 * (t - t0) + 0.5 * az * (t - t0) ** 2
    a, v, rms = cf.fit_parabola(t, z)
    assert a == pytest.approx(az, abs=1e-6 * (1 + abs(az)) * fps**2 / 100)
    assert v == pytest.approx(v0, abs=1e-6 * (1 + abs(az) + abs(v0)))
    assert rms < 1e-9


@SETTINGS
@given(st.floats(0.1, 5.0), st.floats(0.01, 1.0), gs, st.sampled_from([16.0, 24.0, 60.0]))
def test_ballistic_flight_time_returns_the_duration_of_a_free_flight(vz, past_apex, g, fps):
    apex = vz / -g
    duration = apex + past_apex  # lands on the way down (exactly at the apex the root is ill-conditioned)
    t = np.linspace(0.0, duration, max(2, int(duration * fps) + 1))
    z = 1.0 + vz * t + 0.5 * g * t**2
    assert cf.ballistic_flight_time(vz, z[-1] - z[0], g) == pytest.approx(duration, rel=1e-9, abs=1e-9)
    assert cf.ballistic_flight_time(vz, vz * apex + 0.5 * g * apex**2 + 0.01, g) is None  # above its apex: never
    assert cf.ballistic_flight_time(-vz, 0.01, g) is None  # falling, and the target is above


@SETTINGS
@given(st.floats(-20.0, -0.5), st.floats(-3, 3), st.sampled_from([16.0, 24.0, 30.0, 60.0]), st.integers(6, 40), gs)
def test_replaying_at_the_free_fall_fps_makes_the_parabola_free_fall(az, v0, fps, n, g):
    z = 1.0 + v0 * (np.arange(n) / fps) + 0.5 * az * (np.arange(n) / fps) ** 2  # recorded at fps
    f = cf.free_fall_fps(fps, az, g)
    a, _, _ = cf.fit_parabola(np.arange(n) / f, z)  # the same samples, played at f
    assert a == pytest.approx(g, rel=1e-6)
    assert cf.free_fall_fps(fps, -az, g) is None and cf.free_fall_fps(fps, 0.0, g) is None


def _main_flight(result):
    return max(result["phases"], key=lambda p: p["duration_s"])


@pytest.mark.skipif(not CHECKPOINT.is_file(), reason="no checkpoints/imitator/policy.pt")
def test_jump_falls_at_g_and_spin_does_not():
    _, lib, model, idx = cf.build(CHECKPOINT, ["spin", "jump"])
    jump = _main_flight(cf.analyse(lib, model, idx, "jump", 0.05))
    assert jump["com_az_fit"] == pytest.approx(-9.81, abs=1.0)
    spin = _main_flight(cf.analyse(lib, model, idx, "spin", 0.05))
    assert spin["com_az_fit"] > -7.5 and spin["t_start"] == pytest.approx(1.625)
    assert spin["free_fall_fps"] > 27.0 and spin["ballistic_flight_s"] < spin["duration_s"] - 0.1


@pytest.mark.skipif(not CHECKPOINT.is_file(), reason="no checkpoints/imitator/policy.pt")
def test_an_unknown_clip_is_one_error_line_and_exit_2(tmp_path: Path, capsys):
    rc = cf.main(["--checkpoint", str(CHECKPOINT), "--clips", "spin,nosuchclip", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "nosuchclip" in lines[0], err
    assert not list(tmp_path.iterdir())
    assert cf.main(["--checkpoint", str(tmp_path / "none.pt")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"error: no checkpoint {tmp_path / 'none.pt'}"]
