"""`mocap --help`, `mocap validate` (and `schema`, `switches`, `plugins`) import neither torch nor
MuJoCo (they took 3-5 s, mostly importing torch): every entry-point module registers its components
with torch-free params classes and :func:`mocap.plugins.lazy` factories, imported only when a
component is built.

The CLI checks run in a fresh interpreter (this test process has imported torch long ago)."""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mocap.plugins import LazyFactory, get_plugins, lazy

REPO = Path(__file__).resolve().parents[1]

#: runs ``mocap.cli.main(argv)`` and prints the exit code and which heavy modules it imported
PROBE = """
import json, sys
from mocap.cli import main
rc = main(sys.argv[1:])
heavy = sorted(m for m in ("torch", "mujoco", "warp", "mujoco_warp") if m in sys.modules)
print("\\nPROBE " + json.dumps({"rc": rc, "heavy": heavy}))
"""


def _cli(*args: str) -> tuple[dict, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    env["COLUMNS"] = "200"
    proc = subprocess.run([sys.executable, "-c", PROBE, *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("PROBE ")][-1]
    return json.loads(line[len("PROBE ") :]), proc.stdout + proc.stderr


@pytest.mark.parametrize(
    "args",
    [
        ("--help",),
        ("validate", "specs/imitator/amp_bundled.yaml"),
        ("validate", "specs/tasks/speed_pulse.yaml"),
        ("validate", "specs/quickstart.yaml"),
        ("schema",),
        ("switches",),
    ],
    ids=lambda a: " ".join(a),
)
def test_the_light_commands_import_neither_torch_nor_mujoco(args):
    if args[0] == "validate":
        assert (REPO / args[1]).is_file(), args[1]
    result, output = _cli(*args)
    assert result["rc"] == 0, output
    assert result["heavy"] == [], f"`mocap {' '.join(args)}` imported {result['heavy']}"
    assert "warning" not in output, output  # no plugin failed to load


def test_a_failing_validate_imports_no_torch_either(tmp_path):
    spec = tmp_path / "bad.yaml"
    spec.write_text("name: bad\nspec_version: 1\nimitator: {name: phcx}\n")
    result, output = _cli("validate", str(spec))
    assert result["rc"] == 2 and "error:" in output, output
    assert result["heavy"] == []


def test_plugins_lists_every_component_without_torch():
    result, output = _cli("plugins", "--json")
    assert result["rc"] == 0 and result["heavy"] == [], output
    listed = json.loads(output[: output.rindex("\nPROBE ")])
    assert listed["failures"] == []
    names = {p["name"] for p in listed["plugins"]}
    assert {"distill", "evaluation", "generation", "hierarchy", "imitator_phc", "rl", "sim_mujoco", "tasks"} <= names
    pset = get_plugins()  # the same registry, in this process
    expected = {f"{kind}:{name}" for kind, comps in pset.components.items() for name in comps}
    assert {c for p in listed["plugins"] for c in p["registers"]} == expected


def test_every_lazy_factory_resolves_to_a_callable():
    """A misspelt ``lazy("module:name")`` would only fail when a spec builds the component."""
    lazies = []
    for kind, comps in get_plugins().components.items():
        for name, comp in comps.items():
            factory = comp.resolved_factory()
            assert callable(factory) and not isinstance(factory, LazyFactory), (kind, name)
            if isinstance(comp.factory, LazyFactory):
                lazies.append(comp.factory.target)
                assert inspect.signature(comp.factory) == inspect.signature(factory), (kind, name)
    assert len(lazies) >= 25  # the built-in trainers, imitators, latent spaces, tasks, simulators


def test_lazy_factory():
    factory = lazy("mocap.humanoids:make_amp")
    assert repr(factory) == "lazy('mocap.humanoids:make_amp')" and factory.target == "mocap.humanoids:make_amp"
    from mocap.humanoids import AmpParams, make_amp

    assert factory.resolve() is make_amp
    assert factory(AmpParams()).num_bodies == 15
    for bad in ("mocap.humanoids", ":make_amp", "mocap.humanoids:"):
        with pytest.raises(ValueError, match="package.module:attribute"):
            lazy(bad)
    with pytest.raises(AttributeError):
        lazy("mocap.humanoids:no_such_factory").resolve()


def test_the_task_env_sees_a_lazy_task_factory_signature():
    """The task env passes ``motions=`` to a task factory that names it: through the lazy factory."""
    from mocap.task_env import _accepts

    assert _accepts(get_plugins().get("task", "vr_tracking").resolved_factory(), "motions")
    # a lazy factory shows its target's signature, not its own (*args, **kwargs)
    assert not _accepts(lazy("mocap.humanoids:make_amp"), "motions")
    assert not _accepts(lazy("mocap.humanoids:make_amp").resolve(), "motions")


def test_moved_names_stay_reachable_from_the_entry_modules():
    import mocap.distill
    import mocap.evaluation
    import mocap.generation
    import mocap.hierarchy
    from mocap.distill_files import save_latent
    from mocap.imitation_eval import evaluate_imitator
    from mocap.task_env import TaskEnv

    assert mocap.distill.save_latent is save_latent
    assert mocap.evaluation.evaluate_imitator is evaluate_imitator
    assert mocap.hierarchy.TaskEnv is TaskEnv
    assert callable(mocap.generation.evaluate_generation)
    with pytest.raises(AttributeError):
        mocap.evaluation.no_such_name  # noqa: B018


def test_the_torch_free_activation_names_match_the_networks():
    from mocap.bounds import ACTIVATION_NAMES
    from mocap.rl.networks import ACTIVATIONS

    assert sorted(ACTIVATION_NAMES) == sorted(ACTIVATIONS)
