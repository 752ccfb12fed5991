"""The verdict as a table: ``report.md`` (Markdown) and ``report.csv``, and the lines the
command prints."""

from __future__ import annotations

import csv
import io
import math

from scenarios.evaluate.measures import Verdict
from scenarios.evaluate.run import Evaluation

COLUMNS = (
    ("map", "map"),
    ("structure_kept", "structure kept"),
    ("ghost_cell_seconds", "ghost cell-s"),
    ("unknown_share", "unknown share"),
    ("occupied_cells", "occupied cells"),
    ("scans_per_s", "scans/s"),
)
"""(CSV column, Markdown heading), in order."""


def _shown(key: str, value: str | float | int) -> str:
    """A table cell: shares to 3 decimals, cell-seconds and speeds whole, NaN as n/a."""
    if isinstance(value, str):
        return value
    if isinstance(value, float) and math.isnan(value):
        return "n/a"
    if key in ("structure_kept", "unknown_share"):
        return f"{value:.3f}"
    return f"{value:,.0f}"


def markdown_table(verdicts: list[Verdict]) -> str:
    """The verdicts as a Markdown table, one row per map."""
    lines = [
        "| " + " | ".join(heading for _, heading in COLUMNS) + " |",
        "|---|" + "---:|" * (len(COLUMNS) - 1),
    ]
    for verdict in verdicts:
        row = verdict.as_row()
        lines.append("| " + " | ".join(_shown(key, row[key]) for key, _ in COLUMNS) + " |")
    return "\n".join(lines) + "\n"


def csv_text(verdicts: list[Verdict]) -> str:
    """The verdicts as CSV (full precision), a header then one row per map."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([key for key, _ in COLUMNS])
    for verdict in verdicts:
        row = verdict.as_row()
        writer.writerow([row[key] for key, _ in COLUMNS])
    return out.getvalue()


def summary(evaluation: Evaluation, source: str) -> str:
    """One paragraph: what was measured, on which grid, how reads were made."""
    g = evaluation.geometry
    return (
        f"{source}: {evaluation.scans} scans, {evaluation.returns} returns over "
        f"{evaluation.duration:.1f} s of recording; grid {g.width} x {g.height} cells of "
        f"{g.resolution} m from ({g.origin_x:g}, {g.origin_y:g}); ghosts read every "
        f"{evaluation.read_every:g} s, seen through = more than {evaluation.margin} cells "
        f"short of a return; {evaluation.wall_s:.1f} s in all."
    )


def markdown_report(evaluation: Evaluation, source: str) -> str:
    """``report.md``: a title, the summary, the table and a pointer to the measures' page."""
    return (
        f"# fleetmap evaluate\n\n{summary(evaluation, source)}\n\n"
        f"{markdown_table(evaluation.verdicts)}\n"
        "Measures: docs/evaluate.md. Picture: evaluate.png.\n"
    )
