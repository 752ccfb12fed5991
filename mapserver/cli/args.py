"""Argument types and the parser class shared by every ``fleetmap`` command.

``CommandParser`` reads a value that starts with a minus sign followed by a digit
(``--origin -12,-25``, ``--start -3.5,2``) as a value, as written, where argparse alone
takes ``-12,-25`` for an unknown option. No fleetmap option looks like a negative number,
so nothing is lost.
"""

from __future__ import annotations

import argparse
import re

NEGATIVE_VALUE = re.compile(r"^-\.?\d")
"""What argparse must read as a value, never as an option: ``-`` then a digit or ``.5``."""


class CommandParser(argparse.ArgumentParser):
    """An ArgumentParser whose arguments may start with a negative number (``-12,-25``);
    its subparsers are CommandParsers too (argparse makes them of the parent's type)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_VALUE


def xy_pair(text: str) -> tuple[float, float]:
    """argparse type for ``X,Y`` [m] (negative values as written: ``-12,-25``)."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}") from None
    return x, y
