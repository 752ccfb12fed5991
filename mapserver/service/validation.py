"""Validation shared by the server's settings and the scenario and sweep files: pydantic
models whose errors read ``field: reason, got value``.

- ``Section``: a mapping of known fields; an unknown key is an error at that key naming
  the closest field (``is not a field of units; did you mean 'count'?``).
- ``number`` / ``text``: annotated types whose errors read as one sentence (``must be a
  number of seconds >= 0``). Validated with ``strict=True`` (scenario and sweep files) a
  string is not a number and ``true`` is not one either; ints pass as floats. Settings
  are validated lax, as environment variables are strings.
- ``domain_section``: a section generated from a domain dataclass (``SensorModel``,
  ``LidarConfig``, ...): its fields, types and defaults; ``build()`` makes the domain
  object, whose ``FieldError`` becomes an error at the field it names.
- ``problems``: a ``ValidationError`` as (location, reason, value) triples.
"""

from __future__ import annotations

import dataclasses
import sys
import typing
from collections.abc import Callable
from typing import Annotated, Any, ClassVar, NamedTuple

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
    Tag,
    ValidationError,
    ValidatorFunctionWrapHandler,
    WrapValidator,
    create_model,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from mapserver.core.errors import FieldError, dotted
from mapserver.core.text import name_hint

Loc = tuple[str | int, ...]
"""Where a value sits: mapping keys and list indices from the top."""


class _Missing:
    def __repr__(self) -> str:
        return "<missing>"


MISSING: Any = _Missing()
"""The value of a field that is not given (an error about it shows no ``got``)."""

_TAG = "<{}>"
"""How a union variant is tagged (``variant``); tags are dropped from error locations."""


def short_repr(value: Any) -> str:
    """``repr(value)``, cut to 80 characters."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def error(loc: Loc, value: Any, reason: str) -> ValidationError:
    """A validation error at ``loc`` (relative to the model raising it): ``reason``."""
    details = InitErrorDetails(
        type=PydanticCustomError("invalid", "{reason}", {"reason": reason}), loc=loc, input=value
    )
    return ValidationError.from_exception_data("validation", [details])


# ---------------------------------------------------------------------------- types
def reworded(reason: str) -> WrapValidator:
    """Any error of the wrapped type reads ``reason``."""

    def validate(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
        try:
            return handler(value)
        except ValidationError:
            raise PydanticCustomError("invalid", reason) from None

    return WrapValidator(validate)


def number(
    unit: str = "",
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    integer: bool = False,
) -> Any:
    """A finite float (an int with ``integer``) within the bounds; its error reads ``must
    be a number of <unit> in (0, 86400]`` (or ``>= 0``, ``<= 1``, ...). unit: ``seconds``,
    ``metres``, ... as the message names it."""
    kind = ("an integer" if integer else "a number") + (f" of {unit}" if unit else "")
    low = ge if gt is None else gt
    if low is not None and le is not None:
        bound = f" in {'[' if gt is None else '('}{low:g}, {le:g}]"
    elif low is not None:
        bound = f" {'>=' if gt is None else '>'} {low:g}"
    else:
        bound = f" <= {le:g}" if le is not None else ""
    base = int if integer else Annotated[float, Field(allow_inf_nan=False)]
    return Annotated[base, Field(ge=ge, gt=gt, le=le), reworded(f"must be {kind}{bound}")]


def text(what: str = "a string") -> Any:
    """A non-empty string, stripped; its error reads ``must be <what> (a non-empty string)``."""
    return Annotated[
        str,
        StringConstraints(strip_whitespace=True, min_length=1),
        reworded(f"must be {what} (a non-empty string)"),
    ]


def variant(model: type[BaseModel], name: str) -> Any:
    """``model`` as the variant ``name`` of a discriminated union (its tag is left out of
    error locations)."""
    return Annotated[model, Tag(_TAG.format(name))]


def variant_tag(name: str | None) -> str | None:
    """The tag of variant ``name`` (for a union's discriminator function)."""
    return None if name is None else _TAG.format(name)


# ---------------------------------------------------------------------------- sections
@dataclasses.dataclass(frozen=True)
class _Unknown:
    """The value of an unknown key, with the fields it could have meant."""

    value: Any
    names: tuple[str, ...]

    def reason(self, key: Any, where: str) -> str:
        """``is not a field of <where>``, with the closest field or every one."""
        if not isinstance(key, str):
            choices = ", ".join(sorted(self.names))
            return f"has key {key!r}, not a field name (expected {choices})"
        return f"is not a field of {where}{name_hint(key, self.names)}"


def mark_unknown_keys(model: type[BaseModel], data: Any) -> Any:
    """``data`` with the value of each key that is no field of ``model`` marked, so that
    its ``extra_forbidden`` error can name the closest field (a before-validator's body)."""
    if not isinstance(data, dict):
        return data
    names = tuple(model.model_fields)
    if all(isinstance(key, str) and key in names for key in data):
        return data
    for key in data:
        if not isinstance(key, str):
            raise error((), MISSING, _Unknown(None, names).reason(key, ""))
    return {k: v if k in names else _Unknown(v, names) for k, v in data.items()}


class Section(BaseModel):
    """A mapping of known fields (``mark_unknown_keys``); null reads as empty; frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        return mark_unknown_keys(cls, {} if data is None else data)


class DomainSection(Section):
    """A section mirroring ``domain``, a frozen dataclass, field for field
    (``domain_section`` makes one); ``build()`` makes the domain object."""

    domain: ClassVar[type]
    check: ClassVar[bool] = True

    def build(self) -> Any:
        """The domain object with these values."""
        return self.domain(**self.model_dump())

    @model_validator(mode="after")
    def _check_with_domain_class(self) -> DomainSection:
        if self.check:
            try:
                self.build()
            except ValueError as exc:
                raise located(self, exc) from None
        return self


_FIELD_TYPES: dict[Any, Any] = {
    float: number(),
    int: number(integer=True),
    bool: bool,
    float | None: number() | None,
}


def domain_section(
    domain: type, name: str, doc: str, *, check: bool = True, **defaults: Any
) -> type[DomainSection]:
    """A ``DomainSection`` class ``name`` with the init fields of dataclass ``domain``
    (``float``, ``int``, ``bool`` and ``float | None`` fields), its defaults but for
    ``defaults``. check: validate with the domain class (False: types only)."""
    hints = typing.get_type_hints(domain)
    fields: dict[str, Any] = {}
    for f in dataclasses.fields(domain):
        if f.init:
            default = defaults.get(f.name, f.default)
            required = default is dataclasses.MISSING
            fields[f.name] = (_FIELD_TYPES[hints[f.name]], ... if required else default)
    module = sys._getframe(1).f_globals["__name__"]  # so that instances pickle
    model = create_model(name, __base__=DomainSection, __doc__=doc, __module__=module, **fields)
    model.domain = domain
    model.check = check
    return model


def located(model: BaseModel, exc: ValueError) -> ValidationError:
    """A domain error as a validation error at the field it names.

    A ``FieldError`` carries its field (``p_hit``, ``decay.fade_bound``); when that is a
    field of ``model`` the error is placed there with its reason and value, else on
    ``model`` with the whole message, as is any other ``ValueError``.
    """
    if not isinstance(exc, FieldError):
        return error((), MISSING, str(exc))
    value: Any = model
    loc: tuple[str, ...] = ()
    for part in exc.field.split("."):
        if not isinstance(value, BaseModel) or part not in type(value).model_fields:
            return error((), MISSING, str(exc))
        value, loc = getattr(value, part), (*loc, part)
    return error(loc, exc.value, exc.reason)


# ---------------------------------------------------------------------------- errors
class Problem(NamedTuple):
    """One validation problem: where (``loc``), what is wrong, and the value (MISSING:
    none to show)."""

    loc: Loc
    reason: str
    value: Any

    def detail(self) -> str:
        """``reason, got value`` (the reason alone without a value)."""
        if self.value is MISSING or "got " in self.reason:
            return self.reason
        return f"{self.reason}, got {short_repr(self.value)}"


_REASONS = {
    "missing": "is required",
    "model_type": "must be a mapping",
    "dict_type": "must be a mapping",
    "list_type": "must be a list",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
    "string_type": "must be a string",
}


def problems(
    exc: ValidationError, root: str, hidden: Callable[[Loc], bool] = lambda loc: False
) -> list[Problem]:
    """Each error of ``exc`` as a Problem: unknown keys first (a typo explains what else
    is missing), then in pydantic's order. root: what the top level is called
    (``scenario``); union tags are left out of locations; ``hidden(loc)``: never show the
    value there (secrets)."""
    unknown, out = [], []
    for item in exc.errors():
        loc = tuple(p for p in item["loc"] if not (isinstance(p, str) and _is_tag(p)))
        kind = item["type"]
        value = item.get("input", MISSING)
        if isinstance(value, _Unknown):  # extra_forbidden
            unknown.append(Problem(loc, value.reason(loc[-1], dotted(loc[:-1], root)), MISSING))
            continue
        if kind in _REASONS:
            reason = _REASONS[kind]
        elif kind == "value_error":
            reason = str(item["ctx"]["error"])
        else:
            reason = item["msg"]
        if kind == "missing" or hidden(loc):
            value = MISSING
        out.append(Problem(loc, reason, value))
    return unknown + out


def _is_tag(part: str) -> bool:
    return part.startswith("<") and part.endswith(">")
