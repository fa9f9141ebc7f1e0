"""The latent spaces distilled from ``checkpoints/imitator``: each stage-1 spec is its v15 recipe with
the v20 teacher and the reference velocities v20 was trained on (nothing else differs), and each stage-2 spec
continues its stage 1 exactly as the v15 continuation continued its own. Committed checkpoints embed them."""

from __future__ import annotations

from pathlib import Path

import pytest

from mocap.plugins import get_plugins
from mocap.spec import load_spec
from test_reproduce_spec import _checkpoint, checkpoint_dir

ROOT = Path(__file__).resolve().parents[1]
LATENT = ROOT / "specs" / "latent"

# v20 stage 1, its v15 recipe; v20 stage 2, its v15 counterpart
STAGES = [
    ("pulse_amp_v20", "pulse_amp_v15", "pulse_amp_v20_beta", "pulse_amp_v15_beta"),
    ("hybrid_rvq_amp_v20", "hybrid_rvq_amp_v15", "hybrid_rvq_amp_v20_settle", "hybrid_rvq_amp_v15_settle"),
]


def _spec(name: str):
    return load_spec(LATENT / f"{name}.yaml", get_plugins()).spec


@pytest.mark.parametrize(("name", "recipe", "_s2", "_r2"), STAGES)
def test_a_v20_latent_is_its_v15_recipe_with_the_v20_teacher_and_its_velocities(name, recipe, _s2, _r2):
    spec, base = _spec(name), _spec(recipe)
    assert Path(spec.imitator.checkpoint).resolve() == (checkpoint_dir("imitator_amp_v20") / "policy.pt").resolve()
    assert spec.imitator.model_copy(update={"checkpoint": None}) == base.imitator.model_copy(update={"checkpoint": None})
    teacher = _checkpoint("imitator_amp_v20")[1]["motions"]["params"]
    motions = spec.motions.params
    assert (motions["velocities"], motions["velocity_sigma"]) == (teacher["velocities"], teacher["velocity_sigma"]) == ("central_smoothed", 2.0)
    assert base.motions.params.get("velocities", "forward") == "forward"  # the v15 teacher's rule
    rest = {k: v for k, v in motions.items() if k not in ("velocities", "velocity_sigma")}
    assert rest == {k: v for k, v in base.motions.params.items() if k not in ("velocities", "velocity_sigma")}
    assert spec.latent == base.latent and spec.humanoid == base.humanoid and spec.simulator == base.simulator


@pytest.mark.parametrize(("stage1", "_r1", "name", "counterpart"), STAGES)
def test_a_v20_stage_two_continues_its_stage_one_as_v15_did(stage1, _r1, name, counterpart):
    spec, base = _spec(name), _spec(counterpart)
    params = spec.latent.trainer.params
    assert Path(params["init_latent"]).resolve() == (checkpoint_dir(stage1) / "latent.pt").resolve()
    a, b = spec.latent.model_dump(), base.latent.model_dump()
    a["trainer"]["params"].pop("init_latent"), b["trainer"]["params"].pop("init_latent")
    assert a == b  # the same rate decay, budget and held schedules
    assert spec.imitator == _spec(stage1).imitator and spec.motions == _spec(stage1).motions


@pytest.mark.parametrize(("name", "decoder"), [("speed_pulse", "pulse_amp_v20_beta"), ("speed_hybrid_rvq", "hybrid_rvq_amp_v20_settle")])
def test_a_v20_task_spec_is_its_v15_one_through_the_v20_decoder(name, decoder):
    plugins = get_plugins()
    spec = load_spec(ROOT / "specs" / "tasks" / f"{name}_v20.yaml", plugins).spec
    base = load_spec(ROOT / "specs" / "tasks" / f"{name}_v15.yaml", plugins).spec
    assert Path(spec.latent.checkpoint).resolve() == (checkpoint_dir(decoder) / "latent.pt").resolve()
    assert Path(spec.imitator.checkpoint).resolve() == (checkpoint_dir("imitator_amp_v20") / "policy.pt").resolve()
    assert spec.latent.model_copy(update={"checkpoint": None}) == base.latent.model_copy(update={"checkpoint": None})
    assert spec.task == base.task and spec.humanoid == base.humanoid and spec.simulator == base.simulator
    assert spec.motions.params["velocities"] == "central_smoothed" and spec.motions.name == base.motions.name


@pytest.mark.parametrize(
    ("name", "steps", "start"),
    [
        ("pulse_amp_v20", 10_000_384, None),
        ("hybrid_rvq_amp_v20", 8_001_536, None),
        ("pulse_amp_v20_beta", 4_001_792, "pulse_amp_v20"),
        ("hybrid_rvq_amp_v20_settle", 4_001_792, "hybrid_rvq_amp_v20"),
        ("pulse_amp_v20_stage3", 3_000_320, "pulse_amp_v20_beta"),
    ],
)
def test_a_committed_v20_latent_embeds_its_spec_and_teacher(name, steps, start):
    data, embedded = _checkpoint(name, "latent.pt")
    assert embedded["name"] == _spec(name).name == name.replace("_", "-")
    assert embedded["imitator"]["checkpoint"] == "../imitator/policy.pt"
    assert embedded["motions"]["params"]["velocities"] == "central_smoothed"
    assert embedded["latent"]["trainer"]["params"].get("init_latent") == (None if start is None else f"../{checkpoint_dir(start).name}/latent.pt")
    assert data["extra"]["metrics"]["env_steps"] == steps and data["extra"]["metrics"]["eval/total"] == 15


# committed task policies through the v20 latent spaces: (checkpoint = spec name, decoder)
V20_TASK_POLICIES = [("speed_pulse_v20", "pulse_amp_v20_beta"), ("speed_hybrid_rvq_v20", "hybrid_rvq_amp_v20_settle")]


@pytest.mark.parametrize(("name", "decoder"), V20_TASK_POLICIES)
def test_a_v20_task_policy_was_trained_by_its_spec_for_8m_steps(name, decoder):
    spec = load_spec(ROOT / "specs" / "tasks" / f"{name}.yaml", get_plugins()).spec
    _, embedded = _checkpoint(name, "task_policy.pt")
    params = embedded["task"]["trainer"]["params"]
    assert embedded["name"] == spec.name and embedded["task"]["name"] == spec.task.name
    assert params["total_env_steps"] == 8_000_000 and embedded["simulator"]["params"]["threads"] == 1
    expected = dict(spec.task.trainer.params)
    expected.pop("total_env_steps")
    assert all(params[k] == (list(v) if isinstance(v, tuple) else v) for k, v in expected.items())
    assert embedded["latent"]["checkpoint"] == f"../{checkpoint_dir(decoder).name}/latent.pt"
    assert embedded["imitator"]["checkpoint"] == "../imitator/policy.pt"


def test_the_v20_vmp_task_policy_was_trained_by_its_spec_through_the_committed_tracker():
    spec = load_spec(ROOT / "specs" / "tasks" / "speed_vmp_v20.yaml", get_plugins()).spec
    _, embedded = _checkpoint("speed_vmp_v20", "task_policy.pt")
    params = embedded["task"]["trainer"]["params"]
    assert embedded["name"] == spec.name and embedded["task"]["name"] == spec.task.name == "speed"
    assert params["total_env_steps"] == 8_000_000 and embedded["simulator"]["params"]["threads"] == 1
    expected = dict(spec.task.trainer.params)
    expected.pop("total_env_steps")
    assert all(params[k] == (list(v) if isinstance(v, tuple) else v) for k, v in expected.items())
    assert embedded["latent"]["checkpoint"] == "../vmp/latent.pt"
    assert embedded["latent"]["params"]["task_action"] == "latent"


def test_the_v20_vmp_spec_is_vmp_amp_on_the_teachers_humanoid_with_a_distilled_start():
    spec, base = _spec("vmp_amp_v20"), _spec("vmp_amp")
    teacher = _checkpoint("imitator_amp_v20")[1]
    assert Path(spec.imitator.checkpoint).resolve() == (checkpoint_dir("imitator_amp_v20") / "policy.pt").resolve()
    for key in ("shoulder_turns", "shoulder_order"):
        assert spec.humanoid.params[key] == teacher["humanoid"]["params"][key]
    for key in ("velocities", "velocity_sigma"):
        assert spec.motions.params[key] == teacher["motions"]["params"][key]
    assert spec.imitator.params["action"] == teacher["imitator"]["params"]["action"] == "residual"
    assert spec.latent.params == base.latent.params and spec.simulator == base.simulator
    mine, theirs = spec.latent.trainer.params, base.latent.trainer.params
    assert mine["vae"] == theirs["vae"] and mine["tracker"] == theirs["tracker"] and theirs["distill"] is None
    assert mine["distill"]["total_env_steps"] > 0
    changed = {k for k in set(mine["ppo"]) | set(theirs["ppo"]) if mine["ppo"].get(k) != theirs["ppo"].get(k)}
    assert changed == {"total_env_steps", "log_std_init", "learn_std", "desired_kl"}


@pytest.mark.parametrize(("name", "conditioning"), [("vmp_amp_v20", "LM"), ("vmp_amp_v20_m", "M")])
def test_the_committed_v20_vmp_embeds_its_spec_teacher_and_budgets(name, conditioning):
    data, embedded = _checkpoint(name, "latent.pt")
    assert embedded["name"] == _spec(name).name == name.replace("_", "-")
    assert embedded["imitator"]["checkpoint"] == "../imitator/policy.pt"
    params = embedded["latent"]["trainer"]["params"]
    assert params["distill"]["total_env_steps"] == 6_000_000 and params["tracker"]["conditioning"] == conditioning
    assert data["tracker"]["metrics"]["env_steps"] == 2_007_040  # PPO after the distillation (8192-step iterations)


def test_the_v20_vmp_m_ablation_differs_from_lm_by_the_conditioning_only():
    lm, m = _spec("vmp_amp_v20").model_dump(), _spec("vmp_amp_v20_m").model_dump()
    assert m["latent"]["trainer"]["params"]["tracker"].pop("conditioning") == "M"
    assert lm["latent"]["trainer"]["params"]["tracker"].pop("conditioning") == "LM"
    for key in ("name", "description"):
        lm.pop(key), m.pop(key)
    assert lm == m


def test_the_third_pulse_stage_continues_the_second_with_a_lower_rate_only():
    """checkpoints/pulse (pulse_amp_v20_stage3): stage 2 (pulse_amp_v20_beta) continued from its latent.pt with the
    rate 2e-4 -> 2e-5 for 3M env steps; nothing else differs."""
    spec, base = _spec("pulse_amp_v20_stage3"), _spec("pulse_amp_v20_beta")
    params = spec.latent.trainer.params
    assert Path(params["init_latent"]).resolve() == (checkpoint_dir("pulse_amp_v20_beta") / "latent.pt").resolve()
    assert (params["lr"], params["lr_end"], params["total_env_steps"]) == (2e-4, 2e-5, 3_000_000)
    a, b = spec.latent.model_dump(), base.latent.model_dump()
    for key in ("init_latent", "lr", "lr_end", "total_env_steps"):
        a["trainer"]["params"].pop(key), b["trainer"]["params"].pop(key)
    assert a == b
    assert spec.imitator == base.imitator and spec.motions == base.motions and spec.humanoid == base.humanoid
