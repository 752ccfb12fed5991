"""The docs' lists of run metrics, made from the metric registry
(``scenarios.score.metric_registry``) and kept in the pages between two markers::

    <!-- metrics:begin GROUP -->
    | key | title | unit | better | over seeds | shown in | definition |
    ...
    <!-- metrics:end GROUP -->

``GROUP`` is ``all`` (every metric) or a metric's ``group`` (``throughput``, ``freezes``,
...): a row per metric of it, in the registry's order.

``python -m scenarios.score.metric_docs [FILE...] [--write]`` checks every block of the
files (default: README.md and docs/*.md) against the registry and names each stale one
(exit status 1); with ``--write`` it rewrites them in place (exit status 0).
``tests/scenarios/test_metric_registry.py`` fails while a block is stale.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from scenarios.doc_blocks import marked_blocks
from scenarios.score.metric_registry import REGISTRY, Metric, Registry, View

__all__ = ["ALL", "block_table", "main", "page_files", "rewrite", "stale_blocks"]

ROOT = Path(__file__).resolve().parents[2]
ALL = "all"
BEGIN = re.compile(r"^<!-- metrics:begin (?P<group>[\w-]+) -->$", re.M)
END = "<!-- metrics:end {group} -->"
HEADER = (
    "| key | title | unit | better | over seeds | shown in | definition |\n"
    "|---|---|---|---|---|---|---|\n"
)


def _row(m: Metric) -> str:
    shown = ", ".join(v.value for v in View if v in m.views and v is not View.METRICS_JSON)
    return (
        f"| `{m.key}` | {m.title} | {m.unit.symbol} | {m.better.value} | {m.reduce.value} "
        f"| {shown or '-'} | {m.meaning} |\n"
    )


def block_table(group: str, registry: Registry = REGISTRY) -> str:
    """The Markdown table of ``group``'s metrics (module docstring); ValueError naming a
    group no metric has."""
    rows = [_row(m) for m in registry if group in (ALL, m.group)]
    if not rows:
        groups = ", ".join(dict.fromkeys(m.group for m in registry))
        raise ValueError(f"no metric of group {group!r} (groups: {ALL}, {groups})")
    return HEADER + "".join(rows)


def _blocks(text: str) -> list[tuple[str, int, int]]:
    """(group, start, end) of each block's text between its markers; ValueError for a
    block without its end marker."""
    return [(m["group"], start, end) for m, start, end in marked_blocks(text, BEGIN, END)]


def stale_blocks(text: str, registry: Registry = REGISTRY) -> list[str]:
    """The groups of ``text``'s blocks that differ from the registry."""
    return [g for g, a, b in _blocks(text) if text[a:b] != block_table(g, registry)]


def rewrite(text: str, registry: Registry = REGISTRY) -> str:
    """``text`` with every block made from ``registry``."""
    for group, start, end in reversed(_blocks(text)):  # from the end: offsets stay valid
        text = text[:start] + block_table(group, registry) + text[end:]
    return text


def page_files() -> list[Path]:
    """The pages that may hold blocks: README.md and docs/*.md."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def main(argv: Sequence[str] | None = None) -> int:
    """The command (module docstring)."""
    parser = argparse.ArgumentParser(
        prog="python -m scenarios.score.metric_docs",
        description="Check (or --write) the docs' metric lists against the metric registry.",
    )
    parser.add_argument("files", nargs="*", type=Path, help="default: README.md, docs/*.md")
    parser.add_argument("--write", action="store_true", help="rewrite stale blocks in place")
    args = parser.parse_args(argv)
    status = 0
    for path in args.files or page_files():
        text = path.read_text()
        stale = stale_blocks(text)
        if stale and args.write:
            path.write_text(rewrite(text))
            print(f"{path}: rewrote {', '.join(stale)}")
        elif stale:
            print(f"{path}: stale metrics block(s) {', '.join(stale)}", file=sys.stderr)
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
