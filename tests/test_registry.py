"""Plugin loading and the registry: throw-away, broken and duplicate plugins; allow/block lists."""

from __future__ import annotations

import types

import pytest
from toy_plugins import ToyComponent, ToyModelParams, toy

from mocap.hooks import hookimpl
from mocap.plugins import DuplicateRegistration, UnknownComponent, load_plugins


def _module(name: str, **hooks) -> types.ModuleType:
    mod = types.ModuleType(name)
    for hook_name, fn in hooks.items():
        setattr(mod, hook_name, hookimpl(fn))
    return mod


def test_throwaway_plugin_registers_components():
    pset = load_plugins([("toy", toy)], entry_points=False)
    assert pset.failures == []
    assert pset.names("latent") == ["toy_latent", "toy_latent_b"]
    comp = pset.get("imitator", "toy_imitator")
    assert comp.plugin == "toy" and comp.params is ToyModelParams
    built = comp.build({"hidden": 3})
    assert isinstance(built, ToyComponent) and built.params.hidden == 3
    info = {p.name: p for p in pset.plugins}["toy"]
    assert "register_trainers" in info.hooks and info.package.startswith("<local:")


def test_unknown_component_lists_registered_names():
    pset = load_plugins([("toy", toy)], entry_points=False)
    with pytest.raises(UnknownComponent) as exc:
        pset.get("latent", "toy_latnet")
    assert "toy_latent, toy_latent_b" in str(exc.value)


def test_plugin_raising_on_import_is_reported_and_others_work():
    def boom():
        raise ImportError("missing dependency 'frobnicate'")

    class BrokenLoader:  # simulate an entry point whose load() raises: use a hook that raises instead
        pass

    broken = _module("broken_plugin", register_tasks=lambda register: boom())
    pset = load_plugins([("broken", broken), ("toy", toy)], entry_points=False)
    assert [f.name for f in pset.failures] == ["broken"]
    assert "frobnicate" in pset.failures[0].line() and "broken" in pset.failures[0].line()
    assert "toy_latent" in pset.names("latent")


def test_broken_plugin_keeps_nothing_it_registered():
    def ok(register):
        register("half_task", ToyComponent)

    def bad(register):
        raise RuntimeError("bad metric")

    mod = _module("half", register_tasks=ok, register_metrics=bad)
    pset = load_plugins([("half", mod)], entry_points=False)
    assert "half_task" not in pset.names("task")
    assert pset.failures and "bad metric" in pset.failures[0].error


def test_misspelt_hook_is_caught_by_check_pending():
    mod = _module("typo", register_latnet_spaces=lambda register: None)
    pset = load_plugins([("typo", mod), ("toy", toy)], entry_points=False)
    assert [f.name for f in pset.failures] == ["typo"]
    assert "register_latnet_spaces" in pset.failures[0].error
    assert pset.names("trainer") == ["count"]


def test_duplicate_name_is_an_error_naming_both_plugins():
    mod = _module("other", register_latent_spaces=lambda register: register("toy_latent", ToyComponent))
    pset = load_plugins([("toy", toy), ("other", mod)], entry_points=False)
    with pytest.raises(DuplicateRegistration) as exc:
        pset.get("latent", "toy_latent")
    assert "'toy'" in str(exc.value) and "'other'" in str(exc.value)
    # other names stay usable
    assert pset.get("latent", "toy_latent_b").plugin == "toy"


def test_registration_with_bad_params_type_fails_cleanly():
    mod = _module("badparams", register_tasks=lambda register: register("t", ToyComponent, params=dict))
    pset = load_plugins([("badparams", mod)], entry_points=False)
    assert pset.failures and "pydantic" in pset.failures[0].error


def test_allow_and_block_lists(monkeypatch):
    monkeypatch.setenv("MOCAP_DISABLE_PLUGINS", "toy")
    assert "toy" not in {p.name for p in load_plugins([("toy", toy)], entry_points=False).plugins}
    monkeypatch.delenv("MOCAP_DISABLE_PLUGINS")
    monkeypatch.setenv("MOCAP_LOAD_PLUGINS", "toy")
    pset = load_plugins([("toy", toy)], entry_points=True)
    assert [p.name for p in pset.plugins] == ["toy"]
    monkeypatch.setenv("MOCAP_LOAD_PLUGINS", "")
    assert load_plugins([("toy", toy)]).plugins == []


def test_builtin_plugins_load_through_entry_points():
    pset = load_plugins()
    names = {p.name: p for p in pset.plugins}
    assert pset.failures == [], [f.line() for f in pset.failures]
    for name in ("humanoids", "motion", "sim_mujoco"):
        assert names[name].package == "mocap"
        assert names[name].hooks, f"built-in plugin {name} implements no hook"


def test_entry_point_that_fails_to_import_is_reported_in_one_line(monkeypatch):
    from importlib import metadata

    import mocap.plugins as plugins_module

    real = metadata.entry_points

    def fake(group=None, **kw):
        eps = list(real(group=group, **kw)) if group else []
        bad = metadata.EntryPoint(name="broken_dist", value="mocap_no_such_module_xyz", group="mocap")
        return [*eps, bad]

    monkeypatch.setattr(plugins_module.metadata, "entry_points", fake)
    pset = load_plugins()
    (failure,) = [f for f in pset.failures if f.name == "broken_dist"]
    line = failure.line()
    assert "\n" not in line and "broken_dist" in line and "mocap_no_such_module_xyz" in line
    assert "amp" in pset.names("humanoid")  # the others keep working


def test_components_declare_how_their_metrics_are_shown():
    """``register(..., metrics=...)`` is how a plugin's metric gets a display name and unit in
    reports; a malformed declaration fails the plugin in one line, and undeclared keys show as keys."""
    from mocap.metric_display import MetricInfo, declared_metrics, metric_label

    def tasks(register):
        register("jumpy", ToyComponent, metrics={"jump_height": MetricInfo("jump height", "m"), "hops": ("hops", "")})

    pset = load_plugins([("jumpy", _module("jumpy", register_tasks=tasks))], entry_points=False)
    assert pset.failures == []
    declared = declared_metrics(pset)
    assert declared["jump_height"] == MetricInfo("jump height", "m") and declared["hops"] == MetricInfo("hops")
    assert metric_label("task/episode/jump_height", declared) == "jump height (m)"
    assert metric_label("eval/hops", declared) == "hops"
    assert metric_label("eval/undeclared_thing", declared) == "eval/undeclared_thing"
    bad = _module("badmetrics", register_tasks=lambda register: register("t", ToyComponent, metrics={"x": 3}))
    failed = load_plugins([("badmetrics", bad)], entry_points=False)
    assert failed.failures and "metric 'x'" in failed.failures[0].error
    builtin = declared_metrics(load_plugins())
    assert builtin["mpjpe_g"] == MetricInfo("MPJPE-g", "mm") and builtin["speed_error"] == MetricInfo("speed error", "m/s")
