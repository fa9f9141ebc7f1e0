"""Plugin loading (pluggy + the ``mocap`` entry-point group) and the component registry.

Built-in plugins (the humanoids, the motion sources, the MuJoCo simulator, ...) are published by
this distribution under the same entry-point group a third-party package uses, and are loaded by
the same code. Environment variables:

* ``MOCAP_LOAD_PLUGINS``: comma-separated allow-list of entry-point names; only those load
  (an empty value loads none).
* ``MOCAP_DISABLE_PLUGINS``: comma-separated block-list of entry-point names.

A plugin that raises on import, fails ``check_pending()`` (a misspelt hook) or raises inside a
registration hook is reported by name in one line (:attr:`PluginSet.failures`) and the others keep
working. Two plugins registering the same name for the same role is an error that names both
(:class:`DuplicateRegistration`), raised when that role's registry is used.

A factory may be registered as :func:`lazy` ``("package.module:name")``: its module (and whatever it
imports, torch included) is imported only when a component is built, so that listing, validating
and documenting components (``mocap --help``, ``mocap validate``, ``mocap switches``) stay fast.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import os
import threading
from dataclasses import dataclass, field
from importlib import metadata
from types import ModuleType
from typing import Any, Callable, Iterable, Mapping

import pluggy
from pydantic import BaseModel

from mocap import hooks
from mocap.hooks import ENTRY_POINT_GROUP, REGISTRATION_HOOKS
from mocap.metric_display import MetricInfo

KINDS: tuple[str, ...] = tuple(REGISTRATION_HOOKS.values())


class PluginError(Exception):
    """A problem with plugins that a user must fix (duplicate names, unknown components)."""


class DuplicateRegistration(PluginError):
    pass


class UnknownComponent(PluginError):
    def __init__(self, kind: str, name: str, choices: Iterable[str]):
        self.kind, self.name, self.choices = kind, name, sorted(choices)
        listed = ", ".join(self.choices) or "(none registered)"
        super().__init__(f"unknown {kind} {name!r}; registered {kind}s: {listed}")


def install_hint(kind: str, name: str, provenance: Any) -> str:
    """``"; it was made with package 'mocap-foo' 1.2 (plugin 'foo'): install it"`` when a checkpoint's
    recorded ``provenance`` (:meth:`PluginSet.provenance`) knows who registered ``kind`` ``name``, else ""."""
    entry = provenance.get(f"{kind}:{name}") if isinstance(provenance, dict) else None
    if not isinstance(entry, dict):
        return ""
    package, version, plugin = (str(entry.get(k) or "") for k in ("package", "version", "plugin"))
    if not package or package.startswith("<local:"):
        return f"; the file was made with plugin {plugin!r} (not an installed package): load that plugin" if plugin else ""
    return f"; the file was made with {kind} {name!r} from package {package!r} {version}: install it (pip install {package})"


class LazyFactory:
    """A factory named ``"package.module:attr"`` (``attr`` may be dotted), imported on first use.

    Calling it imports the module and calls the target; :meth:`resolve` returns the target itself
    (a function or a class). ``inspect.signature`` sees the target's signature.
    """

    __slots__ = ("target", "_resolved")

    def __init__(self, target: str) -> None:
        module, sep, attr = target.partition(":")
        if not (sep and module and attr):
            raise ValueError(f"lazy factory {target!r}: expected 'package.module:attribute'")
        self.target = target
        self._resolved: Callable[..., Any] | None = None

    def resolve(self) -> Callable[..., Any]:
        """The target (imported now, the first time)."""
        if self._resolved is None:
            module, _, attr = self.target.partition(":")
            obj: Any = importlib.import_module(module)
            for part in attr.split("."):
                obj = getattr(obj, part)
            if not callable(obj):
                raise TypeError(f"lazy factory {self.target!r} is not callable")
            self._resolved = obj
        return self._resolved

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.resolve()(*args, **kwargs)

    @property
    def __signature__(self) -> inspect.Signature:
        return inspect.signature(self.resolve())

    def __repr__(self) -> str:
        return f"lazy({self.target!r})"


def lazy(target: str) -> LazyFactory:
    """A factory for ``register``: ``lazy("mocap.rl.ppo:PPOTrainer")`` imports ``mocap.rl.ppo`` only when
    the component is built (a plugin module that registers lazily imports nothing heavy)."""
    return LazyFactory(target)


@dataclass(frozen=True)
class Component:
    """One registered component: ``factory`` builds it from a validated ``params`` instance."""

    kind: str
    name: str
    factory: Callable[..., Any]
    params: type[BaseModel] | None
    plugin: str
    description: str = ""
    #: display name and unit of each metric this component reports (:mod:`mocap.metric_display`)
    metrics: Mapping[str, MetricInfo] = field(default_factory=dict)

    def validate_params(self, raw: dict[str, Any] | None) -> BaseModel | None:
        """Validate a spec's ``params`` mapping with this component's model (pydantic errors propagate)."""
        if self.params is None:
            if raw:
                raise ValueError(f"{self.kind} {self.name!r} takes no params")
            return None
        return self.params.model_validate(raw or {})

    def resolved_factory(self) -> Callable[..., Any]:
        """The factory itself: a :func:`lazy` one imported (for inspecting its signature)."""
        return self.factory.resolve() if isinstance(self.factory, LazyFactory) else self.factory

    def code_modules(self) -> tuple[str, ...]:
        """The modules holding this component's code, without importing them: its factory's (a
        :func:`lazy` factory's target module) (:meth:`PluginSet.code_of` adds the registering plugin's)."""
        if isinstance(self.factory, LazyFactory):
            return (self.factory.target.partition(":")[0],)
        module = inspect.getmodule(self.factory)
        return (module.__name__,) if module is not None else ()

    def build(self, params: BaseModel | dict[str, Any] | None = None, **kwargs: Any) -> Any:
        if not isinstance(params, BaseModel) and self.params is not None:
            params = self.params.model_validate(params or {})
        return self.factory(params, **kwargs) if self.params is not None else self.factory(**kwargs)


@dataclass(frozen=True)
class PluginInfo:
    name: str
    package: str
    version: str
    hooks: tuple[str, ...]
    module: str
    #: the module the plugin object is defined in (its code's package enters the stage keys)
    code_module: str = ""


@dataclass(frozen=True)
class PluginFailure:
    name: str
    package: str
    error: str

    def line(self) -> str:
        return f"plugin {self.name!r} ({self.package}) failed to load: {self.error}"


@dataclass
class PluginSet:
    """Loaded plugins, their registered components, and what failed."""

    manager: pluggy.PluginManager
    plugins: list[PluginInfo] = field(default_factory=list)
    failures: list[PluginFailure] = field(default_factory=list)
    components: dict[str, dict[str, Component]] = field(default_factory=lambda: {k: {} for k in KINDS})
    duplicates: dict[tuple[str, str], list[str]] = field(default_factory=dict)

    # -- lookup -------------------------------------------------------------------------------
    def names(self, kind: str) -> list[str]:
        return sorted(self.components[kind])

    def get(self, kind: str, name: str) -> Component:
        self.check_duplicates(kind, name)
        try:
            return self.components[kind][name]
        except KeyError:
            raise UnknownComponent(kind, name, self.components[kind]) from None

    def check_duplicates(self, kind: str | None = None, name: str | None = None) -> None:
        for (k, n), owners in self.duplicates.items():
            if (kind is None or k == kind) and (name is None or n == name):
                raise DuplicateRegistration(
                    f"{k} {n!r} is registered by more than one plugin: {' and '.join(repr(o) for o in owners)}; "
                    f"uninstall one or block it with MOCAP_DISABLE_PLUGINS={owners[-1]}"
                )

    def provenance(self) -> dict[str, dict[str, str]]:
        """``{"<kind>:<name>": {"plugin", "package", "version", "code"}}`` of every registered component:
        what a checkpoint records, so that a reader without the plugin learns which package to install
        and ``mocap eval`` can tell whether other code made it (``code``: :meth:`code_of`)."""
        out: dict[str, dict[str, str]] = {}
        for kind, comps in self.components.items():
            for name, comp in comps.items():
                code = self._code(comp)
                out[f"{kind}:{name}"] = {"plugin": comp.plugin, "package": code["package"], "version": code["version"], "code": code["code"]}
        return out

    def code_of(self, kind: str, name: str) -> dict[str, str]:
        """The code fingerprint of a registered component: ``{"package", "version", "code"}``, where
        ``code`` is a short sha256 over the source files of every top-level package holding its
        code (the registering plugin's and its factory's; :func:`mocap.fingerprint.package_digest`).
        Editing any file of those packages, or installing another version, changes it."""
        return self._code(self.get(kind, name))

    def _code(self, comp: Component) -> dict[str, str]:
        from mocap.fingerprint import package_digest

        owner = next((p for p in self.plugins if p.name == comp.plugin), None)
        modules = [*comp.code_modules(), owner.code_module if owner is not None else ""]
        tops = sorted({m.split(".", 1)[0] for m in modules if m})
        h = hashlib.sha256("".join(f"{top}={package_digest(top)}\n" for top in tops).encode())
        return {
            "package": owner.package if owner else "",
            "version": owner.version if owner else "",
            "code": h.hexdigest()[:16],
            "modules": ",".join(tops),
        }

    def commands(self, app: Any) -> None:
        """Let every plugin add its CLI commands (failures are recorded, not raised)."""
        for impl in self.manager.hook.register_commands.get_hookimpls():
            try:
                impl.function(app=app)
            except Exception as exc:  # noqa: BLE001 - a broken plugin must not break the CLI
                self.failures.append(PluginFailure(impl.plugin_name, _package_of(self, impl.plugin_name), _one_line(exc)))


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _package_of(pset: PluginSet, plugin_name: str) -> str:
    for info in pset.plugins:
        if info.name == plugin_name:
            return info.package
    return "?"


def _env_list(var: str) -> set[str] | None:
    value = os.environ.get(var)
    if value is None:
        return None
    return {part.strip() for part in value.split(",") if part.strip()}


def new_manager() -> pluggy.PluginManager:
    pm = pluggy.PluginManager(hooks.PROJECT)
    pm.add_hookspecs(hooks)
    return pm


def load_plugins(
    extra: Iterable[tuple[str, ModuleType | object]] = (),
    *,
    entry_points: bool = True,
) -> PluginSet:
    """Load entry-point plugins (honouring the allow/block lists) plus ``extra`` (name, plugin) pairs.

    ``extra`` is how tests and plugin authors register throw-away plugins through the same path.
    """
    pm = new_manager()
    pset = PluginSet(manager=pm)
    allow = _env_list("MOCAP_LOAD_PLUGINS")
    block = _env_list("MOCAP_DISABLE_PLUGINS") or set()
    candidates: list[tuple[str, str, str, Callable[[], object]]] = []
    if entry_points:
        seen: set[str] = set()
        for ep in sorted(metadata.entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
            if ep.name in seen:  # the same distribution visible twice on sys.path
                continue
            seen.add(ep.name)
            dist = getattr(ep, "dist", None)
            package = dist.metadata["Name"] if dist is not None else "?"
            version = dist.version if dist is not None else "?"
            candidates.append((ep.name, package, version, ep.load))
    extra = list(extra)
    local_names = {name for name, _ in extra}
    candidates = [c for c in candidates if c[0] not in local_names]  # a local plugin replaces an installed one
    for name, obj in extra:
        module = getattr(obj, "__name__", type(obj).__name__)

        def local_loader(obj: object = obj) -> object:
            return obj

        candidates.append((name, f"<local:{module}>", "-", local_loader))

    for name, package, version, loader in candidates:
        if allow is not None and name not in allow:
            continue
        if name in block:
            continue
        registered = False
        try:
            plugin = loader()
            pm.register(plugin, name=name)
            registered = True
            pm.check_pending()
        except Exception as exc:  # noqa: BLE001 - isolate every plugin
            if registered:
                pm.unregister(name=name)
            pset.failures.append(PluginFailure(name, package, _one_line(exc)))
            continue
        hook_names = tuple(sorted(impl.name for impl in _impls_of(pm, plugin)))
        module = getattr(plugin, "__name__", type(plugin).__name__)
        home = inspect.getmodule(plugin)
        pset.plugins.append(PluginInfo(name, package, version, hook_names, module, home.__name__ if home is not None else ""))

    _collect(pset)
    return pset


def _impls_of(pm: pluggy.PluginManager, plugin: object) -> list[Any]:
    impls = []
    for caller in pm.get_hookcallers(plugin) or []:
        for impl in caller.get_hookimpls():
            if impl.plugin is plugin:
                impls.append(caller)
    return impls


def _collect(pset: PluginSet) -> None:
    """Call every registration hook of every plugin, one plugin at a time, recording owners."""
    failed: set[str] = set()
    for hook_name, kind in REGISTRATION_HOOKS.items():
        caller = getattr(pset.manager.hook, hook_name)
        for impl in caller.get_hookimpls():  # registration order
            if impl.plugin_name in failed:
                continue
            registered: list[Component] = []

            def register(
                name: str,
                factory: Callable[..., Any],
                params: type[BaseModel] | None = None,
                description: str = "",
                *,
                metrics: Mapping[str, Any] | None = None,
                _kind: str = kind,
                _plugin: str = impl.plugin_name,
                _out: list[Component] = registered,
            ) -> None:
                if not isinstance(name, str) or not name:
                    raise ValueError(f"{_kind} name must be a non-empty string, got {name!r}")
                if params is not None and not (isinstance(params, type) and issubclass(params, BaseModel)):
                    raise TypeError(f"params of {_kind} {name!r} must be a pydantic model class")
                if metrics is not None and not isinstance(metrics, Mapping):
                    raise TypeError(f"metrics of {_kind} {name!r} must map metric names to MetricInfo(display, unit)")
                infos = {str(k): MetricInfo.coerce(v, str(k)) for k, v in (metrics or {}).items()}
                _out.append(Component(_kind, name, factory, params, _plugin, description, infos))

            try:
                impl.function(register=register)
            except Exception as exc:  # noqa: BLE001
                failed.add(impl.plugin_name)
                pset.failures.append(PluginFailure(impl.plugin_name, _package_of(pset, impl.plugin_name), f"in {hook_name}: {_one_line(exc)}"))
                continue
            for comp in registered:
                existing = pset.components[kind].get(comp.name)
                if existing is not None and existing.plugin != comp.plugin:
                    owners = pset.duplicates.setdefault((kind, comp.name), [existing.plugin])
                    owners.append(comp.plugin)
                    continue
                pset.components[kind][comp.name] = comp
    # A plugin that failed part-way keeps nothing: remove what it registered in earlier hooks.
    for kind in KINDS:
        for name in [n for n, c in pset.components[kind].items() if c.plugin in failed]:
            del pset.components[kind][name]


_default: PluginSet | None = None
_lock = threading.Lock()


def get_plugins(reload: bool = False) -> PluginSet:
    """The process-wide plugin set (entry points loaded once)."""
    global _default
    with _lock:
        if _default is None or reload:
            _default = load_plugins()
        return _default


def set_plugins(pset: PluginSet | None) -> None:
    """Replace the process-wide plugin set (tests and the plugin-author test helper use this)."""
    global _default
    with _lock:
        _default = pset
