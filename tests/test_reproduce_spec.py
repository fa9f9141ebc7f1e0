"""``specs/reproduce/bundled.yaml`` retrains the four first-generation models from nothing: the
imitator stage is trained (not loaded), shared by every cell (one artifact key: trained once), and
each latent cell uses the recipe of its spec in ``specs/latent/``. Every other committed checkpoint
is accounted for by the spec that continued it (tested below and in the files named there)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from committed import committed_files

from mocap.matrix import load_cells
from mocap.pipeline import stage_keys
from mocap.plugins import get_plugins
from mocap.spec import load_spec

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "specs" / "reproduce" / "bundled.yaml"
# the canonical checkpoint directories (issue 23): the trained model each names, by its spec's name
CANONICAL = {"imitator_amp_v20": "imitator", "pulse_amp_v20_stage3": "pulse", "hybrid_rvq_amp_v20_settle": "hybrid_rvq", "vmp_amp_v20": "vmp"}


def checkpoint_dir(name: str) -> Path:
    """``checkpoints/<dir>`` of the model trained by the spec (or run) ``name``."""
    return ROOT / "checkpoints" / CANONICAL.get(name, name)


def _checkpoint(name: str, file: str = "policy.pt") -> tuple[dict, dict]:
    """A committed checkpoint's contents and the spec it embeds (parsed)."""
    import yaml

    from mocap.checkpoint import load_checkpoint

    data = load_checkpoint(checkpoint_dir(name) / file)
    return data, yaml.safe_load(data["spec"])


def test_reproduce_spec_trains_everything_and_shares_the_imitator():
    plugins = get_plugins()
    cells = {cell.name: resolved for cell, resolved in load_cells(SPEC, plugins)}
    assert set(cells) == {"latent-none", "latent-pulse", "latent-hybrid_rvq", "latent-vmp"}
    committed = {p.parent.name for p in committed_files("checkpoints", "*/*.pt")}  # tracked by git: not a user's export
    latents = {f"{r.spec.latent.name}_amp" for r in cells.values() if r.spec.latent is not None}
    # imitator _v2 and _v3: the same recipe trained further; vmp_amp: an earlier recipe, superseded by vmp_amp_v2;
    # vmp_amp_m: the M-conditioning ablation of the vmp cell; pulse_amp_v2: the pulse recipe with the
    # _v2 imitator as the teacher (tests below); imitator _v4: _v3 continued by specs/imitator/continue_v3.yaml;
    # imitator _v5: _v4 continued by specs/imitator/continue_v4_contacts_getup.yaml (tested below);
    # imitator _v6: _v4 continued on the x-z-y humanoid variant by specs/imitator/continue_v4_shoulders.yaml (tested below);
    # imitator _v7: _v6 continued by specs/imitator/continue_v6.yaml with 256 envs (tested below)
    covered = {"imitator_amp", "imitator_amp_v2", "imitator_amp_v3", "imitator_amp_v4", "imitator_amp_v5", "imitator_amp_v6", "vmp_amp_v2", "vmp_amp_m"}
    covered |= {"imitator_amp_v7", "pulse_amp_v7", "hybrid_rvq_amp_v7"}  # the v7 latent specs, tested below
    covered |= {"imitator_amp_v8"}  # _v7 continued by continue_v7.yaml with gamma 0.99 (tested below)
    covered |= {"imitator_amp_v11"}  # _v8 through the hard-clip curriculum, then continue_v8.yaml (tested below)
    covered |= {"imitator_amp_v12"}  # _v11 after two curriculum cycles (curriculum_hard_v11.yaml, continue_v11.yaml; tested below)
    covered |= {"imitator_amp_v13", "imitator_amp_v14"}  # _v12 and _v13 continued by continue_v12/_v13.yaml (tested below)
    covered |= {"imitator_amp_v16"}  # _v15 continued by continue_v15.yaml (tests/test_reproduce_continued.py)
    covered |= {"imitator_amp_v17"}  # _v16 continued by continue_v16.yaml + desired_kl 0.003 (tests/test_reproduce_continued.py)
    covered |= {
        "imitator_amp_v18",
        "imitator_amp_v19",
        "imitator_amp_v20",
    }  # _v17 by continue_v17_vel.yaml, then continue_v18/_v19.yaml (tests/test_reproduce_continued.py)
    covered |= {"imitator_amp_v15"}  # _v14 continued by continue_v14.yaml with PHC's fixed sigma (tested below)
    covered |= {"pulse_amp_v15", "hybrid_rvq_amp_v15"}  # the v7 latent recipes from _v15 with longer budgets (tested below)
    covered |= {
        "pulse_amp_v15_settle",
        "pulse_amp_v15_beta",
        "hybrid_rvq_amp_v15_settle",
    }  # pulse_amp_v15 continued with a decaying rate (tests/test_reproduce_continued.py)
    covered |= {
        "pulse_amp_v20",
        "pulse_amp_v20_beta",
        "pulse_amp_v20_stage3",
        "hybrid_rvq_amp_v20",
        "hybrid_rvq_amp_v20_settle",
        "speed_pulse_v20",
        "speed_hybrid_rvq_v20",
        "speed_vmp_v20",
    }  # the v15 latent and task recipes from imitator_amp_v20 (tests/test_reproduce_v20_latents.py)
    covered |= {"vmp_amp_v20", "vmp_amp_v20_m"}  # vmp_amp.yaml on the v20 humanoid, distilled from imitator_amp_v20 (tests/test_reproduce_v20_latents.py)
    covered = {CANONICAL.get(name, name) for name in covered}
    covered |= {name for name, *_ in TASK_POLICIES}  # task policies of specs/tasks/*_v15.yaml (tested below)
    covered |= {"pulse_amp_v2"}
    covered |= {"realism_judge"}  # not a pipeline model: bench/train_realism_judge.py (its MODEL_CARD; tests/test_realism.py)
    covered |= latents
    assert committed <= covered, f"committed checkpoints without a cell: {committed - covered}"
    keys = {name: stage_keys(r.spec) for name, r in cells.items()}
    assert len({k["imitator"] for k in keys.values()}) == 1  # one imitator artifact for all cells
    imitator_recipe = load_spec(ROOT / "specs" / "imitator" / "amp_bundled.yaml", plugins).spec
    for name, resolved in cells.items():
        spec = resolved.spec
        assert spec.imitator.checkpoint is None and spec.imitator.trainer is not None, name
        assert spec.imitator.model_dump() == imitator_recipe.imitator.model_dump(), name
        if spec.latent is None:
            continue
        assert spec.latent.checkpoint is None and spec.latent.trainer is not None, name
        recipe = load_spec(ROOT / "specs" / "latent" / f"{spec.latent.name}_amp.yaml", plugins).spec
        assert spec.latent.model_dump() == recipe.latent.model_dump(), f"{name}: differs from specs/latent/{spec.latent.name}_amp.yaml"


def test_vmp_m_ablation_differs_from_the_vmp_recipe_only_by_conditioning():
    """checkpoints/vmp_amp_m is reproduced by specs/latent/vmp_amp_m.yaml: the vmp cell's recipe
    with M conditioning (VMP Table 2), nothing else changed."""
    plugins = get_plugins()
    lm = load_spec(ROOT / "specs" / "latent" / "vmp_amp.yaml", plugins).spec.latent.model_dump()
    m = load_spec(ROOT / "specs" / "latent" / "vmp_amp_m.yaml", plugins).spec.latent.model_dump()
    assert lm["trainer"]["params"]["tracker"]["conditioning"] == "LM"
    assert m["trainer"]["params"]["tracker"]["conditioning"] == "M"
    m["trainer"]["params"]["tracker"]["conditioning"] = "LM"
    assert m == lm


def test_pulse_v2_differs_from_the_pulse_recipe_only_by_its_teacher():
    plugins = get_plugins()
    v1 = load_spec(ROOT / "specs" / "latent" / "pulse_amp.yaml", plugins).spec
    v2 = load_spec(ROOT / "specs" / "latent" / "pulse_amp_v2.yaml", plugins).spec
    assert v1.latent.model_dump() == v2.latent.model_dump()
    assert Path(v1.imitator.checkpoint).parent.name == "imitator_amp"
    assert Path(v2.imitator.checkpoint).parent.name == "imitator_amp_v2"
    a, b = v1.imitator.model_dump(), v2.imitator.model_dump()
    a.pop("checkpoint"), b.pop("checkpoint")
    assert a == b


@pytest.mark.parametrize("family", ["pulse", "hybrid_rvq"])
def test_the_v4_latent_specs_differ_from_their_recipe_only_by_teacher_and_threads(family):
    """specs/latent/<family>_amp_v4.yaml: the committed recipe with imitator_amp_v4 as the teacher and
    2 torch threads (run alone), nothing else changed."""
    plugins = get_plugins()
    base = load_spec(ROOT / "specs" / "latent" / f"{family}_amp.yaml", plugins).spec
    v4 = load_spec(ROOT / "specs" / "latent" / f"{family}_amp_v4.yaml", plugins).spec
    assert Path(v4.imitator.checkpoint).parent.name == "imitator_amp_v4"
    a, b = base.latent.model_dump(), v4.latent.model_dump()
    assert (a["trainer"]["params"]["torch_threads"], b["trainer"]["params"]["torch_threads"]) == (1, 2)
    b["trainer"]["params"]["torch_threads"] = 1
    assert a == b
    a, b = base.imitator.model_dump(), v4.imitator.model_dump()
    a.pop("checkpoint"), b.pop("checkpoint")
    assert a == b


def test_imitator_v5_was_trained_by_the_committed_getup_recipe_from_v4():
    """checkpoints/imitator_amp_v5 embeds the spec that trained it: continue_v4_contacts_getup.yaml, from v4."""
    _, embedded = _checkpoint("imitator_amp_v5")
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v4_contacts_getup.yaml", get_plugins()).spec
    assert embedded["name"] == recipe.name
    params = embedded["imitator"]["params"]
    assert params["getup_starts"] == recipe.imitator.params["getup_starts"]
    assert params["fail_states"]["fall_init_prob"] == recipe.imitator.params["fail_states"]["fall_init_prob"]
    assert embedded["imitator"]["trainer"]["params"]["init_policy"] == "../imitator_amp_v4/policy.pt"


def test_imitator_v6_was_trained_by_the_shoulders_recipe_on_its_humanoid():
    """checkpoints/imitator_amp_v6 embeds continue_v4_shoulders.yaml: the x-z-y humanoid variant, from v4;
    continue_v6.yaml continues it on the same humanoid."""
    _, embedded = _checkpoint("imitator_amp_v6")
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v4_shoulders.yaml", get_plugins()).spec
    assert embedded["name"] == recipe.name
    assert embedded["humanoid"]["params"]["shoulder_order"] == "xzy" == recipe.humanoid.params["shoulder_order"]
    assert embedded["humanoid"]["params"]["shoulder_turns"] == recipe.humanoid.params["shoulder_turns"] == 8.0
    assert embedded["imitator"]["trainer"]["params"]["init_policy"] == "../imitator_amp_v4/policy.pt"
    follow = load_spec(ROOT / "specs" / "imitator" / "continue_v6.yaml", get_plugins()).spec
    assert follow.humanoid == recipe.humanoid
    assert Path(follow.imitator.trainer.params["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v6" / "policy.pt").resolve()


def test_imitator_v7_was_trained_by_continue_v6_with_the_larger_batch():
    """checkpoints/imitator_amp_v7 embeds continue_v6.yaml with 256 envs and minibatches of 8192, from v6 on
    the same humanoid variant; continue_v7.yaml continues it with that recipe and batch."""
    data, embedded = _checkpoint("imitator_amp_v7")
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v6.yaml", get_plugins()).spec
    assert embedded["name"] == recipe.name
    assert embedded["humanoid"]["params"]["shoulder_order"] == "xzy" == recipe.humanoid.params["shoulder_order"]
    trainer = embedded["imitator"]["trainer"]["params"]
    assert trainer["init_policy"] == "../imitator_amp_v6/policy.pt"
    assert (trainer["num_envs"], trainer["minibatch_size"]) == (256, 8192)
    assert data["extra"]["env_steps"] == 14024704
    follow = load_spec(ROOT / "specs" / "imitator" / "continue_v7.yaml", get_plugins()).spec
    assert follow.humanoid == recipe.humanoid
    params = follow.imitator.trainer.params
    assert (params["num_envs"], params["minibatch_size"]) == (256, 8192)
    assert Path(params["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v7" / "policy.pt").resolve()


def test_imitator_v8_was_trained_by_continue_v7_with_gamma_099():
    """checkpoints/imitator_amp_v8 embeds continue_v7.yaml with gamma 0.99, from v7 on the same humanoid
    variant; continue_v8.yaml continues it with that recipe (gamma 0.99, 256 envs)."""
    data, embedded = _checkpoint("imitator_amp_v8")
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v7.yaml", get_plugins()).spec
    assert embedded["name"] == recipe.name
    assert embedded["humanoid"]["params"]["shoulder_order"] == "xzy" == recipe.humanoid.params["shoulder_order"]
    trainer = embedded["imitator"]["trainer"]["params"]
    assert trainer["init_policy"] == "../imitator_amp_v7/policy.pt"
    assert trainer["gamma"] == 0.99 and recipe.imitator.trainer.params["gamma"] == 0.95
    assert data["extra"]["env_steps"] == 5013504
    follow = load_spec(ROOT / "specs" / "imitator" / "continue_v8.yaml", get_plugins()).spec
    assert follow.humanoid == recipe.humanoid
    params = follow.imitator.trainer.params
    assert (params["gamma"], params["num_envs"], params["minibatch_size"]) == (0.99, 256, 8192)
    assert Path(params["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v8" / "policy.pt").resolve()


@pytest.mark.parametrize(("name", "getup"), [("pulse_amp_v7", False), ("pulse_amp_v7_getup", True), ("hybrid_rvq_amp_v7", True)])
def test_the_v7_latent_specs_differ_from_the_v4_ones_by_teacher_humanoid_and_getup_starts(name, getup):
    """specs/latent/<name>.yaml: the v4 recipe with imitator_amp_v7 as the teacher, on its humanoid variant,
    on one torch thread, and (getup) with 10% fallen starts that track a get-up clip; nothing else changed."""
    plugins = get_plugins()
    family = name.split("_amp")[0]
    v4 = load_spec(ROOT / "specs" / "latent" / f"{family}_amp_v4.yaml", plugins).spec
    v7 = load_spec(ROOT / "specs" / "latent" / f"{name}.yaml", plugins).spec
    assert Path(v7.imitator.checkpoint).parent.name == "imitator_amp_v7"
    assert (v7.humanoid.params["shoulder_order"], v7.humanoid.params["shoulder_turns"]) == ("xzy", 8.0)
    a, b = v4.latent.model_dump(), v7.latent.model_dump()
    assert b["trainer"]["params"]["torch_threads"] == 1
    b["trainer"]["params"]["torch_threads"] = a["trainer"]["params"]["torch_threads"]
    fail, starts = b["trainer"]["params"]["fail_states"], b["trainer"]["params"]["getup_starts"]
    assert (fail is not None, starts is not None) == (getup, getup)
    if getup:
        assert (fail["fall_init_prob"], fail["recovery_episode_prob"], starts["clips"]) == (0.1, 0.0, ["getup*"])
    b["trainer"]["params"]["fail_states"], b["trainer"]["params"]["getup_starts"] = None, None
    assert a == b
    a, b = v4.imitator.model_dump(), v7.imitator.model_dump()
    a.pop("checkpoint"), b.pop("checkpoint")
    assert a == b


def test_imitator_v11_ends_with_continue_v8_on_all_clips_after_the_hard_clip_curriculum():
    """checkpoints/imitator_amp_v11 embeds continue_v8.yaml as is (its last phase, on the 15 clips), started from
    the curriculum's policy, committed next to it with its first phase (each names the policy it started
    from); curriculum_hard_v8.yaml differs from continue_v8.yaml only by its clips (and name);
    continue_v11.yaml continues v11 with the last phase's recipe."""
    data, embedded = _checkpoint("imitator_amp_v11")
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v8.yaml", get_plugins()).spec
    assert embedded["name"] == recipe.name and embedded["motions"]["params"].get("clips") is None
    assert embedded["imitator"]["params"]["termination_curriculum"] is None
    assert embedded["imitator"]["trainer"]["params"]["init_policy"] == "curriculum_phase2.pt"
    hard_clips = ["backflip", "dance_a", "dance_b", "spin", "getup_faceup", "getup_facedown"]
    for phase, start in (("curriculum_phase2.pt", "curriculum_phase1.pt"), ("curriculum_phase1.pt", "../imitator_amp_v8/policy.pt")):
        _, doc = _checkpoint("imitator_amp_v11", phase)
        assert doc["motions"]["params"]["clips"] == hard_clips and doc["imitator"]["trainer"]["params"]["init_policy"] == start
    hard = load_spec(ROOT / "specs" / "imitator" / "curriculum_hard_v8.yaml", get_plugins()).spec
    assert hard.motions.params["clips"] == hard_clips
    assert hard.imitator == recipe.imitator and hard.humanoid == recipe.humanoid
    follow = load_spec(ROOT / "specs" / "imitator" / "continue_v11.yaml", get_plugins()).spec
    assert follow.humanoid == recipe.humanoid and follow.imitator.params == recipe.imitator.params
    assert Path(follow.imitator.trainer.params["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v11" / "policy.pt").resolve()


@pytest.mark.parametrize("family", ["pulse", "hybrid_rvq"])
def test_the_v11_latent_specs_differ_from_the_v7_ones_only_by_the_teacher(family):
    """specs/latent/<family>_amp_v11.yaml: the v7 recipe (sizes, schedule, humanoid, fallen starts) with
    imitator_amp_v11 as the teacher; nothing else changed."""
    plugins = get_plugins()
    v7 = load_spec(ROOT / "specs" / "latent" / f"{family}_amp_v7.yaml", plugins).spec
    v11 = load_spec(ROOT / "specs" / "latent" / f"{family}_amp_v11.yaml", plugins).spec
    assert Path(v11.imitator.checkpoint).resolve() == (ROOT / "checkpoints" / "imitator_amp_v11" / "policy.pt").resolve()
    assert v11.latent == v7.latent and v11.humanoid == v7.humanoid and v11.motions == v7.motions
    assert v11.imitator.model_copy(update={"checkpoint": None}) == v7.imitator.model_copy(update={"checkpoint": None})


@pytest.mark.parametrize(("family", "steps"), [("pulse", 10_000_000), ("hybrid_rvq", 8_000_000)])
def test_the_v15_latent_specs_differ_from_the_v7_ones_by_teacher_and_budget(family, steps):
    """specs/latent/<family>_amp_v15.yaml: the v7 recipe with imitator_amp_v15 as the teacher and a longer
    budget (PULSE 10M env steps instead of 6M, the hybrid 8M instead of 4M); nothing else changed."""
    plugins = get_plugins()
    v7 = load_spec(ROOT / "specs" / "latent" / f"{family}_amp_v7.yaml", plugins).spec
    v15 = load_spec(ROOT / "specs" / "latent" / f"{family}_amp_v15.yaml", plugins).spec
    assert Path(v15.imitator.checkpoint).resolve() == (ROOT / "checkpoints" / "imitator_amp_v15" / "policy.pt").resolve()
    assert v15.latent.trainer.params["total_env_steps"] == steps != v7.latent.trainer.params["total_env_steps"]
    a, b = v7.latent.model_dump(), v15.latent.model_dump()
    a["trainer"]["params"].pop("total_env_steps"), b["trainer"]["params"].pop("total_env_steps")
    assert a == b and v15.humanoid == v7.humanoid and v15.motions == v7.motions
    assert v15.imitator.model_copy(update={"checkpoint": None}) == v7.imitator.model_copy(update={"checkpoint": None})


def test_curriculum_hard_v11_is_continue_v11_on_the_hard_clips():
    """The cycles' hard phase: continue_v11.yaml (from v11) on the five hardest clips and the two get-ups."""
    plugins = get_plugins()
    follow = load_spec(ROOT / "specs" / "imitator" / "continue_v11.yaml", plugins).spec
    hard = load_spec(ROOT / "specs" / "imitator" / "curriculum_hard_v11.yaml", plugins).spec
    assert hard.motions.params["clips"] == ["backflip", "dance_a", "dance_b", "spin", "roll", "getup_faceup", "getup_facedown"]
    assert hard.imitator == follow.imitator and hard.humanoid == follow.humanoid


def test_imitator_v12_is_two_curriculum_cycles_from_v11():
    """checkpoints/imitator_amp_v12 embeds continue_v11.yaml's recipe on the 15 clips; the phases before it are
    committed next to it, each naming the policy it started from: curriculum_hard_v11.yaml (from the
    committed v11), continue_v11.yaml's recipe, curriculum_hard_v11.yaml again. continue_v12.yaml continues
    v12 with that recipe."""
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v11.yaml", get_plugins()).spec
    hard = load_spec(ROOT / "specs" / "imitator" / "curriculum_hard_v11.yaml", get_plugins()).spec
    chain = [("policy.pt", recipe, "curriculum_phase3.pt"), ("curriculum_phase3.pt", hard, "curriculum_phase2.pt")]
    chain += [("curriculum_phase2.pt", recipe, "curriculum_phase1.pt"), ("curriculum_phase1.pt", hard, "../imitator_amp_v11/policy.pt")]
    for file, spec, start in chain:
        _, doc = _checkpoint("imitator_amp_v12", file)
        assert doc["name"] == spec.name and doc["motions"]["params"].get("clips") == spec.motions.params.get("clips"), file
        assert doc["imitator"]["trainer"]["params"]["init_policy"] == start, file
    follow = load_spec(ROOT / "specs" / "imitator" / "continue_v12.yaml", get_plugins()).spec
    assert follow.motions == recipe.motions and follow.imitator.params == recipe.imitator.params
    assert Path(follow.imitator.trainer.params["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v12" / "policy.pt").resolve()


@pytest.mark.parametrize(("name", "recipe"), [("v13", "v12"), ("v14", "v13")])
def test_imitator_continued_on_all_clips_embeds_its_recipe(name, recipe):
    """checkpoints/imitator_amp_<name> embeds continue_<recipe>.yaml as is (the 15 clips, seed 0, from the
    committed imitator_amp_<recipe>); continue_<name>.yaml continues it with that recipe."""
    _, embedded = _checkpoint(f"imitator_amp_{name}")
    spec = load_spec(ROOT / "specs" / "imitator" / f"continue_{recipe}.yaml", get_plugins()).spec
    assert embedded["name"] == spec.name and embedded["motions"]["params"].get("clips") is None and embedded["seed"] == 0
    assert embedded["imitator"]["trainer"]["params"]["init_policy"] == f"../imitator_amp_{recipe}/policy.pt"
    nxt = load_spec(ROOT / "specs" / "imitator" / f"continue_{name}.yaml", get_plugins()).spec
    assert nxt.motions == spec.motions and nxt.humanoid == spec.humanoid and nxt.imitator.params == spec.imitator.params
    assert Path(nxt.imitator.trainer.params["init_policy"]).resolve() == (ROOT / "checkpoints" / f"imitator_amp_{name}" / "policy.pt").resolve()


def test_imitator_v15_is_continue_v14_with_phcs_fixed_sigma():
    """checkpoints/imitator_amp_v15 embeds continue_v14.yaml with init_log_std -2.9 and learn_std false (PHC's
    fixed sigma 0.055), from v14, at 10.01M steps; its policy's sigma is that value, and continue_v15.yaml keeps it fixed."""
    data, embedded = _checkpoint("imitator_amp_v15")
    recipe = load_spec(ROOT / "specs" / "imitator" / "continue_v14.yaml", get_plugins()).spec
    assert embedded["name"] == recipe.name and embedded["seed"] == 0 and embedded["motions"]["params"].get("clips") is None
    trainer = embedded["imitator"]["trainer"]["params"]
    assert trainer["init_policy"] == "../imitator_amp_v14/policy.pt"
    assert (trainer["init_log_std"], trainer["learn_std"]) == (-2.9, False) and recipe.imitator.trainer.params["learn_std"] is True
    assert embedded["imitator"]["params"]["start_sampling"] == recipe.imitator.params["start_sampling"]
    assert embedded["imitator"]["params"]["getup_starts"] == recipe.imitator.params["getup_starts"]
    assert data["extra"]["env_steps"] == 10010624
    assert torch.allclose(data["state_dict"]["log_std"], torch.full_like(data["state_dict"]["log_std"], -2.9))
    nxt = load_spec(ROOT / "specs" / "imitator" / "continue_v15.yaml", get_plugins()).spec
    assert nxt.motions == recipe.motions and nxt.humanoid == recipe.humanoid and nxt.imitator.params == recipe.imitator.params
    params = nxt.imitator.trainer.params
    assert params["learn_std"] is False and params["init_log_std"] is None
    assert Path(params["init_policy"]).resolve() == (ROOT / "checkpoints" / "imitator_amp_v15" / "policy.pt").resolve()


#: committed task policies: (checkpoint, spec, env steps it ran, overrides beyond steps and threads)
TASK_POLICIES = [
    ("speed_pulse_v15", "speed_pulse_v15", 15_000_000, {}),
    ("speed_scratch_v15", "speed_scratch_v15", 15_000_000, {}),
    ("reach_scratch_v15", "reach_scratch_v15", 12_000_000, {}),
    ("reach_pulse_far_v15", "reach_pulse_far_v15", 10_000_000, {"far_weight": 0.5, "far_coefficient": 0.05}),
    ("speed_hybrid_rvq_v15", "speed_hybrid_rvq_v15", 8_000_000, {}),
]


@pytest.mark.parametrize("name, spec_name, steps, overrides", TASK_POLICIES)
def test_the_v15_task_policies_were_trained_by_their_specs(name, spec_name, steps, overrides):
    """checkpoints/<task>_<latent>_v15 embed specs/tasks/<spec>.yaml, run with fewer env steps than its
    20M budget, one simulator thread (two runs side by side) and the listed task params; PULSE's
    through the committed pulse_amp_v15."""
    plugins = get_plugins()
    spec = load_spec(ROOT / "specs" / "tasks" / f"{spec_name}.yaml", plugins).spec
    _, embedded = _checkpoint(name, "task_policy.pt")
    params = embedded["task"]["trainer"]["params"]
    assert embedded["task"]["name"] == spec.task.name and params["total_env_steps"] == steps
    expected = dict(spec.task.trainer.params)
    assert expected.pop("total_env_steps") == 20_000_000
    for key, value in expected.items():
        assert params[key] == (list(value) if isinstance(value, tuple) else value), key
    for key, value in overrides.items():
        assert embedded["task"]["params"][key] == value, key
    assert embedded["simulator"]["params"]["threads"] == 1 and embedded["latent"]["name"] == spec.latent.name
    hp = embedded["humanoid"]["params"]
    assert embedded["humanoid"]["name"] == "amp" and hp["shoulder_order"] == "xzy" and hp["shoulder_turns"] == 8.0  # the v15 humanoid
    if spec.latent.name == "pulse":
        assert embedded["latent"]["checkpoint"] == "../pulse_amp_v15/latent.pt"
    if spec.latent.name == "hybrid_rvq":
        assert embedded["latent"]["checkpoint"] == "../hybrid_rvq_amp_v15/latent.pt"


@pytest.mark.parametrize("task", ["speed", "reach", "strike", "point_goal"])
def test_the_v15_task_specs_compare_the_latents_at_equal_ppo_budgets(task):
    """<task>_{scratch,pulse,hybrid_rvq}_v15.yaml share the PPO budget and batch shape (equal steps, PULSE Fig. 4);
    only the action head (fixed sigma for PULSE's residual, a learned one otherwise) and the latent differ."""
    plugins = get_plugins()
    shared = ("num_envs", "horizon", "total_env_steps", "epochs", "minibatch_size", "lr", "gamma", "gae_lambda")
    specs = {
        latent: load_spec(ROOT / "specs" / "tasks" / f"{task}_{latent}_v15.yaml", plugins).spec
        for latent in ("scratch", "pulse", "hybrid_rvq")
        if (ROOT / "specs" / "tasks" / f"{task}_{latent}_v15.yaml").exists()
    }
    assert {"scratch", "pulse"} <= set(specs)
    budgets = {latent: tuple(s.task.trainer.params[k] for k in shared) for latent, s in specs.items()}
    assert len(set(budgets.values())) == 1, budgets
    assert {latent: s.task.name for latent, s in specs.items()} == dict.fromkeys(specs, task)
    hp = {latent: (s.humanoid.name, s.humanoid.params) for latent, s in specs.items()}
    assert len({(n, tuple(sorted(p.items()))) for n, p in hp.values()}) == 1, hp


def test_a_users_export_into_checkpoints_is_no_committed_checkpoint(tmp_path):
    """Issue 63, newcomer 7: the README's ``mocap export runs/pulse-amp-v20 checkpoints/my_pulse``
    writes an untracked folder; the committed-checkpoint tests count only what git tracks."""
    import subprocess

    for name in ("imitator", "my_pulse"):
        (tmp_path / "checkpoints" / name).mkdir(parents=True)
        (tmp_path / "checkpoints" / name / "policy.pt").write_bytes(b"x")
    git = ["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "checkpoints/imitator"], check=True)
    subprocess.run([*git, "commit", "-qm", "one checkpoint"], check=True)
    assert committed_files("checkpoints", "*/*.pt", root=tmp_path) == [tmp_path / "checkpoints" / "imitator" / "policy.pt"]
    assert {p.parent.name for p in committed_files("checkpoints", "*/*.pt")} >= {"imitator", "pulse"}  # this repository's


def test_the_reproduce_spec_says_exactly_what_it_retrains():
    """Issue 63, newcomer 9: bundled.yaml and the README said "every committed checkpoint"; it
    retrains four first-generation models, none of the canonical ones or any task policy."""
    import re

    text = SPEC.read_text()
    description = load_cells(SPEC, get_plugins())[0][1].spec.description or ""
    for name in ("imitator_amp", "pulse_amp", "hybrid_rvq_amp", "vmp_amp_v2"):
        assert re.search(rf"\b{name}\b", description) and (ROOT / "checkpoints" / name).is_dir(), name
    assert "not the canonical checkpoints or any task policy" in description
    assert "does NOT retrain the canonical checkpoints" in text
    for path in (SPEC, ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))):
        flat = " ".join(path.read_text().split())
        assert not re.search(r"every committed checkpoint (retrained )?from nothing|retrains? every committed", flat), path
