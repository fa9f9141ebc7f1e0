"""Declarative run specs: pydantic models, YAML loading with ``extends:``, ``--set`` overrides.

A spec names a registered component for each role and that component's ``params``::

    spec_version: 1
    name: walk-imitation
    humanoid: {name: amp}
    motions: {name: deepmimic, params: {clips: [walk]}}
    simulator: {name: mujoco, params: {num_envs: 64}}
    imitator:
      name: phc
      params: {...}                 # validated by the phc plugin's own pydantic model
      trainer: {name: ppo, params: {...}}
    eval: {trainer: {name: imitation_eval}}

Validation is two-phase: the structure below (``extra="forbid"`` everywhere), then each
component's ``params`` with the model its plugin registered. Every problem becomes a
:class:`SpecError` naming the file, the field path, the bad value and the allowed choices.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from mocap import safe_yaml
from mocap.bounds import ThreadCount
from mocap.plugins import PluginError, PluginSet, UnknownComponent, install_hint

SPEC_VERSION = 1


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ComponentRef(_Strict):
    """A registered component by ``name`` with its ``params`` (validated by the component's model)."""

    name: str = Field(description="registered name of the component")
    params: dict[str, Any] = Field(default_factory=dict, description="the component's parameters")


class StageSpec(ComponentRef):
    """A pipeline stage: the component it produces, the trainer that trains it, or a checkpoint."""

    trainer: ComponentRef | None = Field(default=None, description="trainer that produces this stage's artifact")
    checkpoint: Path | None = Field(default=None, description="use this existing checkpoint instead of training (relative to the spec file)")


class EvalSpec(_Strict):
    """The evaluation stage: an evaluating trainer and the metrics it reports."""

    trainer: ComponentRef = Field(description="the trainer that runs the evaluation")
    metrics: list[ComponentRef] = Field(default_factory=list, description="registered metrics to compute")


class Spec(_Strict):
    """A complete run: the components for each role and the stages to run."""

    spec_version: Literal[1] = Field(description="spec format version (this build reads version 1)")
    name: str = Field(
        description="run name, used as the run directory's name (runs/<name>): letters, digits, '.', '_' and '-', "
        "starting with a letter or digit, at most 100 characters",
        pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$",
    )
    description: str = ""
    seed: int = Field(default=0, ge=0, le=2**63 - 1, description="global seed; each stage derives its own from it")
    device: Literal["auto", "cpu", "cuda"] = Field(default="auto", description="torch device for networks")
    torch_threads: ThreadCount | None = Field(default=None, description="torch intra-op threads (None: leave the cores to the simulator threads)")
    humanoid: ComponentRef = Field(default_factory=lambda: ComponentRef(name="amp"))
    motions: ComponentRef = Field(default_factory=lambda: ComponentRef(name="deepmimic"))
    simulator: ComponentRef = Field(default_factory=lambda: ComponentRef(name="mujoco"))
    imitator: StageSpec | None = None
    latent: StageSpec | None = None
    task: StageSpec | None = None
    eval: EvalSpec | None = None


#: role field -> registry kind of its component
ROLE_KINDS: dict[str, str] = {
    "humanoid": "humanoid",
    "motions": "motion_source",
    "simulator": "simulator",
    "imitator": "imitator",
    "latent": "latent",
    "task": "task",
}
STAGES: tuple[str, ...] = ("imitator", "latent", "task", "eval")


# ------------------------------------------------------------------------------------ errors
@dataclass
class SpecIssue:
    path: str  # dotted field path, "" for the whole document
    message: str
    line: int | None = None
    column: int | None = None

    def format(self, source: str) -> str:
        where = source
        if self.line is not None:
            where += f":{self.line}" + (f":{self.column}" if self.column is not None else "")
        return f"{where}: {self.path}: {self.message}" if self.path else f"{where}: {self.message}"


class SpecError(Exception):
    """User-input error in a spec: one or more issues, each with its field path."""

    def __init__(self, source: str, issues: list[SpecIssue]):
        self.source = source
        self.issues = issues
        super().__init__(self.format())

    def format(self) -> str:
        return "\n".join(issue.format(self.source) for issue in self.issues)


def _fmt_value(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _model_at(model: type[BaseModel] | None, loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The pydantic model that holds the field at ``loc`` (list indices and dict keys skipped)."""
    import typing

    def first_model(tp: Any) -> type[BaseModel] | None:
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            return tp
        for arg in typing.get_args(tp):
            found = first_model(arg)
            if found is not None:
                return found
        return None

    for part in loc:
        if model is None:
            return None
        if isinstance(part, str) and part in model.model_fields:
            model = first_model(model.model_fields[part].annotation)
    return model


def _unknown_field_hint(model: type[BaseModel] | None, name: Any) -> str:
    """``; did you mean 'lr'? allowed fields: ...`` (difflib), or "" without a model."""
    import difflib

    if model is None:
        return ""
    allowed = list(model.model_fields)
    close = difflib.get_close_matches(str(name), allowed, n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"{hint} allowed fields: {', '.join(allowed)}"


def _issues_from_validation(exc: ValidationError, prefix: tuple[Any, ...] = (), model: type[BaseModel] | None = None) -> list[SpecIssue]:
    issues = []
    for err in exc.errors(include_url=False):
        loc = prefix + tuple(err.get("loc", ()))
        msg = err["msg"]
        if err["type"] == "literal_error" and "expected" in (err.get("ctx") or {}):
            msg = f"must be one of {err['ctx']['expected']}"
        if err["type"] not in ("missing",) and "input" in err and not isinstance(err["input"], dict):
            msg += f" (got {_fmt_value(err['input'])})"
        if err["type"] == "extra_forbidden":
            local = tuple(err.get("loc", ()))
            msg = "unknown field" + (f" (got {_fmt_value(err.get('input'))})" if err.get("input") is not None else "")
            msg += _unknown_field_hint(_model_at(model, local[:-1]), local[-1] if local else "")
        issues.append(SpecIssue(".".join(str(p) for p in loc), msg))
    return issues


# -------------------------------------------------------------------------------- YAML + merge
#: limits of a spec document (a spec is a few kB and a few levels deep): see :mod:`mocap.safe_yaml`
MAX_SPEC_BYTES = safe_yaml.MAX_CHARS
MAX_SPEC_DEPTH = safe_yaml.MAX_DEPTH
#: the longest ``extends:`` chain and ``--set`` key (a spec extends one or two files)
MAX_EXTENDS_DEPTH = 64
MAX_SET_PARTS = 64


def _yaml_load(text: str, source: str) -> Any:
    try:
        return safe_yaml.load(text)
    except safe_yaml.YamlLimitError as exc:
        raise SpecError(source, [SpecIssue("", exc.message, exc.line)]) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or "invalid YAML"
        line = mark.line + 1 if mark is not None else None
        col = mark.column + 1 if mark is not None else None
        raise SpecError(source, [SpecIssue("", f"YAML syntax error: {problem}", line, col)]) from None
    except yaml.YAMLError as exc:
        raise SpecError(source, [SpecIssue("", f"YAML error: {exc}")]) from None
    except ValueError as exc:  # a value YAML cannot build, e.g. an integer of more than 4,300 digits
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        what = "a number of more than 4,300 digits" if "digits" in text else text[:200]
        raise SpecError(source, [SpecIssue("", f"unreadable value: {what}")]) from None


def deep_merge(base: Any, override: Any, _root: bool = True, replaced: list[tuple[str, Any, Any]] | None = None, _path: str = "") -> Any:
    """``override`` on top of ``base``: mappings merge recursively, everything else replaces.

    A component mapping whose ``name`` changes is replaced whole (the old params, and a stage's
    trainer, belong to another component); ``replaced`` collects ``(path, old name, new name)`` of
    each such mapping, for the hint :func:`extends_hints` adds to a later validation error.
    """
    if not (isinstance(base, dict) and isinstance(override, dict)):
        return copy.deepcopy(override)
    if not _root and "name" in base and "name" in override and base["name"] != override["name"]:
        if replaced is not None:
            replaced.append((_path, base["name"], override["name"]))
        return copy.deepcopy(override)
    out = copy.deepcopy(base)
    for key, value in override.items():
        sub = f"{_path}.{key}" if _path else str(key)
        out[key] = deep_merge(out[key], value, _root=False, replaced=replaced, _path=sub) if key in out else copy.deepcopy(value)
    return out


def extends_hints(exc: SpecError, replaced: list[tuple[str, Any, Any]]) -> SpecError:
    """``exc`` with a hint on each issue inside a section that ``extends:`` replaced whole because
    its component was renamed (the usual cause of "task.trainer.name: Field required")."""
    if not replaced:
        return exc
    issues = []
    for issue in exc.issues:
        for path, old, new in replaced:
            if issue.path == path or issue.path.startswith(path + "."):
                hint = (
                    f" (under `extends:`, {path} was renamed from {old!r} to {new!r}, so nothing of the parent's {path} "
                    "section is kept: its params and trainer belong to the other component; write the section in full)"
                )
                issue = SpecIssue(issue.path, issue.message + hint, issue.line, issue.column)
                break
        issues.append(issue)
    return SpecError(exc.source, issues)


def load_document(path: Path, _chain: tuple[Path, ...] = (), replaced: list[tuple[str, Any, Any]] | None = None) -> dict[str, Any]:
    """Read a spec file and everything it ``extends`` into one merged mapping (not yet validated);
    ``replaced``: see :func:`deep_merge`."""
    path = Path(path)
    source = str(path)
    try:
        found = path.is_file()
    except OSError as exc:  # e.g. a name over 255 bytes (ENAMETOOLONG), from an `extends:` value
        raise SpecError(source[:200], [SpecIssue("", f"cannot look up this spec file ({exc.strerror or exc})")]) from None
    if not found:
        raise SpecError(source, [SpecIssue("", "no such spec file")])
    resolved = path.resolve()
    if len(_chain) >= MAX_EXTENDS_DEPTH:
        chain = f"a chain of more than {MAX_EXTENDS_DEPTH} files extending one another (the last read: {source[:200]})"
        raise SpecError(str(_chain[0]), [SpecIssue("extends", chain)])
    if resolved in _chain:
        cycle = " -> ".join(str(p) for p in (*_chain, resolved))
        raise SpecError(source, [SpecIssue("extends", f"circular extends: {cycle}")])
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(source, [SpecIssue("", f"cannot read: {exc}")]) from None
    doc = parse_document(text, source)
    parent = doc.pop("extends", None)
    if parent is None:
        return _rebase_paths(doc, path.parent)
    if not isinstance(parent, str) or not parent:
        raise SpecError(source, [SpecIssue("extends", f"must be a relative path to another spec file (got {_fmt_value(parent)})")])
    base = load_document(path.parent / parent, (*_chain, resolved), replaced)
    return deep_merge(base, _rebase_paths(doc, path.parent), replaced=replaced)


def parse_document(text: str, source: str = "<spec>") -> dict[str, Any]:
    doc = _yaml_load(text, source)
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise SpecError(source, [SpecIssue("", f"a spec must be a YAML mapping, got {type(doc).__name__}")])
    bad = [k for k in doc if not isinstance(k, str)]
    if bad:
        raise SpecError(source, [SpecIssue("", f"keys must be strings (got {_fmt_value(bad[0])})")])
    return doc


def _rebase_paths(doc: dict[str, Any], base_dir: Path) -> dict[str, Any]:
    """Make stage ``checkpoint`` paths absolute relative to the file that wrote them."""
    for stage in ("imitator", "latent", "task"):
        section = doc.get(stage)
        if isinstance(section, dict) and isinstance(section.get("checkpoint"), str):
            ckpt = Path(section["checkpoint"]).expanduser()
            section["checkpoint"] = str(ckpt if ckpt.is_absolute() else (base_dir / ckpt).resolve())
    return doc


# ---------------------------------------------------------------------------------- overrides
def parse_override(item: str) -> tuple[list[str], Any]:
    """``a.b.c=value`` -> (["a", "b", "c"], value).

    Lists and mappings (``[1, 2]``, ``{k: v}``) and ``null`` are parsed as YAML; other scalars
    stay strings so that the schema types them (``"3"`` becomes 3 for an int field and stays
    ``"3"`` for a string field).
    """
    if "=" not in item:
        raise SpecError("--set", [SpecIssue("", f"expected KEY=VALUE, got {item!r}")])
    key, raw = item.split("=", 1)
    parts = [p for p in key.strip().split(".")]
    if len(parts) > MAX_SET_PARTS:
        raise SpecError("--set", [SpecIssue("", f"the key {_fmt_value(key)} has {len(parts):,} parts; a field path has at most {MAX_SET_PARTS}")])
    if not parts or any(not p for p in parts):
        raise SpecError("--set", [SpecIssue("", f"bad key {key!r} (use dotted field names, e.g. latent.params.beta)")])
    bad = safe_yaml.unwritable_char(item)
    if bad is not None:  # a lone surrogate: an argument's undecodable byte
        raise SpecError("--set", [SpecIssue("", f"{_fmt_value(item)} holds {bad}, which no file name or text file can hold")])
    value: Any = raw
    stripped = raw.strip()
    if stripped[:1] in ("[", "{") or stripped in ("null", "~"):
        value = _yaml_load(stripped, f"--set {key}")
    return parts, value


def apply_overrides(doc: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    doc = copy.deepcopy(doc)
    for item in overrides:
        parts, value = parse_override(item)
        node: Any = doc
        for i, part in enumerate(parts[:-1]):
            if isinstance(node, list):
                node = _list_item(node, part, parts[: i + 1])
                continue
            if not isinstance(node, dict):
                raise SpecError("--set", [SpecIssue(".".join(parts[:i]), f"is not a mapping; cannot set {'.'.join(parts)}")])
            nxt = node.get(part)
            if nxt is None:
                nxt = node[part] = {}
            node = nxt
        last = parts[-1]
        if isinstance(node, list):
            idx = _list_index(node, last, parts)
            node[idx] = value
        elif isinstance(node, dict):
            node[last] = value
        else:
            raise SpecError("--set", [SpecIssue(".".join(parts[:-1]), f"is not a mapping; cannot set {'.'.join(parts)}")])
    return doc


def _list_index(node: list[Any], part: str, parts: list[str]) -> int:
    try:
        idx = int(part)
        node[idx]
    except (ValueError, IndexError):
        raise SpecError("--set", [SpecIssue(".".join(parts), f"list index {part!r} out of range (length {len(node)})")]) from None
    return idx


def _list_item(node: list[Any], part: str, parts: list[str]) -> Any:
    return node[_list_index(node, part, parts)]


# -------------------------------------------------------------------------------- resolution
@dataclass
class ResolvedSpec:
    """A validated spec whose component params are filled with their defaults.

    ``spec.<role>.params`` hold the plain (JSON-able) validated values; ``params[path]`` the
    validated pydantic instances, keyed by the component's dotted path (``latent``,
    ``latent.trainer``, ``eval.metrics.0``).
    """

    spec: Spec
    source: str
    params: dict[str, BaseModel | None] = field(default_factory=dict)

    def to_yaml(self) -> str:
        data = self.spec.model_dump(mode="json", exclude_none=True)
        return yaml.safe_dump(data, sort_keys=False)


def iter_components(spec: Spec) -> Iterator[tuple[str, str, ComponentRef]]:
    """(dotted path, registry kind, ref) for every component the spec names."""
    for role, kind in ROLE_KINDS.items():
        ref = getattr(spec, role)
        if ref is None:
            continue
        yield role, kind, ref
        if isinstance(ref, StageSpec) and ref.trainer is not None:
            yield f"{role}.trainer", "trainer", ref.trainer
    if spec.eval is not None:
        yield "eval.trainer", "trainer", spec.eval.trainer
        for i, metric in enumerate(spec.eval.metrics):
            yield f"eval.metrics.{i}", "metric", metric


def resolve_relative_paths(model: BaseModel, base_dir: Path) -> BaseModel:
    """Make every relative ``Path`` in a params model (nested models and lists included) relative
    to ``base_dir`` (the directory of the spec file that is run), so a spec works from any cwd."""

    def fix(value: Any) -> Any:
        if isinstance(value, Path):
            value = value.expanduser()
            return value if value.is_absolute() else (base_dir / value).resolve()
        if isinstance(value, BaseModel):
            for name in type(value).model_fields:
                setattr(value, name, fix(getattr(value, name)))
            return value
        if isinstance(value, list):
            return [fix(v) for v in value]
        if isinstance(value, tuple):
            return tuple(fix(v) for v in value)
        if isinstance(value, dict):
            return {k: fix(v) for k, v in value.items()}
        return value

    return fix(model)


def validate_document(doc: dict[str, Any], plugins: PluginSet, source: str = "<spec>", base_dir: Path | None = None, provenance: Any = None) -> ResolvedSpec:
    """Validate a merged mapping against the structure and every component's params model.

    Relative paths inside component params are resolved against ``base_dir`` (default: cwd).
    """
    base_dir = Path(base_dir) if base_dir is not None else Path.cwd()
    try:
        spec = Spec.model_validate(doc)
    except ValidationError as exc:
        raise SpecError(source, _issues_from_validation(exc, model=Spec)) from None
    issues: list[SpecIssue] = []
    resolved: dict[str, BaseModel | None] = {}
    for path, kind, ref in iter_components(spec):
        try:
            comp = plugins.get(kind, ref.name)
        except UnknownComponent as exc:
            listed = ", ".join(exc.choices) or "(none registered)"
            hint = install_hint(kind, ref.name, provenance)
            issues.append(SpecIssue(f"{path}.name", f"unknown {kind} {ref.name!r}; registered {kind}s: {listed}{hint}"))
            continue
        except PluginError as exc:
            issues.append(SpecIssue(f"{path}.name", str(exc)))
            continue
        try:
            model = comp.validate_params(ref.params)
        except ValidationError as exc:
            issues.extend(_issues_from_validation(exc, tuple(path.split(".")) + ("params",), comp.params))
            continue
        except ValueError as exc:
            issues.append(SpecIssue(f"{path}.params", str(exc)))
            continue
        if model is not None:
            model = resolve_relative_paths(model, base_dir)
        resolved[path] = model
        ref.params = model.model_dump(mode="json") if model is not None else {}
    if issues:
        raise SpecError(source, issues)
    return ResolvedSpec(spec=spec, source=source, params=resolved)


def load_spec(path: str | Path, plugins: PluginSet, overrides: list[str] | None = None) -> ResolvedSpec:
    """Read, merge (``extends``), override (``--set``) and validate a spec file."""
    replaced: list[tuple[str, Any, Any]] = []
    doc = load_document(Path(path), replaced=replaced)
    if overrides:
        doc = apply_overrides(doc, overrides)
    try:
        return validate_document(doc, plugins, source=str(path), base_dir=Path(path).resolve().parent)
    except SpecError as exc:
        raise extends_hints(exc, replaced) from None


def load_spec_text(text: str, plugins: PluginSet, source: str = "<spec>", overrides: list[str] | None = None) -> ResolvedSpec:
    doc = parse_document(text, source)
    if "extends" in doc:
        raise SpecError(source, [SpecIssue("extends", "only spec files can extend other files")])
    if overrides:
        doc = apply_overrides(doc, overrides)
    return validate_document(doc, plugins, source=source)


def json_schema(plugins: PluginSet) -> dict[str, Any]:
    """JSON Schema of specs for editors: each role's ``params`` is typed by its registered components."""
    schema = Spec.model_json_schema()
    defs = schema.setdefault("$defs", {})

    def one_of(kind: str) -> dict[str, Any]:
        variants = []
        for name in plugins.names(kind):
            comp = plugins.components[kind][name]
            params_schema: dict[str, Any] = {"type": "object", "maxProperties": 0}
            if comp.params is not None:
                sub = comp.params.model_json_schema(ref_template="#/$defs/{model}")
                defs.update(sub.pop("$defs", {}))
                params_schema = sub
            variants.append(
                {
                    "type": "object",
                    "description": comp.description,
                    "properties": {"name": {"const": name}, "params": params_schema},
                    "required": ["name"],
                }
            )
        return {"oneOf": variants} if variants else {}

    trainers = one_of("trainer")
    if trainers:  # a stage's (and eval's) trainer params are typed by the registered trainers too
        for model in defs.values():
            field = model.get("properties", {}).get("trainer")
            if field is None:
                continue
            typed = {"allOf": [{"$ref": "#/$defs/ComponentRef"}, trainers]}
            nullable = "anyOf" in field
            model["properties"]["trainer"] = {
                **{k: v for k, v in field.items() if k not in ("anyOf", "$ref")},
                **({"anyOf": [typed, {"type": "null"}]} if nullable else typed),
            }
    props = schema["properties"]
    for role, kind in ROLE_KINDS.items():
        variants = one_of(kind)
        if variants:
            props[role] = (
                {"allOf": [props[role], variants]}
                if "anyOf" not in props[role]
                else {"anyOf": [{"allOf": [{"$ref": "#/$defs/StageSpec"}, variants]}, {"type": "null"}]}
            )
    return schema
