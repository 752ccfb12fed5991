"""Reading a scenario file: YAML with the line of every field, and typed readers whose
errors name the file, the line and the field (``moved_pod.yaml:23: events[1].at: must be
a number of seconds >= 0, got 'soon'``).

- ``parse_yaml(text, source)`` composes the document with PyYAML's ``SafeLoader`` (plain
  data only, no Python objects), rejects a key given twice in one mapping, constructs the
  data, then walks the node tree alongside the data to record the 1-based line of every
  mapping key and sequence item (``Document.lines``, keyed by field path).
- ``Document.with_overrides`` sets dotted keys (``map_server.policy``) on the data, as a
  sweep does; an error in an overridden value names the override instead of a line.
- ``Fields`` reads one mapping of the document: unknown keys are errors (with the
  closest known key as a hint), and each typed read (``number``, ``integer``, ``text``,
  ...) raises a ``ScenarioError`` at the field it reads.
- ``build_dataclass`` fills a domain dataclass (``LidarConfig``, ``DriveLimits``, ...)
  from a mapping: keys are its fields, types come from its annotations, and the value
  rules are the class's own (its ``ValueError`` names the field it rejects).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from mapserver.core.errors import FieldError, FleetmapError

FieldPath = tuple[str | int, ...]
"""Where a value sits in the document: mapping keys and list indices from the top."""

T = TypeVar("T")


class _Missing:
    def __repr__(self) -> str:
        return "<missing>"


MISSING: Any = _Missing()
"""The value of a field the file does not give (an error about it shows no ``got``)."""

_MERGE_TAG = "tag:yaml.org,2002:merge"


def dotted(path: FieldPath) -> str:
    """``("events", 1, "at")`` -> ``events[1].at``; the empty path is ``scenario``."""
    text = ""
    for part in path:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text or "scenario"


def field_path(name: str) -> FieldPath:
    """``obstacles[2].box.x`` -> ``("obstacles", 2, "box", "x")``."""
    return tuple(
        int(index) if index else key for key, index in re.findall(r"([^.\[\]]+)|\[(\d+)\]", name)
    )


def short_repr(value: Any) -> str:
    """``repr(value)``, cut to 80 characters."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


class ScenarioError(FleetmapError, ValueError):
    """An invalid scenario: ``source:line: field: what is wrong, got value``.

    source: the file (as given); line: 1-based, None when unknown; field: the dotted
    field path (``events[1].at``); detail: what is wrong, with the bad value.
    """

    def __init__(self, source: str, line: int | None, field: str, detail: str) -> None:
        self.source = source
        self.line = line
        self.field = field
        self.detail = detail
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {field}: {detail}")


@dataclass(frozen=True)
class Document:
    """A parsed scenario file: its ``data``, the ``lines`` of its fields, and the field
    paths set by overrides (which have no line)."""

    source: str
    data: Any
    lines: Mapping[FieldPath, int] = field(default_factory=dict)
    overridden: frozenset[FieldPath] = frozenset()

    def line(self, path: FieldPath) -> int | None:
        """The line of ``path``, or of its nearest enclosing field that has one."""
        for n in range(len(path), -1, -1):
            prefix = path[:n]
            if prefix in self.overridden:
                return None
            if prefix in self.lines:
                return self.lines[prefix]
        return None

    def error(self, path: FieldPath, reason: str, value: Any = MISSING) -> ScenarioError:
        """A ScenarioError at ``path``: ``reason``, then ``got value`` unless MISSING."""
        detail = reason if value is MISSING else f"{reason}, got {short_repr(value)}"
        name = dotted(path)
        if any(path[:n] in self.overridden for n in range(len(path) + 1)):
            name += " (override)"
        return ScenarioError(self.source, self.line(path), name, detail)

    def with_overrides(self, overrides: Mapping[str, Any]) -> Document:
        """This document with each dotted key of ``overrides`` set to its value
        (``{"map_server.decay.half_life_occupied": 10}``); missing mappings are created."""
        data = _copy_mappings(self.data if self.data is not None else {})
        if not isinstance(data, dict):
            raise self.error((), "must be a mapping of scenario fields", data)
        overridden = set(self.overridden)
        for key, value in overrides.items():
            path: FieldPath = tuple(str(key).split("."))
            target = data
            for depth, part in enumerate(path[:-1]):
                child = target.setdefault(part, {})
                if child is None:
                    child = target[part] = {}
                if not isinstance(child, dict):
                    raise self.error(path[: depth + 1], f"cannot set override {key!r}", child)
                target = child
            target[path[-1]] = value
            overridden.add(path)
        return dataclasses.replace(self, data=data, overridden=frozenset(overridden))


def _copy_mappings(value: Any) -> Any:
    """A copy of the nested dicts of ``value`` (lists and scalars shared)."""
    if isinstance(value, dict):
        return {k: _copy_mappings(v) for k, v in value.items()}
    return value


# ---------------------------------------------------------------------------- parsing
def parse_yaml(text: str, source: str) -> Document:
    """The YAML document in ``text`` with the line of every field (module docstring).

    Raises ScenarioError for invalid YAML (at the line of the problem), for more than
    one document, and for a key given twice in one mapping.
    """
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return Document(source, None)
        _reject_duplicate_keys(loader, node, (), source, set())
        data = loader.construct_document(node)
        lines: dict[FieldPath, int] = {}
        _record_lines(loader, node, data, (), lines, set())
        return Document(source, data, lines)
    except ScenarioError:
        raise
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or str(exc)
        line = mark.line + 1 if mark is not None else None
        raise ScenarioError(source, line, "scenario", f"not valid YAML: {problem}") from None
    except (yaml.YAMLError, ValueError, OverflowError, RecursionError) as exc:
        raise ScenarioError(source, None, "scenario", f"not valid YAML: {exc}") from None
    finally:
        loader.dispose()


def _scalar_key(loader: yaml.SafeLoader, node: Node) -> Any:
    """The constructed value of a scalar key node (MISSING for other keys)."""
    if not isinstance(node, ScalarNode):
        return MISSING
    return loader.construct_object(node)


def _reject_duplicate_keys(
    loader: yaml.SafeLoader, node: Node, path: FieldPath, source: str, active: set[int]
) -> None:
    """Raise ScenarioError at the second of two equal keys in one mapping (merge keys
    ``<<`` may repeat keys: the explicit one wins, as YAML says)."""
    if id(node) in active:  # an alias of an enclosing node: already being checked
        return
    active.add(id(node))
    if isinstance(node, MappingNode):
        seen: dict[Any, int] = {}
        for key_node, value_node in node.value:
            if key_node.tag == _MERGE_TAG:
                continue
            key = _scalar_key(loader, key_node)
            line = key_node.start_mark.line + 1
            if key is not MISSING:  # scalar keys are hashable
                if key in seen:
                    raise ScenarioError(
                        source,
                        line,
                        dotted((*path, key)),
                        f"is given twice in one mapping (first on line {seen[key]})",
                    )
                seen[key] = line
            child = key if isinstance(key, str | int) else "?"
            _reject_duplicate_keys(loader, value_node, (*path, child), source, active)
    elif isinstance(node, SequenceNode):
        for i, item in enumerate(node.value):
            _reject_duplicate_keys(loader, item, (*path, i), source, active)
    active.discard(id(node))


def _record_lines(
    loader: yaml.SafeLoader,
    node: Node,
    data: Any,
    path: FieldPath,
    lines: dict[FieldPath, int],
    active: set[int],
) -> None:
    """Record the line of every key and item under ``node``, whose value is ``data``."""
    if id(node) in active:  # a recursive alias
        return
    active.add(id(node))
    if isinstance(node, MappingNode) and isinstance(data, dict):
        for key_node, value_node in node.value:  # merges are flattened: explicit keys last
            key = _scalar_key(loader, key_node)
            if not isinstance(key, str | int) or isinstance(key, bool) or key not in data:
                continue
            lines[(*path, key)] = key_node.start_mark.line + 1
            _record_lines(loader, value_node, data[key], (*path, key), lines, active)
    elif isinstance(node, SequenceNode) and isinstance(data, list):
        for i, (item, value) in enumerate(zip(node.value, data, strict=False)):
            lines[(*path, i)] = item.start_mark.line + 1
            _record_lines(loader, item, value, (*path, i), lines, active)
    active.discard(id(node))


# ---------------------------------------------------------------------------- reading
def is_number(value: Any) -> bool:
    """A finite int or float (not a bool)."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int beyond any float
        return False


def check_number(
    doc: Document,
    path: FieldPath,
    value: Any,
    *,
    unit: str = "",
    low: float | None = None,
    low_open: bool = False,
    high: float | None = None,
    integer: bool = False,
) -> Any:
    """``value`` if it is a finite number (an int if ``integer``) within the bounds, as a
    float (int); else a ScenarioError at ``path`` such as ``must be a number of seconds
    >= 0``. unit: ``seconds``, ``metres``, ... (named in the message)."""
    kind = "an integer" if integer else "a number"
    if unit:
        kind += f" of {unit}"
    if low is not None and high is not None:
        bound = f" in {'(' if low_open else '['}{low:g}, {high:g}]"
    elif low is not None:
        bound = f" {'>' if low_open else '>='} {low:g}"
    elif high is not None:
        bound = f" <= {high:g}"
    else:
        bound = ""
    ok = isinstance(value, int) if integer else True
    ok = ok and is_number(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        raise doc.error(path, f"must be {kind}{bound}", value)
    return int(value) if integer else float(value)


def check_text(doc: Document, path: FieldPath, value: Any, what: str = "a string") -> str:
    """``value`` if it is a non-empty string (stripped), else a ScenarioError at ``path``."""
    if not isinstance(value, str) or not value.strip():
        raise doc.error(path, f"must be {what} (a non-empty string)", value)
    return value.strip()


def check_list(doc: Document, path: FieldPath, value: Any) -> list[tuple[FieldPath, Any]]:
    """The items of list ``value`` with their paths; ScenarioError if it is no list."""
    if not isinstance(value, list):
        raise doc.error(path, "must be a list", value)
    return [((*path, i), item) for i, item in enumerate(value)]


def check_point(doc: Document, path: FieldPath, value: Any) -> tuple[float, float]:
    """``[x, y]`` [m] as a tuple of floats; ScenarioError otherwise."""
    if not (isinstance(value, list) and len(value) == 2 and all(map(is_number, value))):
        raise doc.error(path, "must be a point [x, y] of two numbers of metres", value)
    return (float(value[0]), float(value[1]))


class Fields:
    """The mapping at ``path`` of ``doc`` (None reads as empty), read field by field.

    allowed: the keys it may hold (others are errors naming the closest allowed key);
    required: keys it must hold. ``what`` names the mapping in messages.
    """

    def __init__(
        self,
        doc: Document,
        path: FieldPath,
        value: Any,
        allowed: Iterable[str],
        required: Iterable[str] = (),
    ) -> None:
        self.doc = doc
        self.path = path
        allowed = tuple(allowed)
        if value is None:
            value = {}
        if not isinstance(value, dict):
            raise doc.error(path, "must be a mapping", value)
        for key in value:
            if isinstance(key, str) and key in allowed:
                continue
            choices = ", ".join(sorted(allowed))
            if not isinstance(key, str):
                raise doc.error(path, f"has key {key!r}, not a field name (expected {choices})")
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else f" (expected one of {choices})"
            raise doc.error((*path, key), f"is not a field of {dotted(path)}{hint}")
        for key in required:
            if key not in value:
                raise doc.error((*path, key), "is required")
        self.data: dict[str, Any] = value

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def at(self, key: str | int) -> FieldPath:
        """The path of ``key`` in this mapping."""
        return (*self.path, key)

    def get(self, key: str, default: Any = None) -> Any:
        """The raw value of ``key`` (``default`` when absent)."""
        return self.data.get(key, default)

    def _value(self, key: str, default: Any) -> Any:
        if key in self.data:
            return self.data[key]
        if default is MISSING:
            raise self.doc.error(self.at(key), "is required")
        return default

    def number(self, key: str, default: Any = MISSING, **bounds: Any) -> Any:
        """Field ``key`` as a float checked by ``check_number`` (``default`` if absent,
        returned as is)."""
        if key not in self.data and default is not MISSING:
            return default
        return check_number(self.doc, self.at(key), self._value(key, default), **bounds)

    def integer(self, key: str, default: Any = MISSING, **bounds: Any) -> Any:
        """Field ``key`` as an int (``check_number(integer=True)``)."""
        return self.number(key, default, integer=True, **bounds)

    def text(self, key: str, default: Any = MISSING, what: str = "a string") -> Any:
        """Field ``key`` as a non-empty string (``default`` if absent)."""
        if key not in self.data and default is not MISSING:
            return default
        return check_text(self.doc, self.at(key), self._value(key, default), what)

    def items(self, key: str) -> list[tuple[FieldPath, Any]]:
        """The items of list field ``key`` with their paths (none when absent or null)."""
        value = self.data.get(key)
        return [] if value is None else check_list(self.doc, self.at(key), value)

    def fields(self, key: str, allowed: Iterable[str], required: Iterable[str] = ()) -> Fields:
        """The mapping field ``key`` (empty when absent)."""
        return Fields(self.doc, self.at(key), self.data.get(key), allowed, required)


def build_dataclass(
    doc: Document, path: FieldPath, value: Any, cls: type[T], defaults: Mapping[str, Any] = {}
) -> T:
    """An instance of the frozen dataclass ``cls`` from the mapping ``value`` at ``path``.

    Keys are the class's init fields; ``float``, ``int`` and ``bool`` fields must hold
    finite numbers, integers and booleans; ``defaults`` replace the class's own defaults
    for absent keys. The class checks the values: its ``ValueError`` (``name must ...``)
    becomes a ScenarioError at field ``name``.
    """
    names = [f.name for f in dataclasses.fields(cls) if f.init]  # type: ignore[arg-type]
    reader = Fields(doc, path, value, names)
    kwargs: dict[str, Any] = dict(defaults)
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name not in reader:
            continue
        raw = reader.get(f.name)
        where = reader.at(f.name)
        if f.type == "bool":
            if not isinstance(raw, bool):
                raise doc.error(where, "must be true or false", raw)
            kwargs[f.name] = raw
        elif f.type == "int":
            kwargs[f.name] = check_number(doc, where, raw, integer=True)
        elif f.type == "float":
            kwargs[f.name] = check_number(doc, where, raw)
        else:
            raise TypeError(f"{cls.__name__}.{f.name}: unsupported field type {f.type!r}")
    try:
        return cls(**kwargs)
    except FieldError as exc:
        if exc.field not in names:
            raise doc.error(path, str(exc)) from None
        raise doc.error((*path, exc.field), exc.reason, kwargs.get(exc.field, MISSING)) from None
    except ValueError as exc:
        raise doc.error(path, str(exc)) from None
