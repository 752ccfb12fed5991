"""The one rule for the strings the API stores or echoes (unit ids, a unit state's
``reason``, a plan's ``unit_id``), and bounded quoting of any value in a message.

A string is *clean* when it

- holds between 1 and ``max_chars`` characters (code points; 64 for an identifier,
  ``MAX_ID_CHARS``, the unit board's limit) and is not only whitespace;
- holds printable characters only, as ``str.isprintable`` defines them: no character of
  the Unicode categories "Other" (``Cc`` controls such as NUL, newline or DEL; ``Cs``
  lone surrogates, which no UTF-8 text and no SQLite text can hold; ``Cf`` invisible
  format characters: zero-width spaces and joiners, the byte order mark, the
  bidirectional overrides of "Trojan Source" (CVE-2021-42574); ``Co`` private use;
  ``Cn`` unassigned) and none of the category "Separator" but the ASCII space (``Zl``,
  ``Zp`` line and paragraph separators, ``Zs`` spaces such as U+00A0 no-break space).

So an id reads the same in a log line, a terminal, a 409's message and the viewer as in
the fleet's own files, two ids that look alike differ in a visible character, and one
line of log is one record. Letters, digits, punctuation and symbols of every script are
clean (``"小车-7"``, ``"unité_3"``); an emoji sequence joined by U+200D is not.

A string that is not clean is refused with its field named and its value quoted bounded
(``quote``): a 1 MB id costs a message of a hundred bytes, not a megabyte.
"""

from __future__ import annotations

import difflib
import reprlib
from collections.abc import Iterable
from typing import Any

MAX_ID_CHARS = 64
"""Most characters in an identifier (``unit_id``)."""

QUOTE_CHARS = 60
"""Most characters of a string value quoted in a message (more are elided in the middle)."""

_QUOTE = reprlib.Repr()  # keyword arguments need Python 3.12
_QUOTE.maxlevel, _QUOTE.maxlist, _QUOTE.maxdict = 3, 4, 4
_QUOTE.maxstring = _QUOTE.maxother = QUOTE_CHARS


def quote(value: Any) -> str:
    """A repr of ``value`` for a message, bounded however long it is or however it nests:
    at most about ``QUOTE_CHARS`` characters of a string (its control characters and
    surrogates escaped, as ``repr`` writes them), 4 items of a list or dict, 3 levels."""
    return _QUOTE.repr(value)


def clip(text: str, limit: int = 200) -> str:
    """``text`` cut to at most ``limit`` characters (an ellipsis marks the cut), e.g. an
    exception's message that may carry a value of a request."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def name_hint(name: str, names: Iterable[str]) -> str:
    """What to add after ``NAME: is not a field of X`` for an unknown ``name``: the
    closest of ``names`` (``; did you mean 'count'?``), else them all (`` (expected one of
    a, b)``)."""
    choices = sorted(names)
    close = difflib.get_close_matches(name, choices, n=1)
    return f"; did you mean {close[0]!r}?" if close else f" (expected one of {', '.join(choices)})"


def text_problem(value: Any, max_chars: int = MAX_ID_CHARS) -> str | None:
    """Why ``value`` is not a clean string of at most ``max_chars`` characters (the
    module's rule), as a reason such as ``must be at most 64 characters (got 1048576)``;
    None when it is clean."""
    if not isinstance(value, str) or not value.strip():
        return "must be a non-empty string"
    if len(value) > max_chars:
        return f"must be at most {max_chars} characters (got {len(value)})"
    if not value.isprintable():
        bad = next(c for c in value if not c.isprintable())
        return (
            "must hold printable characters only (no control, format or surrogate "
            f"characters, no separator but the space; U+{ord(bad):04X} at index "
            f"{value.index(bad)})"
        )
    return None
