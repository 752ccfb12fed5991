"""The root of fleetmap's errors and the error of one bad field.

Every exception fleetmap raises on purpose derives from ``FleetmapError``, so a caller can
catch them all apart from bugs. ``FieldError`` carries what is wrong as attributes, the
field (dotted, e.g. ``decay.fade_bound``), the value and the reason, so code that reports
it (settings, the API, scenario files) places it without reading its message.
"""

from __future__ import annotations

from typing import Any


class FleetmapError(Exception):
    """The root of every error fleetmap raises on purpose."""


class FieldError(FleetmapError, ValueError):
    """``field`` holds ``value``, which is wrong for ``reason``.

    The message reads ``field reason, got value`` (e.g. ``p_hit must be greater than the
    prior (0.5), got 0.3``); ``reason`` alone is ``must be greater than the prior (0.5)``.
    """

    def __init__(self, field: str, value: Any, reason: str) -> None:
        self.field = field
        self.value = value
        self.reason = reason
        super().__init__(f"{field} {reason}, got {value!r}")

    @property
    def detail(self) -> str:
        """``reason, got value``: the message without the field's name."""
        return f"{self.reason}, got {self.value!r}"


def dotted(path: tuple[str | int, ...], root: str = "") -> str:
    """A field's place as text: ``("events", 1, "at")`` -> ``events[1].at``; ``()`` -> ``root``."""
    text = ""
    for part in path:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text or root
