"""Argument types and the parser class shared by every ``fleetmap`` command.

``CommandParser`` reads a value that starts with a minus sign followed by a digit
(``--origin -12,-25``, ``--start -3.5,2``) as a value, as written, where argparse alone
takes ``-12,-25`` for an unknown option. No fleetmap option looks like a negative number,
so nothing is lost.

``add_dataclass_args`` generates one flag per field of a domain dataclass (``SensorModel``,
``DecayParams``), as ``validation.domain_section`` generates the settings sections from
them: the flag's name, type and default from the field, its help from the field's entry in
the class docstring (``field_docs``); ``dataclass_from_args`` builds the object back.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import typing
from typing import Any

NEGATIVE_VALUE = re.compile(r"^-\.?\d")
"""What argparse must read as a value, never as an option: ``-`` then a digit or ``.5``."""


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Help that shows each option's default: `` (default: 0.05)`` after its text, unless
    the text already says its default in words (``default: sized from the data``), it
    has none (None: the option is off or derived) or it is an on/off switch's False."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            "default" in text
            or default is None
            or default is argparse.SUPPRESS
            or (default is False and action.nargs == 0)
            or not action.option_strings
        ):
            return action.help
        return f"{text} (default: %(default)s)"


class CommandParser(argparse.ArgumentParser):
    """An ArgumentParser whose arguments may start with a negative number (``-12,-25``)
    and whose help shows the defaults (``DefaultsHelpFormatter``); its subparsers are
    CommandParsers too (argparse makes them of the parent's type)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_VALUE


def xy_pair(text: str) -> tuple[float, float]:
    """argparse type for ``X,Y`` [m] (negative values as written: ``-12,-25``)."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}") from None
    return x, y


def number_or_none(text: str) -> float | None:
    """argparse type for a ``float | None`` field (``--no-return-range``): metres, or
    ``none``."""
    if text.strip().lower() == "none":
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected metres or 'none', got {text!r}") from None


_FLAG_KINDS: dict[Any, dict[str, Any]] = {
    float: {"type": float},
    int: {"type": int},
    bool: {"action": argparse.BooleanOptionalAction},
    float | None: {"type": number_or_none},
}
"""How a field of each annotation becomes a flag (``add_dataclass_args``)."""

_ENTRY = re.compile(r"(?P<names>[a-z_][a-z0-9_]*(?:, [a-z_][a-z0-9_]*)*): (?P<text>.+)")
"""A field's entry in a class docstring: ``name: text`` or ``name, other: text``."""


def field_docs(cls: type) -> dict[str, str]:
    """Each field's description in ``cls``'s docstring, as plain text: the entries
    ``name: text`` (``name, other: text`` for fields sharing one) at the docstring's left
    margin, each continued on the more indented lines below it."""
    docs: dict[str, list[str]] = {}
    names: list[str] = []
    for line in inspect.cleandoc(cls.__doc__ or "").splitlines():
        entry = _ENTRY.fullmatch(line)
        if entry:
            names = entry["names"].split(", ")
            for name in names:
                docs[name] = [entry["text"]]
        elif names and line[:1].isspace() and line.strip():
            for name in names:
                docs[name].append(line.strip())
        else:
            names = []
    return {name: _plain(" ".join(parts)) for name, parts in docs.items()}


def _plain(text: str) -> str:
    """Docstring text without its markup (````code````, ``*emphasis*``)."""
    return re.sub(r"\*(\w[^*]*?)\*", r"\1", re.sub(r"``(.+?)``", r"\1", text))


def add_dataclass_args(group: Any, domain: type) -> None:
    """Add to ``group`` (a parser or argument group) a flag per init field of dataclass
    ``domain``: ``--field-name`` (dest the field's name), its type from the annotation
    (``_FLAG_KINDS``: a bool is ``--name``/``--no-name``, a ``float | None`` takes
    ``none``), its default the field's, its help the field's docstring entry
    (``field_docs``). TypeError when a field has no entry or a type with no flag kind."""
    hints = typing.get_type_hints(domain)
    docs = field_docs(domain)
    for f in dataclasses.fields(domain):
        if not f.init:
            continue
        if f.name not in docs or hints[f.name] not in _FLAG_KINDS:
            raise TypeError(
                f"{domain.__name__}.{f.name}: a flag needs a docstring entry "
                f"'{f.name}: ...' and a type of {', '.join(map(str, _FLAG_KINDS))}"
            )
        kind = dict(_FLAG_KINDS[hints[f.name]])
        if kind.get("type") is number_or_none:
            kind["metavar"] = f"{f.name.upper()}|none"
        group.add_argument(
            "--" + f.name.replace("_", "-"),
            default=f.default,
            help=docs[f.name].replace("%", "%%") + " (default: %(default)s)",
            **kind,
        )


def dataclass_from_args(domain: type, args: argparse.Namespace) -> Any:
    """``domain`` built from the flags ``add_dataclass_args`` added (its own validation
    names a bad value's field)."""
    return domain(**{f.name: getattr(args, f.name) for f in dataclasses.fields(domain) if f.init})
