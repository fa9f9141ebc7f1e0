"""Spec validation, extends, --set overrides, and the never-a-traceback property."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from toy_plugins import TOY_SPEC, toy

from mocap.plugins import load_plugins
from mocap.spec import SpecError, apply_overrides, deep_merge, load_spec, load_spec_text, parse_override

PSET = load_plugins([("toy", toy)], entry_points=False)


def issues(text: str, overrides=None) -> list[str]:
    with pytest.raises(SpecError) as exc:
        load_spec_text(text, PSET, source="s.yaml", overrides=overrides)
    return [i.format("s.yaml") for i in exc.value.issues]


def test_valid_spec_fills_component_defaults():
    resolved = load_spec_text(TOY_SPEC, PSET)
    assert resolved.spec.imitator.params == {"hidden": 16, "optim": {"lr": 0.01, "schedule": "constant"}, "files": []}
    assert resolved.spec.latent.params == {"hidden": 8, "optim": {"lr": 0.001, "schedule": "constant"}, "files": []}
    assert resolved.params["imitator"].optim.lr == 0.01
    assert resolved.params["latent.trainer"].iterations == 2
    # the resolved YAML validates again to the same spec
    again = load_spec_text(resolved.to_yaml(), PSET)
    assert again.spec == resolved.spec


def test_misspelt_component_lists_registered_names():
    (msg,) = issues(TOY_SPEC.replace("name: toy_latent", "name: toy_latnet"))
    assert "latent.name" in msg and "'toy_latnet'" in msg and "toy_latent, toy_latent_b" in msg


def test_wrong_type_of_nested_param_names_the_path_and_value():
    (msg,) = issues(TOY_SPEC.replace("lr: 0.01", "lr: fast"))
    assert "imitator.params.optim.lr" in msg and "'fast'" in msg


def test_unknown_fields_are_rejected_everywhere():
    msgs = issues(TOY_SPEC + "colour: blue\n")
    assert any("colour" in m and "unknown field" in m for m in msgs)
    msgs = issues(TOY_SPEC.replace("hidden: 16", "hidden: 16, hiden: 3"))
    assert any("imitator.params.hiden" in m for m in msgs)


def test_yaml_syntax_error_has_line_and_column():
    (msg,) = issues("spec_version: 1\nname: x\nlatent: {name: a\n  params: : :\n")
    assert msg.startswith("s.yaml:") and "YAML syntax error" in msg
    line = int(msg.split(":")[1])
    assert 3 <= line <= 5


def test_spec_version_is_required_and_checked():
    assert any("spec_version" in m for m in issues("name: x\n"))
    assert any("spec_version" in m and "must be one of" in m for m in issues("spec_version: 7\nname: x\n"))


def test_set_overrides_are_typed_by_the_schema():
    resolved = load_spec_text(TOY_SPEC, PSET, overrides=["imitator.params.hidden=32", "seed=7", "name=123"])
    assert resolved.spec.imitator.params["hidden"] == 32 and resolved.spec.seed == 7 and resolved.spec.name == "123"
    (msg,) = issues(TOY_SPEC, overrides=["imitator.params.hidden=many"])
    assert "imitator.params.hidden" in msg and "'many'" in msg


def test_set_parses_lists_and_null_and_indexes_lists():
    doc = {"a": {"b": [1, 2, 3]}, "c": 1}
    out = apply_overrides(doc, ["a.b.1=9", "c=null", "d.e=[1, 2]"])
    assert out == {"a": {"b": [1, "9", 3]}, "c": None, "d": {"e": [1, 2]}}
    assert doc["c"] == 1  # input untouched
    with pytest.raises(SpecError):
        apply_overrides(doc, ["a.b.7=1"])
    with pytest.raises(SpecError):
        parse_override("novalue")


def test_extends_merges_and_replaces_renamed_components(tmp_path: Path):
    (tmp_path / "base.yaml").write_text(TOY_SPEC)
    (tmp_path / "child.yaml").write_text("extends: base.yaml\nname: child\nimitator: {params: {hidden: 64}}\nlatent: {name: toy_latent_b}\n")
    resolved = load_spec(tmp_path / "child.yaml", PSET)
    spec = resolved.spec
    assert spec.name == "child"
    assert spec.imitator.params["hidden"] == 64 and spec.imitator.params["optim"]["lr"] == 0.01  # merged
    assert spec.latent.name == "toy_latent_b" and spec.latent.trainer is None  # replaced whole
    assert spec.simulator.params["hidden"] == 4  # inherited


def test_a_renamed_component_under_extends_explains_the_missing_trainer(tmp_path: Path):
    """Renaming a stage's component in a child spec drops the parent's whole section; the error on
    the half-written trainer says so (it used to be a bare "Field required")."""
    (tmp_path / "base.yaml").write_text(TOY_SPEC)
    (tmp_path / "child.yaml").write_text("extends: base.yaml\nlatent: {name: toy_latent_b, trainer: {params: {iterations: 5}}}\n")
    with pytest.raises(SpecError) as info:
        load_spec(tmp_path / "child.yaml", PSET)
    msg = str(info.value)
    assert "latent.trainer.name" in msg
    assert "latent was renamed from 'toy_latent' to 'toy_latent_b'" in msg and "write the section in full" in msg
    (tmp_path / "ok.yaml").write_text("extends: base.yaml\nlatent: {params: {}, trainer: {params: {iterations: 5}}}\n")
    load_spec(tmp_path / "ok.yaml", PSET)  # no rename: the trainer merges as before


def test_an_extends_name_too_long_for_the_os_is_a_spec_error(tmp_path: Path):
    """Found by the 10,000-case fuzz run: `extends: <300 characters>` raised ENAMETOOLONG."""
    (tmp_path / "child.yaml").write_text("extends: " + "x" * 300 + "\n" + TOY_SPEC)
    with pytest.raises(SpecError, match="cannot look up this spec file"):
        load_spec(tmp_path / "child.yaml", PSET)


def test_extends_cycle_and_missing_base(tmp_path: Path):
    (tmp_path / "a.yaml").write_text("extends: b.yaml\n")
    (tmp_path / "b.yaml").write_text("extends: a.yaml\n")
    with pytest.raises(SpecError, match="circular extends"):
        load_spec(tmp_path / "a.yaml", PSET)
    (tmp_path / "c.yaml").write_text("extends: nowhere.yaml\n")
    with pytest.raises(SpecError, match="no such spec file"):
        load_spec(tmp_path / "c.yaml", PSET)


def test_checkpoint_paths_are_relative_to_the_spec_file(tmp_path: Path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "s.yaml").write_text(TOY_SPEC.replace("  trainer: {name: count, params: {iterations: 2}}", "  checkpoint: ckpt/latent.pt"))
    spec = load_spec(tmp_path / "sub" / "s.yaml", PSET).spec
    assert spec.latent.checkpoint == (tmp_path / "sub" / "ckpt" / "latent.pt").resolve()


def test_relative_paths_in_params_resolve_against_the_spec_file(tmp_path: Path, monkeypatch):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "s.yaml").write_text(TOY_SPEC.replace("hidden: 16,", "hidden: 16, files: [data/a.npz, /abs/b.npz],"))
    monkeypatch.chdir(tmp_path)
    resolved = load_spec("sub/s.yaml", PSET)
    assert resolved.params["imitator"].files == [(tmp_path / "sub" / "data" / "a.npz").resolve(), Path("/abs/b.npz")]
    assert resolved.spec.imitator.params["files"][0] == str((tmp_path / "sub" / "data" / "a.npz").resolve())


def test_deep_merge_properties():
    assert deep_merge({"a": {"b": 1, "c": 2}}, {"a": {"c": 3}}) == {"a": {"b": 1, "c": 3}}
    assert deep_merge({"a": [1, 2]}, {"a": [3]}) == {"a": [3]}
    assert deep_merge({"c": {"name": "x", "params": {"p": 1}}}, {"c": {"name": "y"}}) == {"c": {"name": "y"}}
    assert deep_merge({"name": "x", "seed": 1}, {"name": "y"}) == {"name": "y", "seed": 1}  # the root merges


yaml_scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(allow_nan=True), st.text(max_size=8))
yaml_values = st.recursive(
    yaml_scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=3),
        st.dictionaries(st.sampled_from(["name", "params", "trainer", "hidden", "lr", "x", "optim", "checkpoint"]), children, max_size=3),
    ),
    max_leaves=8,
)
field_names = st.sampled_from(
    ["spec_version", "name", "seed", "device", "humanoid", "motions", "simulator", "imitator", "latent", "task", "eval", "extends", "bogus"]
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(field_names, yaml_values, max_size=6), st.booleans())
def test_random_documents_give_a_spec_or_a_clean_error(doc, start_from_valid):
    if start_from_valid:
        base = yaml.safe_load(TOY_SPEC)
        doc = deep_merge(base, doc)
    text = yaml.safe_dump(doc)
    try:
        load_spec_text(text, PSET)
    except SpecError as exc:
        assert exc.issues and all(isinstance(i.message, str) and i.message for i in exc.issues)
        exc.format()


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=60))
def test_random_text_gives_a_spec_or_a_clean_error(text):
    try:
        load_spec_text(text, PSET)
    except SpecError as exc:
        assert exc.issues


@settings(max_examples=100, deadline=None)
@given(
    st.sampled_from(
        ["imitator.params.hidden", "imitator.params.optim.lr", "seed", "latent.name", "simulator.params", "name", "x.y", "imitator.trainer.params.iterations"]
    ),
    st.one_of(st.text(max_size=6), st.integers().map(str), st.floats().map(str), st.just("[1, 2]"), st.just("null"), st.just("{a: 1}")),
)
def test_random_overrides_give_a_spec_or_a_clean_error(key, value):
    try:
        load_spec_text(TOY_SPEC, PSET, overrides=[f"{key}={value}"])
    except SpecError as exc:
        assert exc.issues
