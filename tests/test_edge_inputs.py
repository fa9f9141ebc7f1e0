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


# ------------------------------------------------------------------ output paths, checked before any work
def test_generate_refuses_an_unsupported_video_file_at_once(amp_policy, tmp_path):
    """Checked before the target loads (a policy file is no latent space: that error would come next)."""
    assert_one_line_error(invoke(["generate", amp_policy, "--video", tmp_path / "gen.mkv"]), "--video", "the video must be a .mp4 or .gif file")
    assert_one_line_error(invoke(["recover", amp_policy, "--video", tmp_path / "r.avi"]), "--video", "the video must be a .mp4 or .gif file")


def test_render_refuses_a_folder_that_does_not_exist_instead_of_creating_it(tmp_path):
    missing = tmp_path / "nonexistent"
    line = assert_one_line_error(invoke(["render", "--motion", "walk", "--out", missing / "walk.mp4"]), "--out")
    assert f"the folder {missing} does not exist" in line
    assert not missing.exists()


@pytest.mark.parametrize("where", ["folder", "under_a_file", "under_a_file_deeper", "long_name"])
def test_eval_output_paths_are_refused_before_any_evaluation(amp_policy, tmp_path, monkeypatch, where):
    import mocap.imitation_eval

    def never(*args, **kwargs):
        raise AssertionError("the evaluation ran before the output path was checked")

    monkeypatch.setattr(mocap.imitation_eval, "evaluate_imitator", never)
    afile = tmp_path / "afile"
    afile.write_text("x")
    json_path = {
        "folder": tmp_path,
        "under_a_file": afile / "x.json",
        "under_a_file_deeper": afile / "sub" / "x.json",
        "long_name": tmp_path / ("n" * 5000 + ".json"),
    }[where]
    result = invoke(["eval", amp_policy, "--json", json_path])
    line = assert_one_line_error(result, "--json")
    assert {"folder": "a directory; give a file name", "long_name": "longer than 255 bytes"}.get(where, f"{afile} is a file, not a folder") in line
    assert len(line) < 400
    assert_one_line_error(invoke(["eval", amp_policy, "--video", afile / "v"]), "--video", "a file, not a directory")
    for command in (["eval-noisy", amp_policy], ["recover", amp_policy]):
        assert_one_line_error(invoke([*command, "--json", json_path]), "--json")


def test_task_eval_json_under_a_file_is_refused_before_loading(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert_one_line_error(invoke(["task-eval", tmp_path / "no_run", "--json", afile / "x.json"]), "--json", "is a file, not a folder")


# ------------------------------------------------------------------ the small newcomer items (10)
@pytest.mark.parametrize("argv", [["-h"], ["eval", "-h"], ["checkpoint", "convert", "-h"], ["motions", "list", "-h"]])
def test_dash_h_is_help(argv):
    result = invoke(argv)
    assert result.exit_code == 0, result.output
    assert "Usage" in result.output and "--help" in result.output


def test_after_a_task_run_the_next_hint_names_task_eval(tmp_path, monkeypatch):
    import mocap.pipeline

    monkeypatch.setattr(mocap.pipeline, "run_pipeline", lambda *args, **kwargs: [])  # the run itself is not the point
    spec = Path(__file__).resolve().parents[1] / "specs" / "tasks" / "speed_pulse_v20.yaml"
    result = invoke(["run", spec, "--out", tmp_path / "speed"])
    assert result.exit_code == 0, result.output
    assert f"next: `mocap task-eval {tmp_path / 'speed'}`" in result.stdout
    assert "mocap eval " not in result.stdout


def test_comparison_shows_success_as_a_count_and_an_unmeasured_time_to_fall_as_a_dash():
    from mocap.matrix import render

    def one(mean: float) -> dict:
        return {"mean": mean, "std": None, "ci95": None, "n": 1}

    text = render(
        {
            "latent=pulse": {
                "eval/imitation/success_rate": one(14 / 15),
                "eval/imitation/succeeded": one(14.0),
                "eval/imitation/total": one(15.0),
                "eval/generation/time_to_fall_s": one(float("nan")),
            },
            "latent=vmp": {
                "eval/imitation/success_rate": {"mean": 0.6, "std": 0.1, "ci95": 0.2, "n": 3},
                "eval/imitation/succeeded": {"mean": 9.0, "std": 1.0, "ci95": 2.48, "n": 3},
                "eval/imitation/total": {"mean": 15.0, "std": 0.0, "ci95": 0.0, "n": 3},
                "eval/generation/time_to_fall_s": one(3.5),
            },
        }
    )
    assert "| latent=pulse | 14/15 | - |" in text, text
    assert "| latent=vmp | 9/15 ± 2.5 (n=3) | 3.5 |" in text, text
    assert "0.933" not in text and "nan" not in text


# ------------------------------------------------------------------ spec bounds, error-line length (fuzz 1, 3, 4)
AMP_BUNDLED = Path(__file__).resolve().parents[1] / "specs" / "imitator" / "amp_bundled.yaml"


@pytest.mark.parametrize(
    "override, fragment",
    [
        ("imitator.trainer.params.epochs=1000000000", "imitator.trainer.params.epochs: Input should be less than or equal to 1000"),
        ("imitator.trainer.params.horizon=1000000000", "imitator.trainer.params.horizon: Input should be less than or equal to 100000"),
        ("imitator.trainer.params.num_envs=100000000", "imitator.trainer.params.num_envs: Input should be less than or equal to"),
        ("imitator.trainer.params.minibatch_size=100000000000", "imitator.trainer.params.minibatch_size: Input should be less than or equal to"),
        ("imitator.trainer.params.total_env_steps=10000000000000", "imitator.trainer.params.total_env_steps: Input should be less than or equal to"),
        ("imitator.trainer.params.horizon=100000", "the batch num_envs × horizon = 12,800,000 samples exceeds 10,000,000"),
        ("seed=" + "1" * 30, "seed: Input should be less than or equal to"),
    ],
)
def test_counts_a_spec_sets_for_ppo_are_bounded(override, fragment):
    assert_one_line_error(invoke(["validate", AMP_BUNDLED, "--set", override]), fragment)


def test_a_seed_of_4301_digits_is_one_error_line(tmp_path):
    spec = tmp_path / "seed.yaml"
    spec.write_text(f"spec_version: 1\nextends: {AMP_BUNDLED}\nseed: {'1' * 4301}\n")
    line = assert_one_line_error(invoke(["validate", spec]), str(spec), "a number of more than 4,300 digits")
    assert len(line) < 300
    assert_one_line_error(invoke(["validate", AMP_BUNDLED, "--set", "seed=" + "1" * 4301]), "seed")


def test_error_lines_are_capped(tmp_path):
    import torch

    path = tmp_path / "policy.pt"  # a newer format written by a "mocap" whose version string is 1 MB
    torch.save({"format": "mocap.rl.policy/2", "versions": {"mocap": "9" * 1_000_000}}, path)
    line = assert_one_line_error(invoke(["eval", path]), str(path), "format version 2")
    assert len(line) <= 2100 and line.endswith("more characters]"), line[-80:]  # mocap.cli.MAX_ERROR_CHARS: 2000


# ------------------------------------------------------------------ a policy file's config, checked before any network is built (fuzz 1)
def _edit(data: dict, case: str) -> dict:
    config = dict(data["config"])
    edits = {
        "activation": {"activation": "nosuch"},
        "obs_dim_text": {"obs_dim": "abc"},
        "obs_dim_inf": {"obs_dim": float("inf")},
        "obs_dim_huge": {"obs_dim": 300_000_000},
        "hidden_text": {"actor_hidden": "abc"},
        "hidden_huge": {"actor_hidden": [583, 1_300_000]},
        "log_std_text": {"log_std_init": "x"},
        "obs_clip_text": {"obs_clip": "x"},
        "space_type": {"action_space": {"type": "weird"}},
    }
    if case in edits:
        return {**data, "config": {**config, **edits[case]}}
    if case == "config_text":
        return {**data, "config": "hello"}
    if case == "no_state_dict":
        return {k: v for k, v in data.items() if k != "state_dict"}
    assert case == "int_keys"
    return {**data, "state_dict": dict(enumerate(data["state_dict"].values()))}


@pytest.mark.parametrize(
    "case, fragment",
    [
        ("activation", "config.activation"),
        ("obs_dim_text", "config.obs_dim"),
        ("obs_dim_inf", "config.obs_dim"),
        ("obs_dim_huge", "config.obs_dim: Input should be less than or equal to 100000"),
        ("hidden_text", "config.actor_hidden"),
        ("hidden_huge", "config.actor_hidden.1: Input should be less than or equal to 100000"),
        ("log_std_text", "config.log_std_init"),
        ("obs_clip_text", "config.obs_clip"),
        ("space_type", "config.action_space"),
        ("config_text", "the policy's config is a str"),
        ("no_state_dict", "state_dict"),
        ("int_keys", "not a named tensor"),
    ],
)
def test_a_policy_file_with_a_bad_config_or_weights_is_one_error_line(amp_policy, tmp_path, monkeypatch, case, fragment):
    import torch

    import mocap.rl.networks

    def never(*args, **kwargs):
        raise AssertionError("the network was built before its config was checked")

    path = tmp_path / "policy.pt"
    torch.save(_edit(torch.load(amp_policy, weights_only=True), case), path)
    if case not in ("no_state_dict", "int_keys"):
        monkeypatch.setattr(mocap.rl.networks.ActorCritic, "from_config", never)
    assert_one_line_error(invoke(["eval", path]), str(path), fragment)


def test_an_unfinished_checkpoint_with_nan_env_steps_is_still_described():
    from mocap.checkpoint import training_status

    assert training_status({"finished": False, "env_steps": float("nan"), "params": {"total_env_steps": 100}}) == "in progress"
    assert training_status({"finished": False, "step": float("inf")}) == "in progress"


# ------------------------------------------------------------------ fuzz item 1, the rest: embedded specs, run folders, text, a full disk
@pytest.mark.parametrize("spec", [{"a": 1}, 5], ids=["dict", "int"])
def test_an_embedded_spec_that_is_no_text_is_one_error_line_in_every_command(amp_policy, tmp_path, spec):
    import torch

    path = tmp_path / "policy.pt"
    torch.save({**torch.load(amp_policy, weights_only=True), "spec": spec}, path)
    for command in (["eval", path], ["render", path, "--out", tmp_path / "x.mp4"], ["eval-noisy", path], ["recover", path]):
        assert_one_line_error(invoke(command), str(path), "embedded spec", f"not a valid spec (a {type(spec).__name__}, not YAML text)")


def test_a_config_that_is_text_is_one_error_line_in_every_command(amp_policy, tmp_path):
    import torch

    path = tmp_path / "policy.pt"
    torch.save({**torch.load(amp_policy, weights_only=True), "config": "hello"}, path)
    for command in (["render", path, "--out", tmp_path / "x.mp4"], ["eval-noisy", path], ["recover", path]):
        assert_one_line_error(invoke(command), str(path), "the policy's config is a str")


def test_a_run_folder_whose_stages_name_no_known_stage_is_one_error_line(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "spec.yaml").write_text(AMP_BUNDLED.read_text().replace("extends:", "#"))
    (run / "stages.json").write_text('[{"stage": "x"}]')
    assert_one_line_error(invoke(["eval", run]), str(run))


@pytest.mark.parametrize(
    "text, fragment",
    [
        ('imitator:\n  checkpoint: "a\\0b.pt"\n', "a NUL character"),
        ('description: "\\ud83d"\n', "a lone surrogate \\ud83d"),
        ('imitator:\n  checkpoint: "\\udcff.pt"\n', "a lone surrogate \\udcff"),
    ],
)
def test_a_spec_string_no_file_can_hold_is_one_error_line(tmp_path, text, fragment):
    spec = tmp_path / "odd.yaml"
    spec.write_text(f"spec_version: 1\nextends: {AMP_BUNDLED}\n{text}")
    for command in (["validate", spec], ["run", spec, "--out", tmp_path / "run"]):
        assert_one_line_error(invoke(command), str(spec), fragment)
    assert not (tmp_path / "run").exists()


def test_a_set_value_with_an_undecodable_byte_is_one_error_line():
    assert_one_line_error(invoke(["validate", AMP_BUNDLED, "--set", "description=caf\udce9"]), "--set", "a lone surrogate \\udce9")


def test_a_disk_full_before_the_run_starts_is_one_error_line(tmp_path, monkeypatch):
    import errno

    import mocap.pipeline

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(mocap.pipeline, "_write_pid", full)
    out = tmp_path / "run"
    line = assert_one_line_error(invoke(["run", AMP_BUNDLED, "--out", out]), str(out / ".mocap-run.lock"), "the disk is full")
    assert "free some space" in line


# ------------------------------------------------------------------ fuzz item 5: weights no trained policy holds
@pytest.mark.parametrize(
    "case, fragment",
    [
        ("nan", "holds NaN or infinite values"),
        ("inf", "holds NaN or infinite values"),
        ("bool", "holds torch.bool values, not real numbers"),
        ("complex", "holds torch.complex64 values, not real numbers"),
        ("negative_var", "normalizer variance 'obs_norm.var' is negative"),
    ],
)
def test_a_policy_file_with_weights_no_trained_policy_holds_is_one_error_line(amp_policy, tmp_path, case, fragment):
    import torch

    data = torch.load(amp_policy, weights_only=True)
    state = dict(data["state_dict"])
    weight = next(k for k in state if k.endswith(".weight"))
    if case == "negative_var":
        state["obs_norm.var"] = -state["obs_norm.var"]
    else:
        value = {"nan": float("nan"), "inf": float("inf")}.get(case)
        state[weight] = state[weight].clone().fill_(value) if value is not None else state[weight].to({"bool": torch.bool, "complex": torch.complex64}[case])
    path = tmp_path / "policy.pt"
    torch.save({**data, "state_dict": state}, path)
    for command in (["eval", path], ["eval-noisy", path]):
        assert_one_line_error(invoke(command), str(path), fragment)
