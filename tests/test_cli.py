"""The CLI through its real entry point (in-process) and the installed console script."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from toy_plugins import TOY_SPEC

from mocap.testing import invoke


@pytest.fixture
def spec_file(tmp_path: Path) -> Path:
    path = tmp_path / "toy.yaml"
    path.write_text(TOY_SPEC)
    return path


def assert_clean_error(result, *needles):
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in result.stderr, result.stderr


def test_plugins_lists_builtins_and_local(toy_plugins):
    result = invoke(["plugins", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    by_name = {p["name"]: p for p in data["plugins"]}
    assert by_name["toy"]["registers"] and "latent:toy_latent" in by_name["toy"]["registers"]
    assert by_name["sim_mujoco"]["package"] == "mocap"
    table = invoke(["plugins"])
    assert table.exit_code == 0 and "toy" in table.stdout


def test_validate_ok(toy_plugins, spec_file):
    result = invoke(["validate", spec_file])
    assert result.exit_code == 0, result.output
    assert "valid spec 'toy'" in result.stdout and "imitator (" in result.stdout


def test_validate_misspelt_latent(toy_plugins, spec_file):
    spec_file.write_text(TOY_SPEC.replace("name: toy_latent", "name: toy_latnet"))
    assert_clean_error(invoke(["validate", spec_file]), str(spec_file), "latent.name", "toy_latent, toy_latent_b")


def test_validate_yaml_syntax_error_shows_line_and_column(toy_plugins, spec_file):
    spec_file.write_text("spec_version: 1\nname: [unclosed\n")
    result = invoke(["validate", spec_file])
    assert_clean_error(result, "YAML syntax error")
    assert f"{spec_file}:3:1" in result.stderr or f"{spec_file}:2:" in result.stderr


def test_validate_nested_param_type_error(toy_plugins, spec_file):
    assert_clean_error(invoke(["validate", spec_file, "--set", "imitator.params.optim.lr=fast"]), "imitator.params.optim.lr", "'fast'")


def test_validate_missing_file(toy_plugins, tmp_path):
    assert_clean_error(invoke(["validate", tmp_path / "nope.yaml"]), "no such spec file")


def test_schema_types_component_params(toy_plugins):
    result = invoke(["schema"])
    assert result.exit_code == 0, result.output
    schema = json.loads(result.stdout)
    text = json.dumps(schema["properties"]["latent"])
    assert '"const": "toy_latent"' in text and "ToyModelParams" in text and "Optim" in schema["$defs"]
    # a stage's trainer params are typed by the registered trainers (they were a free-form mapping)
    trainer = json.dumps(schema["$defs"]["StageSpec"]["properties"]["trainer"])
    assert '"const": "count"' in trainer and "CountParams" in json.dumps(schema) and '"null"' in trainer


def test_run_and_rerun_reuses(toy_plugins, spec_file, tmp_path):
    out = tmp_path / "runs" / "toy"
    first = invoke(["run", spec_file, "--out", out])
    assert first.exit_code == 0, first.output
    assert "report" in first.stdout and (out / "report.md").is_file()
    second = invoke(["run", spec_file, "--out", out])
    assert second.exit_code == 0 and second.stdout.count("reusing") == 2


def test_usage_error_is_clean(toy_plugins):
    result = invoke(["validate"])
    assert result.exit_code == 2 and "Traceback" not in result.output


def test_console_script_plugins():
    exe = shutil.which("mocap")
    assert exe, "the mocap console script is not installed"
    proc = subprocess.run([exe, "plugins"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "sim_mujoco" in proc.stdout and "mocap" in proc.stdout
