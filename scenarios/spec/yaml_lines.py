"""Reading a scenario or sweep file: YAML with the line of every field, validated by a
pydantic model whose errors name the file, the line and the field (``moved_pod.yaml:23:
events[1].at: must be a number of seconds >= 0, got 'soon'``).

- ``parse_yaml(text, source)`` composes the document with PyYAML's ``SafeLoader`` (plain
  data only, no Python objects), rejects a key given twice in one mapping, constructs the
  data, then walks the node tree alongside the data to record the 1-based line of every
  mapping key and sequence item (``Document.lines``, keyed by field path).
- ``Document.with_overrides`` sets dotted keys (``map_server.policy``) on the data, as a
  sweep does; an error in an overridden value names the override instead of a line.
- ``Document.validate`` validates the data with a pydantic model, strictly (a string is
  not a number; ``mapserver.service.validation`` has the shared types and sections); its
  first problem becomes a ``ScenarioError`` at the line of the field.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from mapserver.core.errors import FleetmapError, dotted
from mapserver.service.validation import MISSING, problems, short_repr

FieldPath = tuple[str | int, ...]
"""Where a value sits in the document: mapping keys and list indices from the top."""

M = TypeVar("M", bound=BaseModel)

_MERGE_TAG = "tag:yaml.org,2002:merge"


def field_path(name: str) -> FieldPath:
    """``obstacles[2].box.x`` -> ``("obstacles", 2, "box", "x")``."""
    return tuple(
        int(index) if index else key for key, index in re.findall(r"([^.\[\]]+)|\[(\d+)\]", name)
    )


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
    paths set by overrides (which have no line); ``root`` names the whole document in
    errors (``scenario``, ``sweep``)."""

    source: str
    data: Any
    lines: Mapping[FieldPath, int] = field(default_factory=dict)
    overridden: frozenset[FieldPath] = frozenset()
    root: str = "scenario"

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
        name = dotted(path, self.root)
        if any(path[:n] in self.overridden for n in range(len(path) + 1)):
            name += " (override)"
        return ScenarioError(self.source, self.line(path), name, detail)

    def validate(self, model: type[M]) -> M:
        """The data validated by ``model``, strictly; its first problem raises a
        ScenarioError at the line of the field."""
        try:
            return model.model_validate(self.data, strict=True)
        except ValidationError as exc:
            first = problems(exc, self.root)[0]
            raise self.error(first.loc, first.reason, first.value) from None

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
def parse_yaml(text: str, source: str, root: str = "scenario") -> Document:
    """The YAML document in ``text`` with the line of every field (module docstring).

    Raises ScenarioError for invalid YAML (at the line of the problem), for more than
    one document, and for a key given twice in one mapping.
    """
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return Document(source, None, root=root)
        _reject_duplicate_keys(loader, node, (), source, set())
        data = loader.construct_document(node)
        lines: dict[FieldPath, int] = {}
        _record_lines(loader, node, data, (), lines, set())
        return Document(source, data, lines, root=root)
    except ScenarioError:
        raise
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or str(exc)
        line = mark.line + 1 if mark is not None else None
        raise ScenarioError(source, line, root, f"not valid YAML: {problem}") from None
    except (yaml.YAMLError, ValueError, OverflowError, RecursionError) as exc:
        raise ScenarioError(source, None, root, f"not valid YAML: {exc}") from None
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
