"""Generated Markdown kept in the docs between a begin marker and its end marker (the
README's compare tables, ``scenarios.sweep.readme_tables``; the metric lists,
``scenarios.score.metric_docs``)."""

from __future__ import annotations

import re


def marked_blocks(
    text: str, begin: re.Pattern[str], end: str
) -> list[tuple[re.Match[str], int, int]]:
    """Each match of ``begin`` in ``text`` (a pattern of a whole line), with the offsets
    of the text between the line after it and its end marker, ``end`` formatted with the
    match's named groups (``"<!-- x:end {name} -->"``); ValueError naming the end marker
    missing after a begin marker."""
    found = []
    for match in begin.finditer(text):
        marker = end.format(**match.groupdict())
        stop = text.find(marker, match.end())
        if stop < 0:
            raise ValueError(f"no {marker!r} after {match.group(0).strip()!r}")
        found.append((match, match.end() + 1, stop))
    return found
