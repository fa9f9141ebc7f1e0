"""bench/recovery_compare.py: recovery rates per target and planner, averaged over seeds."""

from __future__ import annotations

import pytest
from conftest import load_bench


@pytest.fixture(scope="module")
def rc():
    return load_bench("recovery_compare")


def _run(seed, rate, near, far, stood=None):
    r = {"seed": seed, "recovery_rate": rate, "fallen_near_recovery_rate": near, "fallen_far_recovery_rate": far, "root_back_rate": 0.5}
    r["tracking_at_end"] = 0.0
    if stood is not None:
        r["stood_up_rate"] = stood
    return r


def test_summary_means_over_seeds_and_keeps_only_rates_every_run_has(rc):
    s = rc.summarize([_run(0, 0.25, 0.5, 0.0, 0.9), _run(1, 0.5, 0.75, 0.25)])
    assert s["seeds"] == [0, 1] and s["recovery_rate_per_seed"] == [0.25, 0.5]
    assert s["recovery_rate"] == pytest.approx(0.375) and s["fallen_far_recovery_rate"] == pytest.approx(0.125)
    assert "stood_up_rate" not in s  # one run lacks it: no mean over part of the seeds
    md = rc.render([{"target": "v4", "planner": "getup", "summary": s}], "t")
    assert "| v4 | getup | 37.5% | 25.0%, 50.0% | 62.5% | 12.5% | - | 50.0% | 0.0% |" in md


def test_a_bad_target_is_a_usage_error(rc):
    with pytest.raises(SystemExit):
        rc.main(["--target", "no-equals-sign"])
