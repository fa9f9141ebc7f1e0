"""Issue 63 (trustworthy at the edges): CLI options, output paths and checkpoint contents that the
newcomer trial and the fuzz campaign found giving tracebacks now give one ``error:`` line (exit 2)
before any work, and the small newcomer items."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_bad_input import _amp_policy, assert_one_line_error

from mocap.testing import invoke


@pytest.fixture(scope="module")
def amp_policy(tmp_path_factory) -> Path:
    return _amp_policy(tmp_path_factory.mktemp("policy") / "policy.pt")


# ------------------------------------------------------------------ mocap eval options
@pytest.mark.parametrize("source", ["amass", "npz"])
def test_eval_on_a_motion_source_that_needs_params_says_to_write_a_spec(amp_policy, source):
    result = invoke(["eval", amp_policy, "--motions", source])
    assert_one_line_error(result, f"--motions {source}", "needs params (paths)", "mocap eval that.yaml")


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--num-envs", "0"], "--num-envs 0"),
        (["--num-envs", "-3"], "--num-envs -3"),
        (["--loop", "nan"], "--loop nan"),
        (["--loop", "-5"], "--loop -5"),
        (["--loop", "inf"], "--loop inf"),
    ],
)
def test_eval_counts_out_of_range_are_one_line(amp_policy, args, fragment):
    assert_one_line_error(invoke(["eval", amp_policy, *args]), fragment)
