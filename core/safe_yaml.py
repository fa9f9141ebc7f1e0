"""Reading YAML a user hands to mocap (spec files, ``--set`` values, a run's ``spec.yaml``, the spec
embedded in a checkpoint) with bounded work and memory: every such load goes through :func:`load`.

YAML aliases (``*name``) repeat the node their anchor (``&name``) names without repeating its text,
so a 1 kB document of nine levels of ten aliases each stands for 10**9 values: PyYAML builds it
cheaply (the repeats share one Python object) but whatever walks it later (validation, a deep
copy, an error message's ``repr``) expands it. :class:`BoundedLoader` therefore measures the
composed node graph **with aliases expanded** before anything is built, and refuses a document of
more than :data:`MAX_NODES` values, nested (aliases included) deeper than :data:`MAX_DEPTH` levels,
or one that refers to itself (``&a [*a]``); it also refuses duplicate mapping keys (YAML would
silently keep the last) and strings holding a NUL character or a lone surrogate (``"\\ud83d"``). This module imports no torch and no pydantic.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

#: the most characters of a YAML document read (a spec is a few kB)
MAX_CHARS = 1_000_000
#: the most values (scalars, lists and mappings) a document may stand for, its aliases expanded
MAX_NODES = 100_000
#: the deepest nesting, aliases expanded (PyYAML and pydantic recurse once per level)
MAX_DEPTH = 50


class YamlLimitError(yaml.YAMLError):
    """A document over one of this module's limits; ``line`` (1-based) where the problem is, if known."""

    def __init__(self, message: str, line: int | None = None):
        super().__init__(message)
        self.message = message
        self.line = line

    def __str__(self) -> str:
        return self.message if self.line is None else f"{self.message} (line {self.line})"


#: characters no spec text holds: NUL (no path or name may contain it) and lone UTF-16 surrogates
#: (``"\\ud83d"`` in YAML: no file can be written with one)
_UNWRITABLE = re.compile("[\x00\ud800-\udfff]")


def unwritable_char(text: str) -> str | None:
    """``"a NUL character"`` or ``"a lone surrogate \\ud83d"`` when ``text`` holds one, else None."""
    m = _UNWRITABLE.search(text)
    if m is None:
        return None
    return "a NUL character" if m.group() == "\x00" else f"a lone surrogate \\u{ord(m.group()):04x}"


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [part for pair in node.value for part in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _line(node: yaml.Node) -> int | None:
    mark = node.start_mark
    return mark.line + 1 if mark is not None else None


def check_expanded_size(root: yaml.Node, max_nodes: int = MAX_NODES, max_depth: int = MAX_DEPTH) -> int:
    """The number of values the composed document ``root`` stands for, each alias counted as a full
    copy of what it names; :class:`YamlLimitError` beyond ``max_nodes`` or ``max_depth``, or for a
    node that contains itself. Linear in the number of distinct nodes (an iterative walk, memoized
    per node), so it never expands anything itself."""
    done: dict[int, tuple[int, int]] = {}  # id(node) -> (values, depth)
    open_: set[int] = set()  # nodes whose children are being measured: the current path
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        key = id(node)
        if finished:
            kids = _children(node)
            size = 1 + sum(done[id(k)][0] for k in kids)
            depth = 1 + max((done[id(k)][1] for k in kids), default=0)
            open_.discard(key)
            done[key] = (size, depth)
            if size > max_nodes:
                raise YamlLimitError(
                    f"the document stands for more than {max_nodes:,} values (its aliases *name expanded); a spec holds at most {max_nodes:,}",
                    _line(node),
                )
            if depth > max_depth:
                raise YamlLimitError(f"nested more than {max_depth} levels deep (aliases *name expanded)", _line(node))
            continue
        if key in done:
            continue
        if key in open_:
            raise YamlLimitError("an alias refers to a node that contains it (a recursive structure)", _line(node))
        bad = unwritable_char(node.value) if isinstance(node, yaml.ScalarNode) and isinstance(node.value, str) else None
        if bad is not None:
            raise YamlLimitError(f"a string holds {bad}, which no file name or text file can hold", _line(node))
        open_.add(key)
        stack.append((node, True))
        stack.extend((kid, False) for kid in _children(node) if id(kid) not in done)
    return done[id(root)][0]


def count_values(obj: Any, limit: int) -> int:
    """The number of values (scalars, lists and mappings, keys included) in a loaded document,
    counting a shared object once per place it appears; stops counting past ``limit`` (it then
    returns a number above ``limit``)."""
    count = 0
    stack = [obj]
    while stack and count <= limit:
        item = stack.pop()
        count += 1
        if isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
    return count


class BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that checks the composed document (:func:`check_expanded_size`) before
    building any object, and refuses duplicate mapping keys and deep nesting while composing."""

    _depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:  # checked here too: composing recurses once per level
                raise YamlLimitError(f"nested more than {MAX_DEPTH} levels deep", self.peek_event().start_mark.line + 1)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def get_single_node(self) -> Any:
        node = super().get_single_node()
        if node is not None:
            check_expanded_size(node)
        return node

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            seen: set[Any] = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":  # `<<: *anchor`: merged keys may be overridden
                    continue
                key = self.construct_object(key_node, deep=True)  # type: ignore[no-untyped-call]
                try:
                    dup = key in seen
                    seen.add(key)
                except TypeError:  # an unhashable key: SafeLoader reports it
                    continue
                if dup:
                    raise yaml.constructor.ConstructorError("while reading a mapping", node.start_mark, f"duplicate key {key!r}", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


def load(text: str) -> Any:
    """The value of one YAML document, read with :class:`BoundedLoader`. Raises
    :class:`YamlLimitError` (a :class:`yaml.YAMLError`) for a document over :data:`MAX_CHARS`
    characters or over the loader's limits, another :class:`yaml.YAMLError` for bad YAML, and
    ``ValueError`` for a value YAML cannot build (an integer of more than 4,300 digits)."""
    if len(text) > MAX_CHARS:
        raise YamlLimitError(f"the document is {len(text):,} characters; a spec is at most {MAX_CHARS:,}")
    return yaml.load(text, Loader=BoundedLoader)  # noqa: S506 - a SafeLoader subclass


__all__ = ["MAX_CHARS", "MAX_DEPTH", "MAX_NODES", "BoundedLoader", "YamlLimitError", "check_expanded_size", "count_values", "load", "unwritable_char"]
