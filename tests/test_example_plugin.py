"""A third-party plugin package outside the core, installed with pip, is listed and usable in a spec."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "mocap-example-plugin"


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> dict[str, str]:
    target = tmp_path_factory.mktemp("site")
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target", str(target), str(EXAMPLE)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(target), env.get("PYTHONPATH", "")]))
    return env


def mocap(args: list[str], env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    exe = shutil.which("mocap")
    assert exe
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=600, env=env, cwd=cwd)


def test_installed_plugin_is_listed(installed, tmp_path):
    proc = mocap(["plugins", "--json"], installed, tmp_path)
    assert proc.returncode == 0, proc.stderr
    plugins = {p["name"]: p for p in json.loads(proc.stdout)["plugins"]}
    assert plugins["example"]["package"] == "mocap-example-plugin"
    assert set(plugins["example"]["registers"]) == {"motion_source:sway", "metric:root_drift", "task:face_heading", "latent:tiny_ae"}


def test_installed_plugin_is_usable_in_a_spec(installed, tmp_path):
    spec = EXAMPLE / "sway.yaml"
    proc = mocap(["run", str(spec), "--out", str(tmp_path / "runs" / "sway"), "--set", "motions.params.seconds=0.5"], installed, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    table = json.loads((tmp_path / "runs" / "sway" / "imitation_eval.json").read_text())
    assert list(table["clips"]) == ["sway"]
    assert table["units"]["root_drift"] == "mm" and table["aggregate"]["root_drift"] >= 0.0


def test_without_the_plugin_the_spec_names_the_missing_source(tmp_path):
    env = dict(os.environ)
    proc = mocap(["validate", str(EXAMPLE / "sway.yaml")], env, tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "motions.name" in proc.stderr and "deepmimic" in proc.stderr
