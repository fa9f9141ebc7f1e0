"""bench/task_summary.py: the column picking, the beats-at-equal-steps verdict and the table it writes."""

from __future__ import annotations

import json

import pytest
from conftest import load_bench
from hypothesis import given
from hypothesis import strategies as st


@pytest.fixture(scope="module")
def ts():
    return load_bench("task_summary")


def _group(metric: str, mean: float, std: float = 0.0, n: int = 3, steps: float = 7e6, closest: float | None = None) -> dict:
    task_eval = {metric: {"mean": mean, "std": std, "n": n}}
    if closest is not None:
        task_eval["closest_distance"] = {"mean": closest, "std": 0.0, "n": n}
    return {"seeds": list(range(n)), "final": {"env_steps": {"mean": steps, "std": 0.0, "n": n}}, "task_eval": task_eval}


def _cell(metric: str, mean: float, steps: float) -> dict:
    return {"latent": "x", "metric": metric, "value": {"mean": mean, "std": 0.0, "n": 3}, "env_steps": steps, "closest": None}


def test_a_column_takes_the_first_latent_label_the_json_has_for_the_task(ts):
    groups = {"reach/pulse_far_reward": _group("success_rate", 0.01, closest=1.0), "reach/pulse_mid_reward": _group("success_rate", 0.5)}
    c = ts.cell(groups, "reach", ["pulse", "pulse_far_reward", "pulse_mid_reward"])
    assert c["latent"] == "pulse_far_reward" and c["value"]["mean"] == 0.01 and c["closest"]["mean"] == 1.0
    assert ts.cell(groups, "speed", ["pulse"]) is None  # no group for the task
    no_eval = {"speed/pulse": {"final": {"env_steps": {"mean": 7e6}}, "task_eval": {}}}
    assert ts.cell(no_eval, "speed", ["pulse"]) is None  # trained but never evaluated deterministically


def test_the_verdict_respects_the_direction_of_the_metric_and_the_budget(ts):
    # speed error: lower is better
    assert ts.verdict(_cell("speed_error", 0.5, 7e6), _cell("speed_error", 0.7, 7e6)) == "yes"
    assert ts.verdict(_cell("speed_error", 0.9, 7e6), _cell("speed_error", 0.7, 7e6)) == "no"
    # more steps and still worse: no; fewer steps and worse: not comparable; better with more steps: not comparable
    assert ts.verdict(_cell("speed_error", 1.2, 8e6), _cell("speed_error", 0.7, 7e6)) == "no"
    assert ts.verdict(_cell("speed_error", 1.2, 5e6), _cell("speed_error", 0.7, 7e6)) == "not comparable"
    assert ts.verdict(_cell("speed_error", 0.5, 8e6), _cell("speed_error", 0.7, 7e6)) == "not comparable"
    # success: higher is better; budgets within 2% are equal (7,000,064 against 6,995,968)
    assert ts.verdict(_cell("success_rate", 0.3, 7_000_064), _cell("success_rate", 0.2, 6_995_968)) == "yes"
    assert ts.verdict(None, _cell("success_rate", 0.2, 7e6)) == "not comparable"


@given(
    a=st.floats(0.0, 5.0, allow_nan=False),
    b=st.floats(0.0, 5.0, allow_nan=False),
    metric=st.sampled_from(["speed_error", "success_rate", "hit_rate"]),
)
def test_at_equal_budgets_exactly_one_of_two_different_cells_beats_the_other(ts, a, b, metric):
    x, y = _cell(metric, a, 7e6), _cell(metric, b, 7e6)
    vx, vy = ts.verdict(x, y), ts.verdict(y, x)
    assert {vx, vy} <= {"yes", "no"}
    if a == b:
        assert vx == vy == "no"
    else:
        assert sorted([vx, vy]) == ["no", "yes"]
        assert (vx == "yes") == ((a < b) if metric == "speed_error" else (a > b))


def test_the_table_and_the_tally_from_two_jsons(ts, tmp_path, capsys):
    old = {"groups": {"speed/scratch": _group("speed_error", 0.69, 0.04, steps=7e6), "reach/scratch": _group("success_rate", 0.29, 0.04, closest=0.33)}}
    new = {
        "groups": {
            "speed/pulse": _group("speed_error", 1.18, 0.08, steps=8e6),
            "reach/pulse_far_reward": _group("success_rate", 0.0058, 0.005, closest=1.0),
        }
    }
    (tmp_path / "old.json").write_text(json.dumps(old))
    (tmp_path / "new.json").write_text(json.dumps(new))
    out = tmp_path / "summary"
    rc = ts.main(
        [
            "--column",
            f"scratch={tmp_path / 'old.json'}:scratch",
            "--column",
            f"PULSE={tmp_path / 'new.json'}:pulse,pulse_far_reward",
            "--versus",
            "PULSE:scratch",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    text = out.with_suffix(".md").read_text()
    assert "| speed | 0.69 ± 0.04 m/s (3 seeds, 7M) | 1.18 ± 0.08 m/s (3 seeds, 8M) | no |" in text
    assert "| reach | 29 ± 4% (3 seeds, 7M); closest 0.33 m | 0.58 ± 0.5% (3 seeds, 7M); closest 1.00 m | no |" in text
    assert "| strike | - | - | not comparable |" in text
    one = ts._fmt({"metric": "hit_rate", "value": {"mean": 0.0513, "std": 0.0, "n": 1}, "env_steps": 5e6, "closest": None})
    assert one == "5.13% (1 seed, 5M)"  # no spread shown for one seed
    assert "PULSE beats scratch on 0 of 4 tasks." in text
    saved = json.loads(out.with_suffix(".json").read_text())
    assert saved["verdicts"]["PULSE beats scratch"]["speed"] == "no" and saved["rows"]["reach"]["PULSE"]["latent"] == "pulse_far_reward"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--column", "scratch=missing.json:scratch"], "missing.json: not a task_compare JSON"),
        (["--column", "no-separator"], "expected LABEL=JSON:LATENT"),
        (["--column", "a=x.json:s", "--versus", "a"], "expected A:B"),
    ],
)
def test_bad_arguments_give_one_error_line(ts, tmp_path, capsys, argv, message):
    assert ts.main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and message in err and "Traceback" not in err


def test_versus_must_name_columns(ts, tmp_path, capsys):
    (tmp_path / "t.json").write_text(json.dumps({"groups": {}}))
    assert ts.main(["--column", f"a={tmp_path / 't.json'}:x", "--versus", "a:b", "--out", str(tmp_path / "o")]) == 2
    assert "both must be column labels" in capsys.readouterr().err
