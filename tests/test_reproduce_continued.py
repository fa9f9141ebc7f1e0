"""Continued training runs: the continued distillations (the distill trainer's ``init_latent`` and
``lr_end``; the settle specs differ from the latent specs they continue only by the start, the
decaying rate, the budget and the schedules held at their ends), the task spec through one of them,
and the imitator continued from v15; the committed checkpoints embed those specs."""

from __future__ import annotations

from pathlib import Path

import pytest

from mocap.plugins import get_plugins
from mocap.spec import load_spec
from test_reproduce_spec import _checkpoint, checkpoint_dir

ROOT = Path(__file__).resolve().parents[1]
LATENT = ROOT / "specs" / "latent"

# spec, the spec it continues, the latent parameters it holds at the end of their schedules
SETTLE = [
    ("pulse_amp_v15_settle", "pulse_amp_v15", {"beta_start": 0.001, "beta_end": 0.001}),
    ("pulse_amp_v15_beta", "pulse_amp_v15", {"beta_start": 0.0001, "beta_end": 0.0001}),
    ("hybrid_rvq_amp_v15_settle", "hybrid_rvq_amp_v15", {"kl_weight": (0.5, 0.5), "mm_weight": (1.0, 1.0)}),
]


@pytest.mark.parametrize(("name", "source", "held"), SETTLE)
def test_a_settle_spec_is_its_source_continued_with_a_decaying_rate(name, source, held):
    plugins = get_plugins()
    spec = load_spec(LATENT / f"{name}.yaml", plugins).spec
    base = load_spec(LATENT / f"{source}.yaml", plugins).spec
    params = spec.latent.trainer.params
    assert Path(params["init_latent"]).resolve() == (checkpoint_dir(source) / "latent.pt").resolve()
    assert (params["lr"], params["lr_end"], params["total_env_steps"]) == (0.0005, 0.00005, 4_000_000)
    assert spec.latent.name == base.latent.name
    a, b = spec.latent.model_dump(), base.latent.model_dump()
    for key in ("init_latent", "lr_end", "total_env_steps"):
        a["trainer"]["params"].pop(key), b["trainer"]["params"].pop(key)
    for key, value in held.items():  # the source ended its anneal at these values
        got = a["params"].pop(key)
        b["params"].pop(key)
        assert (tuple(got) if isinstance(value, tuple) else got) == value, key
    assert a == b and spec.humanoid == base.humanoid and spec.motions == base.motions and spec.imitator == base.imitator


@pytest.mark.parametrize(("name", "source"), [("pulse_amp_v15_settle", "pulse_amp_v15"), ("hybrid_rvq_amp_v15_settle", "hybrid_rvq_amp_v15")])
def test_a_settled_checkpoint_embeds_its_spec_and_starts_from_its_source(name, source):
    data, embedded = _checkpoint(name, "latent.pt")
    spec = load_spec(LATENT / f"{name}.yaml", get_plugins()).spec
    assert embedded["name"] == spec.name == name.replace("_", "-")
    trainer = embedded["latent"]["trainer"]["params"]
    assert trainer["init_latent"] == f"../{source}/latent.pt" and trainer["lr_end"] == 0.00005
    assert embedded["imitator"]["checkpoint"] == "../imitator_amp_v15/policy.pt"
    assert data["extra"]["metrics"]["env_steps"] == 4001792 and data["extra"]["metrics"]["eval/total"] == 15


# a speed spec, the speed spec it differs from by the PULSE decoder only, that decoder
DECODER_ARMS = [
    ("speed_pulse_v15_beta", "speed_pulse_v15", "pulse_amp_v15_beta"),
    ("speed_pulse_v20_stage1", "speed_pulse_v20", "pulse_amp_v20"),
]


@pytest.mark.parametrize(("name", "source", "decoder"), DECODER_ARMS)
def test_a_speed_spec_through_another_decoder_differs_by_the_decoder_only(name, source, decoder):
    plugins = get_plugins()
    spec = load_spec(ROOT / "specs" / "tasks" / f"{name}.yaml", plugins).spec
    base = load_spec(ROOT / "specs" / "tasks" / f"{source}.yaml", plugins).spec
    assert Path(spec.latent.checkpoint).resolve() == (checkpoint_dir(decoder) / "latent.pt").resolve()
    assert spec.latent.model_copy(update={"checkpoint": None}) == base.latent.model_copy(update={"checkpoint": None})
    assert spec.task == base.task and spec.imitator == base.imitator and spec.humanoid == base.humanoid and spec.motions == base.motions


def test_pulse_amp_v15_beta_is_the_settle_continuation_with_beta_1e4():
    data, embedded = _checkpoint("pulse_amp_v15_beta", "latent.pt")
    _, settle = _checkpoint("pulse_amp_v15_settle", "latent.pt")
    assert embedded["name"] == "pulse-amp-v15-beta" and embedded["latent"]["trainer"] == settle["latent"]["trainer"]
    assert (embedded["latent"]["params"]["beta_start"], embedded["latent"]["params"]["beta_end"]) == (0.0001, 0.0001)
    assert (settle["latent"]["params"]["beta_start"], settle["latent"]["params"]["beta_end"]) == (0.001, 0.001)
    for doc in (embedded, settle):
        doc["latent"]["params"].pop("beta_start"), doc["latent"]["params"].pop("beta_end"), doc.pop("name"), doc.pop("description")
    assert embedded == settle and data["extra"]["metrics"]["env_steps"] == 4001792


def test_imitator_v16_is_continue_v15_and_continue_v16_carries_on():
    """checkpoints/imitator_amp_v16: the 8.03M snapshot of continue_v15.yaml from v15 (seed 0, sigma fixed by
    the policy it started from); continue_v16.yaml is the same recipe from v16."""
    import torch

    data, embedded = _checkpoint("imitator_amp_v16")
    plugins = get_plugins()
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v15.yaml", plugins).spec
    assert embedded["name"] == recipe.name and embedded["seed"] == 0
    assert embedded["imitator"]["trainer"]["params"]["init_policy"] == "../imitator_amp_v15/policy.pt"
    assert embedded["imitator"]["trainer"]["params"]["learn_std"] is False and data["extra"]["env_steps"] == 8028160
    assert torch.allclose(data["state_dict"]["log_std"], torch.full_like(data["state_dict"]["log_std"], -2.9))
    nxt = load_spec(ROOT / "specs" / "imitator" / "continue_v16.yaml", plugins).spec
    assert nxt.motions == recipe.motions and nxt.humanoid == recipe.humanoid and nxt.imitator.params == recipe.imitator.params
    a, b = nxt.imitator.trainer.params, recipe.imitator.trainer.params
    assert Path(a["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v16" / "policy.pt").resolve()
    assert {k: v for k, v in a.items() if k != "init_policy"} == {k: v for k, v in b.items() if k != "init_policy"}


def test_imitator_v17_is_continue_v16_with_kl_target_0003_and_continue_v17_carries_on():
    """checkpoints/imitator_amp_v17: the last (10.01M) snapshot of continue_v16.yaml + desired_kl 0.003 from v16
    (seed 0); continue_v17.yaml is that recipe from v17."""
    import torch

    data, embedded = _checkpoint("imitator_amp_v17")
    plugins = get_plugins()
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v16.yaml", plugins).spec
    assert embedded["name"] == recipe.name and embedded["seed"] == 0
    trained = embedded["imitator"]["trainer"]["params"]
    assert trained["init_policy"] == "../imitator_amp_v16/policy.pt" and trained["desired_kl"] == 0.003
    assert data["extra"]["env_steps"] == 10010624
    assert torch.allclose(data["state_dict"]["log_std"], torch.full_like(data["state_dict"]["log_std"], -2.9))
    nxt = load_spec(ROOT / "specs" / "imitator" / "continue_v17.yaml", plugins).spec
    assert nxt.motions == recipe.motions and nxt.humanoid == recipe.humanoid and nxt.imitator.params == recipe.imitator.params
    a, b = nxt.imitator.trainer.params, recipe.imitator.trainer.params
    assert Path(a["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v17" / "policy.pt").resolve()
    assert a["desired_kl"] == 0.003 and b["desired_kl"] == 0.01
    skip = ("init_policy", "desired_kl")
    assert {k: v for k, v in a.items() if k not in skip} == {k: v for k, v in b.items() if k not in skip}


def test_imitator_v18_is_continue_v17_with_smoothed_velocities_and_continue_v18_carries_on():
    """checkpoints/imitator_amp_v18: the last (6.01M) snapshot of continue_v17_vel.yaml from v17 (seed 0): v17's recipe
    with PHC's code's reference velocities; continue_v18.yaml is that recipe from v18."""
    data, embedded = _checkpoint("imitator_amp_v18")
    plugins = get_plugins()
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v17_vel.yaml", plugins).spec
    base = load_spec(ROOT / "specs" / "imitator" / "continue_v17.yaml", plugins).spec
    assert embedded["name"] == recipe.name and embedded["seed"] == 0
    assert embedded["motions"]["params"]["velocities"] == "central_smoothed" and embedded["motions"]["params"]["velocity_sigma"] == 2.0
    assert embedded["imitator"]["trainer"]["params"]["init_policy"] == "../imitator_amp_v17/policy.pt"
    assert data["extra"]["env_steps"] == 6012928
    # the lever is the velocities only: the rest of the motions, the humanoid and the imitator are v17's recipe
    assert recipe.motions.params["velocities"] == "central_smoothed" and base.motions.params["velocities"] == "forward"
    assert {k: v for k, v in recipe.motions.params.items() if k != "velocities"} == {k: v for k, v in base.motions.params.items() if k != "velocities"}
    assert recipe.humanoid == base.humanoid and recipe.imitator == base.imitator
    nxt = load_spec(ROOT / "specs" / "imitator" / "continue_v18.yaml", plugins).spec
    assert nxt.motions == recipe.motions and nxt.humanoid == recipe.humanoid and nxt.imitator.params == recipe.imitator.params
    a, b = nxt.imitator.trainer.params, recipe.imitator.trainer.params
    assert Path(a["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v18" / "policy.pt").resolve()
    assert {k: v for k, v in a.items() if k != "init_policy"} == {k: v for k, v in b.items() if k != "init_policy"}


@pytest.mark.parametrize(("name", "source", "steps"), [("v19", "v18", 6012928), ("v20", "v19", 4014080)])
def test_an_imitator_continued_on_smoothed_velocities_and_its_next_spec(name, source, steps):
    """checkpoints/imitator_amp_<name>: the last snapshot of continue_<source>.yaml from <source> (seed 0);
    continue_<name>.yaml is the same recipe from <name>."""
    data, embedded = _checkpoint(f"imitator_amp_{name}")
    plugins = get_plugins()
    recipe = load_spec(ROOT / "specs" / "imitator" / f"continue_{source}.yaml", plugins).spec
    assert embedded["name"] == recipe.name and embedded["seed"] == 0
    assert embedded["motions"]["params"]["velocities"] == "central_smoothed"
    assert embedded["imitator"]["trainer"]["params"]["init_policy"] == f"../imitator_amp_{source}/policy.pt"
    assert data["extra"]["env_steps"] == steps
    nxt = load_spec(ROOT / "specs" / "imitator" / f"continue_{name}.yaml", plugins).spec
    assert nxt.motions == recipe.motions and nxt.humanoid == recipe.humanoid and nxt.imitator.params == recipe.imitator.params
    a, b = nxt.imitator.trainer.params, recipe.imitator.trainer.params
    assert Path(a["init_policy"]).resolve() == (checkpoint_dir(f"imitator_amp_{name}") / "policy.pt").resolve()
    assert {k: v for k, v in a.items() if k != "init_policy"} == {k: v for k, v in b.items() if k != "init_policy"}
