"""Reading JSON request bodies (400 when not JSON; the size and time bounds are
``guards.BodyMiddleware``'s).

Bodies are strict JSON in UTF-8, plus ``Infinity``/``-Infinity``/``NaN`` (which the
contract allows in ``ranges``). Two readers (``mapserver.json_text``): orjson, and
Python's ``json`` for what orjson refuses (those numbers, and a ``\\uD800`` escape that
leaves a lone surrogate in a string).
Both read a body the same way: the fallback takes the bytes as strict UTF-8, as orjson
does (no byte order mark, no UTF-16, no surrogates encoded as bytes: 400), and a string
holding a lone surrogate from an escape is left for the field's rule to refuse by name
(``mapserver.core.text``: 422, the value quoted).

Refused with 400 naming the problem: nesting deeper than ``MAX_DEPTH`` (the API's
deepest body, a unit's path, nests 4 levels; a 1,000-deep one would only exhaust the
validators' recursion) and integers beyond the float range (no
field of the API holds one; as a float such a number would be infinite). An integer
wider than 64 bits but within the float range is read as the nearest float (orjson's
reading; every number the API takes is a float).
"""

from __future__ import annotations

from typing import Any, TypeVar

import numpy as np
from fastapi import HTTPException, Request
from fastapi.exceptions import RequestValidationError
from numba import njit
from pydantic import BaseModel, ValidationError

from mapserver import json_text

Model = TypeVar("Model", bound=BaseModel)
MAX_DEPTH = 32  # levels of arrays and objects


async def read_json(request: Request) -> Any:
    """The request's JSON body (400 naming the problem when it is not usable JSON)."""
    return parse_json(await request.body())


async def read_model(request: Request, model: type[Model]) -> Model:
    """The request's JSON body as ``model`` (400 when not JSON; 422 naming the field,
    as FastAPI's own validation answers, when it does not fit the model)."""
    body = await read_json(request)
    try:
        return model.model_validate(body)
    except ValidationError as exc:
        raise RequestValidationError(exc.errors(include_url=False)) from None


def parse_json(raw: bytes) -> Any:
    """``raw`` as JSON (see the module docstring); HTTPException 400 when not."""
    too_deep = HTTPException(400, f"body: JSON nested deeper than {MAX_DEPTH} levels")
    try:
        value = json_text.loads(raw)
    except json_text.TooDeep:
        raise too_deep from None
    except ValueError as exc:  # UnicodeDecodeError and JSONDecodeError among them
        raise HTTPException(400, f"body: not valid JSON ({exc})") from None
    # Fewer brackets than the limit cannot nest past it (a scan has five): scan only if not.
    if raw.count(b"[") + raw.count(b"{") > MAX_DEPTH and _nesting(raw) > MAX_DEPTH:
        raise too_deep
    return value


def _nesting(raw: bytes) -> int:
    """How many levels of arrays and objects the valid JSON text ``raw`` nests."""
    return int(_nesting_kernel(np.frombuffer(raw, dtype=np.uint8)))


@njit(cache=True, nogil=True)
def _nesting_kernel(text):
    """Deepest bracket level of valid JSON bytes, brackets inside strings not counted
    (one pass; a Python walk of a 100,000-point body's lists took 0.2 s of the loop)."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in text:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 92:  # backslash
                escaped = True
            elif byte == 34:  # closing quote
                in_string = False
        elif byte == 34:
            in_string = True
        elif byte == 91 or byte == 123:  # [ {
            depth += 1
            deepest = max(deepest, depth)
        elif byte == 93 or byte == 125:  # ] }
            depth -= 1
    return deepest


def body_schema(model: type, binary_type: str | None = None) -> dict[str, Any]:
    """``openapi_extra`` for a route that reads its body itself: it takes ``model`` as JSON
    (and, with ``binary_type``, the binary scan encoding of docs/scan-binary.md)."""
    content: dict[str, Any] = {
        "application/json": {"schema": {"$ref": f"#/components/schemas/{model.__name__}"}}
    }
    if binary_type is not None:
        content[binary_type] = {
            "schema": {
                "type": "string",
                "format": "binary",
                "description": "fixed little-endian header, float32 ranges: docs/scan-binary.md",
            }
        }
    return {"requestBody": {"required": True, "content": content}}
