"""bench/pmcp_phase_curves.py: per-phase curves keep every k-th iteration and each phase's last line."""

from __future__ import annotations

import math

from conftest import load_bench


def test_phase_curves_split_by_stage_and_thin():
    pc = load_bench("pmcp_phase_curves")
    lines = [{"stage": "imitator/prim1_getup", "step": i, "env_steps": 10 * i, "reward_mean": float(i), "env/reward/amp": 0.5} for i in range(1, 8)]
    lines += [{"stage": "imitator/prim1", "step": i, "env_steps": 10 * i, "reward_mean": -float(i)} for i in (3, 1, 2)]
    out = pc.phase_curves(lines, every=3)
    getup, pf = out["imitator/prim1_getup"], out["imitator/prim1"]
    assert getup["iteration"] == [3, 6, 7] and getup["env_steps"] == [30.0, 60.0, 70.0]  # 7: the phase's last line
    assert getup["reward_mean"] == [3.0, 6.0, 7.0] and getup["env/reward/amp"] == [0.5, 0.5, 0.5]
    assert pf["iteration"] == [3] and pf["reward_mean"] == [-3.0] and "env/reward/amp" not in pf  # sorted by step
    mixed = pc.phase_curves([{"stage": "s", "step": 1, "env/reward/amp": 1.0}, {"stage": "s", "step": 2}], every=1)["s"]
    assert mixed["env/reward/amp"][0] == 1.0 and math.isnan(mixed["env/reward/amp"][1])
