"""The names a scan body may hold (docs/http-api.md 2.1), checked at the API: a key that
is no field of a scan is refused (422) with the nearest field it could have meant
(``pose_sdt: not a field of a scan; did you mean 'pose_std'?``), so a typo never drops
what it carried (a misspelt ``pose_std`` would be fused as a sure pose).

The names are those of the documented wire models (``schemas.ScanIn``, ``PoseIn``,
``PoseStdIn``, ``ScanBatchIn``). The check is the API's, not ``Scan.from_dict``'s: that
one reads journal records and recordings too, which must open as they were written.
A binary body (docs/scan-binary.md) holds no names; its one way to carry a field this
server does not know, a flag bit, is refused by ``scan_binary`` alike.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel

from mapserver.api.schemas import PoseIn, PoseStdIn, ScanBatchIn, ScanIn
from mapserver.core.text import MAX_ID_CHARS, name_hint, quote, text_problem

NESTED: tuple[tuple[str, type[BaseModel], str], ...] = (
    ("pose", PoseIn, "a pose"),
    ("pose_std", PoseStdIn, "pose_std"),
)
"""The scan's fields that are objects: (name, their model, what a message calls one)."""


def unknown_scan_field(item: Any) -> str | None:
    """``NAME: not a field of a scan; did you mean 'X'?`` for the first key of scan
    mapping ``item`` (or of its ``pose``, ``pose_std``) that the format does not define;
    None when every key is known or ``item`` is no mapping (``Scan.from_dict`` says
    what is wrong with it then)."""
    if not isinstance(item, Mapping):
        return None
    found = [unknown_field(item, ScanIn, "a scan")]
    found += [
        unknown_field(item[name], model, what, f"{name}.")
        for name, model, what in NESTED
        if isinstance(item.get(name), Mapping)
    ]
    return next((problem for problem in found if problem is not None), None)


def unknown_field(data: Mapping, model: type[BaseModel], what: str, prefix: str = "") -> str | None:
    """The first key of ``data`` that is no field of ``model``, as ``PREFIX + KEY: not a
    field of WHAT`` and the nearest field (``name_hint``); None when there is none."""
    names = model.model_fields
    for key in data:
        if key in names:
            continue
        if isinstance(key, str) and text_problem(key, MAX_ID_CHARS) is None:
            return f"{prefix}{key}: not a field of {what}{name_hint(key, names)}"
        return f"{prefix}{quote(key)}: not a field of {what} (expected one of {', '.join(names)})"
    return None


def unknown_batch_field(body: Any) -> str | None:
    """As ``unknown_field`` for a batch body's own keys (only ``scans``)."""
    return unknown_field(body, ScanBatchIn, "a batch") if isinstance(body, Mapping) else None
