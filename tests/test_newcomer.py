"""The newcomer's path (issue 26): commands a new user types give one clear line, never a
traceback, and listings are not cut when piped."""

from __future__ import annotations

from mocap.cli import main


def test_schema_out_into_a_missing_folder_or_a_directory_is_one_error(tmp_path, capsys):
    assert main(["schema", "--out", str(tmp_path / "nope" / "x.json")]) == 2
    err = capsys.readouterr().err
    assert "does not exist" in err and "Traceback" not in err
    assert main(["schema", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "a directory" in err and "Traceback" not in err
    assert main(["schema", "--out", str(tmp_path / "s.json")]) == 0
    assert (tmp_path / "s.json").read_text().startswith("{")


def test_plugins_listing_is_not_truncated_when_piped(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    assert "trainer:imitation_eval" in out
    assert "…" not in out


# ---------------------------------------------------------------------------- report numbers
import math  # noqa: E402

import pytest  # noqa: E402
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from mocap.metric_display import format_cell, mean_ci95, metric_label, t_critical_95  # noqa: E402


def test_single_runs_show_no_interval_and_several_show_the_95_percent_one():
    assert mean_ci95([3.0]) == (3.0, None)
    assert format_cell(3.0, None, 1) == "3"
    mean, half = mean_ci95([1.0, 2.0, 3.0])
    # s = 1, t_{0.975,2} = 4.303: half-width 4.303 / sqrt(3)
    assert mean == 2.0 and half == pytest.approx(4.303 / math.sqrt(3))
    assert format_cell(mean, half, 3) == "2 ± 2.5 (n=3)"


@given(st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=40), st.floats(-100, 100))
def test_interval_is_shift_invariant_and_shrinks_with_t(values, shift):
    m1, h1 = mean_ci95(values)
    m2, h2 = mean_ci95([v + shift for v in values])
    assert m2 == pytest.approx(m1 + shift, abs=1e-6) and h2 == pytest.approx(h1, abs=1e-6)
    assert t_critical_95(len(values) - 1) >= 1.96


def test_metric_labels_carry_units():
    assert metric_label("eval/mpjpe_g") == "MPJPE-g (mm)"
    assert metric_label("eval/imitation/mpjpe_g_succ") == "imitation MPJPE-g (tracked) (mm)"
    assert metric_label("eval/generation/time_to_fall_s") == "generation time to fall (s)"
    assert metric_label("task/episode/normalized_return") == "normalized return"
    assert metric_label("eval/some_plugin_metric") == "eval/some_plugin_metric"


def test_comparison_table_of_single_runs_says_so(tmp_path):
    from mocap.matrix import render

    text = render({"latent=pulse": {"eval/mpjpe_g": {"mean": 87.0, "std": None, "ci95": None, "n": 1}}})
    assert "MPJPE-g (mm)" in text and "| 87 |" in text
    assert "±" not in text and "n=1" not in text and "one run each" in text


@pytest.mark.parametrize(
    "override, expect",
    [
        ("imitator.trainer.params.lrr=0.1", "did you mean 'lr'?"),
        ("imitator.params.episode_step=10", "did you mean 'episode_steps'?"),
        ("seeed=1", "did you mean 'seed'?"),
    ],
)
def test_unknown_fields_get_a_suggestion_and_the_allowed_fields(override, expect, capsys):
    from pathlib import Path

    spec = Path(__file__).resolve().parents[1] / "specs/imitator/amp_bundled.yaml"
    assert main(["validate", str(spec), "--set", override]) == 2
    err = capsys.readouterr().err
    assert "unknown field" in err and expect in err and "allowed fields:" in err


def test_a_latent_with_its_own_tracker_is_evaluated_as_such():
    """`mocap eval runs/quickstart/latent-vmp` (the quickstart's own "next:" line) raised ValueError: a VMP
    latent file is not a distilled latent, so the evaluator now drives its own tracker."""
    from pathlib import Path

    from mocap.eval_targets import _is_distilled

    root = Path(__file__).resolve().parents[1] / "checkpoints"
    assert not _is_distilled(root / "vmp_amp_v2" / "latent.pt")
    assert _is_distilled(root / "pulse_amp_v2" / "latent.pt")
    assert _is_distilled(root / "hybrid_rvq_amp" / "latent.pt")


def test_an_unfinished_training_checkpoint_is_named_as_such():
    from mocap.checkpoint import training_status

    assert training_status({"finished": True, "env_steps": 10}) is None
    assert training_status({"format": "x"}) is None
    text = training_status({"finished": False, "env_steps": 40_960, "params": {"total_env_steps": 22_000_000}})
    assert text == "in progress: 40,960 of 22,000,000 env steps (0.2%)"
    assert training_status({"finished": False, "step": 5, "params": {}}) == "in progress (saved at step 5)"


def test_a_run_ends_with_its_headline_numbers():
    from pathlib import Path

    from mocap.interfaces import StageResult
    from mocap.pipeline import StageRecord
    from mocap.report import headline

    records = [
        StageRecord("imitator", "k1", Path("a"), StageResult(checkpoint=None, metrics={"episode/return": 3.0}), True, 0.0),
        StageRecord("eval", "k2", Path("b"), StageResult(checkpoint=None, metrics={"mpjpe_g_succ": 87.04, "succeeded": 9.0}), False, 1.0),
    ]
    assert headline(records) == ["eval: clips tracked 9", "eval: MPJPE-g (tracked) (mm) 87.04"]


def test_docs_switches_table_is_current():
    """docs/switches.md is `mocap switches` of the built-in components (paper / code / default per switch)."""
    from pathlib import Path

    from mocap.plugins import get_plugins
    from mocap.switches import render

    committed = (Path(__file__).resolve().parents[1] / "docs" / "switches.md").read_text()
    assert render(get_plugins(), {"mocap"}) == committed, "regenerate: mocap switches --out docs/switches.md"
    assert "`reward_form`" in committed and "`dead_threshold_mode`" in committed and "`fail_states`" in committed


def test_a_missing_set_checkpoint_names_the_resolved_path_and_the_rule(tmp_path, capsys, monkeypatch):
    from pathlib import Path

    spec = Path(__file__).resolve().parents[1] / "specs/imitator/amp_bundled.yaml"
    monkeypatch.chdir(tmp_path)
    rc = main(["run", str(spec), "--out", str(tmp_path / "run"), "--set", "imitator.checkpoint=nope/policy.pt", "--set", "imitator.trainer=null"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert str(tmp_path / "nope" / "policy.pt") in err.replace("\n", "")
    assert "relative to the working directory" in err.replace("\n", " ")


def test_eval_progress_is_printed_when_not_a_terminal(amp):
    """The eval stage's progress was blank in logs (a rich bar needs a terminal)."""
    import io

    from rich.console import Console

    from mocap.baselines import PDReplay
    from mocap.evaluation import ImitationEvalParams
    from mocap.imitation_eval import evaluate_imitator
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary
    from mocap_sim_mujoco.simulator import MujocoSimulator

    lib = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk", "kick", "run"])).load(amp), amp)
    buf = io.StringIO()
    console = Console(file=buf, force_terminal=False, width=120)
    params = ImitationEvalParams(num_envs=2, horizon=0.5)
    evaluate_imitator(PDReplay(), lib, lambda n: MujocoSimulator(skeleton=amp, num_envs=n), params, console=console)
    text = buf.getvalue()
    assert "imitation eval: 2/3 clips" in text and "imitation eval: 3/3 clips" in text


def test_a_training_distill_checkpoint_carries_its_label(tmp_path):
    """`mocap generate` of a still-training PULSE run said to set label: pd_targets, which the spec had:
    the label of a distill.pt is read from its params, as latent.pt keeps it in extra."""
    import torch

    from mocap.distill_files import CHECKPOINT_FORMAT, load_latent_state

    path = tmp_path / "distill.pt"
    torch.save({"format": CHECKPOINT_FORMAT, "student": {}, "latent_config": {}, "params": {"label": "pd_targets"}}, path)
    assert load_latent_state(path)["extra"]["label"] == "pd_targets"
