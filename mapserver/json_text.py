"""Reading JSON text as the map server reads it, wherever it comes from (a request body,
a journal record's header).

orjson reads it (strict JSON in UTF-8, ten times faster than ``json`` on 1,080 floats);
what orjson refuses goes to Python's ``json`` made to read as orjson does
(``read_fallback``): strict UTF-8 (no byte order mark, no UTF-16, no surrogates encoded
as bytes), integers wider than 64 bits as the nearest float, integers beyond the float
range refused, and what only ``json`` takes: ``Infinity``/``-Infinity``/``NaN`` and a
lone surrogate left in a string by a ``\\uD800`` escape (for the field's rule to refuse
by name, ``mapserver.core.text``). Every number the server takes is a float, so the two
readers give the same scans.
"""

from __future__ import annotations

import json
import sys
from typing import Any

import orjson

from mapserver.core.errors import FleetmapError

FLOAT_MAX = sys.float_info.max


class TooDeep(FleetmapError, ValueError):
    """The text nests arrays and objects deeper than a reader can follow."""


def loads(raw: bytes) -> Any:
    """``raw`` as JSON (module docstring); TooDeep when it nests deeper than orjson's
    limit (1,024 levels) or Python's recursion, else ValueError (a UnicodeDecodeError or
    JSONDecodeError) when neither reader takes it."""
    try:
        return orjson.loads(raw)
    except orjson.JSONDecodeError as exc:
        if "depth limit" in str(exc):
            raise TooDeep(str(exc)) from None
    try:
        return read_fallback(raw)
    except RecursionError:
        raise TooDeep("nested beyond Python's recursion limit") from None


def read_fallback(raw: bytes) -> Any:
    """``raw`` read by Python's ``json`` as orjson reads it (strict UTF-8, integers beyond
    64 bits as floats), plus ``Infinity``/``NaN`` and lone surrogates from ``\\u``
    escapes; ValueError (a UnicodeDecodeError or JSONDecodeError) when it is not JSON."""
    return json.loads(raw.decode("utf-8"), parse_int=_float_range_int)


def _float_range_int(text: str) -> int | float:
    """A JSON integer, refused (ValueError) beyond the float range; wider than 64 bits,
    the nearest float (as orjson reads it)."""
    value = int(text)
    if abs(value) > FLOAT_MAX:
        raise ValueError(f"integer {text[:20]}... ({len(text)} digits) is beyond the float range")
    if not -(2**63) <= value < 2**64:
        return float(value)
    return value
