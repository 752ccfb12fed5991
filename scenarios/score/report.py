"""``report.png``: one picture of a run for people.

- Left, the final shared costmap (Nav2 costs: white free, shades of violet graded and
  inscribed, black lethal, grey unknown) with every freeze where the unit stood (red X
  for its phantom seconds, blue circle for its true-block seconds, each sized by those
  seconds: a freeze split in time has both), every world event (green triangle,
  labelled E1, E2, ... in time order; a moved object also where it stood, a hollow
  triangle with a dashed arrow to its new place) and every collision incident where the unit first
  touched (orange star: the fleet's, yellow diamond: the scenario's; ``fleet.sim``,
  ``scenarios.score.incidents``).
- Top right, a timeline per unit [s]: each freeze's segments as bars (red phantom, blue
  true block), events as dashed green lines under the same labels, collision incidents
  as the same stars and diamonds at their start on the unit's row, with a line on to
  their end.
- Middle right, the shared map against ground truth at every map read: phantom and
  forgotten cells, and the unknown share of the reachable floor
  (``scenarios.score.report_map_truth``).
- Bottom right, time to clear [s] per removed (or moved) object, in removal order; one
  never cleared gets a hatched bar from its removal to the end of the run, "never"; and
  beside it a table of the throughput metrics (docs/throughput.md; "n/a" where a mean
  has nothing to average).
- The title names the scenario, policy and seed, and the key metrics (``collisions``: the
  fleet's, followed by the scenario's when there were any); one legend for all panels
  runs along the bottom.

Drawn with matplotlib's object API on an Agg canvas: no display, no global pyplot state
(safe in sweep worker processes).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, MAX_GRADED, UNKNOWN
from mapserver.store.atomic import atomic_output
from planner.freeze import PHANTOM, TRUE_BLOCK
from scenarios.run.record import EventRecord, ObjectState, RunRecord
from scenarios.score.metric_registry import View, shown_in
from scenarios.score.report_map_truth import draw_map_truth

FIGURE_INCHES = (16.0, 9.0)
DPI = 100  # -> 1600 x 900 px
TITLE_FIT_CHARS = 170  # a title line longer than this is set smaller, to fit the width
PHANTOM_COLOR = "#d62728"
TRUE_BLOCK_COLOR = "#1f77b4"
EVENT_COLOR = "#2ca02c"
CLEARED_COLOR = "#17becf"
NEVER_COLOR = "#7f7f7f"
# CollisionEvent.cause -> (colour, marker, size [pt^2], legend label)
COLLISION_STYLE = {
    "fleet": ("#ff7f0e", "*", 220.0, "collision, fleet"),
    "scenario": ("#ffd92f", "D", 80.0, "collision, scenario"),
}

REMOVAL_KINDS = ("remove", "move")  # events after which an object's old place must clear

TABLE_ROW_SCALE = 1.3  # row height of the throughput table, in table rows of the font
TABLE_FULL_ROWS = 11  # rows that fit at TABLE_ROW_SCALE; more are squeezed into their height


def write_report(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Draw ``record`` as ``report.png`` (1600 x 900 px) at ``path`` atomically."""
    figure = Figure(figsize=FIGURE_INCHES, dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)
    grid = figure.add_gridspec(3, 2, width_ratios=(1.15, 1.0), height_ratios=(1.1, 0.8, 1.0))
    end = run_end(record)
    _draw_map(figure.add_subplot(grid[:, 0]), record)
    _draw_timeline(figure.add_subplot(grid[0, 1]), record, end)
    draw_map_truth(figure.add_subplot(grid[1, 1]), record, end)
    bottom = grid[2, 1].subgridspec(1, 2, width_ratios=(1.6, 1.0))
    _draw_time_to_clear(figure.add_subplot(bottom[0, 0]), record, end)
    _draw_throughput(figure.add_subplot(bottom[0, 1]), record)
    text = title(record)
    longest = max(len(line) for line in text.split("\n"))
    figure.suptitle(
        text, fontsize=13 if longest <= TITLE_FIT_CHARS else 13 * TITLE_FIT_CHARS / longest
    )
    _legend(figure, record)
    with atomic_output(path) as f:
        figure.savefig(f, format="png", dpi=DPI)
    return Path(path)


def title(record: RunRecord) -> str:
    """Two lines: scenario, policy and seed; then the key metrics that the record has."""
    head = f"{record.scenario}  |  policy {record.policy}  |  seed {record.seed}"
    shown = []
    for m in shown_in(View.REPORT_TITLE):  # the metric registry's, in its order
        if m.number(record.metrics) is not None:
            value = m.text(m.stored(record.metrics))
            shown.append(f"{m.title} {value}" + _scenario_share(record, m.key))
    return head + ("\n" + "  ·  ".join(shown) if shown else "")


def _scenario_share(record: RunRecord, key: str) -> str:
    """After the fleet's ``collisions``: the scenario's, when there were any."""
    extra = record.metrics.get("scenario_collisions")
    if key != "collisions" or not isinstance(extra, int) or isinstance(extra, bool) or not extra:
        return ""
    return f" (+{extra} scenario)"


def run_end(record: RunRecord) -> float:
    """[s] the last moment the run covers: ``sim_seconds`` or the latest stamp recorded."""
    stamps = [0.0]
    sim_seconds = record.metrics.get("sim_seconds")
    if isinstance(sim_seconds, int | float):
        stamps.append(float(sim_seconds))
    stamps += [f.start + f.duration for f in record.freezes]
    stamps += [i.end for i in record.incidents]
    streams = (record.units, record.events, record.grids, record.plans, record.scans,
               record.map_truth)  # fmt: skip
    for stream in streams:
        if stream:
            stamps.append(max(s.stamp for s in stream))
    return max(stamps)


def cost_colormap() -> ListedColormap:
    """256 colours indexed by Nav2 cost (see the module docstring)."""
    table = np.ones((256, 4))
    graded = np.linspace(0.0, 1.0, int(MAX_GRADED))[:, None]
    light, dark = np.array([0.95, 0.93, 0.99, 1.0]), np.array([0.66, 0.58, 0.82, 1.0])
    table[1 : int(MAX_GRADED) + 1] = light + graded * (dark - light)
    table[int(FREE)] = (1.0, 1.0, 1.0, 1.0)
    table[int(INSCRIBED)] = (0.45, 0.36, 0.62, 1.0)
    table[int(LETHAL)] = (0.08, 0.08, 0.10, 1.0)
    table[int(UNKNOWN)] = (0.78, 0.78, 0.78, 1.0)
    return ListedColormap(table, name="nav2_costs")


def _draw_map(ax: Axes, record: RunRecord) -> None:
    g = record.geometry
    xmin, ymin, xmax, ymax = g.bounds
    if record.grids:
        final = max(record.grids, key=lambda s: s.stamp)
        ax.imshow(
            final.costs,
            cmap=cost_colormap(),
            vmin=0,
            vmax=255,
            origin="lower",
            extent=(xmin, xmax, ymin, ymax),
            interpolation="nearest",
        )
        ax.set_title(f"final costmap at {final.stamp:.1f} s, freezes, events and collisions")
    else:
        ax.text(0.5, 0.5, "no map recorded", ha="center", va="center", transform=ax.transAxes)
        ax.set_title("freezes, events and collisions")
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    for kind in (PHANTOM, TRUE_BLOCK):
        group = [f for f in record.freezes if f.seconds(kind) > 0]
        ax.scatter(
            [f.x for f in group],
            [f.y for f in group],
            s=[_marker_area(f.seconds(kind)) for f in group],
            c=_FREEZE_STYLE[kind][0],
            marker=_FREEZE_STYLE[kind][1],
            edgecolors="white",
            linewidths=1.0,
            zorder=4,
        )
    events = _numbered_events(record)
    ax.scatter(
        [e.x for _, e in events],
        [e.y for _, e in events],
        s=90,
        c=EVENT_COLOR,
        marker="^",
        edgecolors="black",
        linewidths=0.6,
        zorder=3,
    )
    for label, event in events:
        ax.annotate(
            f"{label} {event.kind} {event.object_id}",
            (event.x, event.y),
            xytext=(6, 6),
            textcoords="offset points",
            fontsize=8,
            zorder=5,
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": EVENT_COLOR, "alpha": 0.85},
        )
    for cause, group in _collisions_by_cause(record):
        _scatter_collisions(ax, cause, [c.x for c in group], [c.y for c in group])
    _draw_moves(ax, record, events)


def _draw_moves(ax: Axes, record: RunRecord, events: list[tuple[str, EventRecord]]) -> None:
    """Where each moved object stood before its move: a hollow event triangle labelled
    ``E1 pod-9 stood here``, and a dashed arrow from there to the event's triangle at its
    new place (none for a move whose object the run did not record before it)."""
    for label, event in events:
        before = _place_before(record, event) if event.kind == "move" else None
        if before is None:
            continue
        ax.annotate("", xy=(event.x, event.y), xytext=(before.x, before.y), zorder=3,
                    arrowprops={"arrowstyle": "->", "color": EVENT_COLOR, "linestyle": "--",
                                "linewidth": 1.4, "shrinkA": 6, "shrinkB": 6})  # fmt: skip
        ax.scatter([before.x], [before.y], s=90, marker="^", facecolors="none",
                   edgecolors=EVENT_COLOR, linewidths=1.6, zorder=3)  # fmt: skip
        ax.annotate(f"{label} {event.object_id} stood here", (before.x, before.y),
                    xytext=(6, -14), textcoords="offset points", fontsize=8, zorder=5,
                    bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": EVENT_COLOR,
                          "alpha": 0.85, "linestyle": "--"})  # fmt: skip


def _place_before(record: RunRecord, event: EventRecord) -> ObjectState | None:
    """The ``ObjectState`` of ``event``'s object in the last objects sample before the
    event (None when no sample holds it)."""
    earlier = [s for s in record.objects if s.stamp < event.stamp - 1e-9]
    for sample in sorted(earlier, key=lambda s: s.stamp, reverse=True):
        for state in sample.objects:
            if state.object_id == event.object_id:
                return state
    return None


def _collisions_by_cause(record: RunRecord) -> list[tuple[str, list]]:
    """The run's collision incidents by cause (``COLLISION_STYLE`` order; unknown causes
    drawn as the fleet's)."""
    groups: dict[str, list] = {cause: [] for cause in COLLISION_STYLE}
    for c in record.incidents:
        groups[c.cause if c.cause in COLLISION_STYLE else "fleet"].append(c)
    return list(groups.items())


def _scatter_collisions(ax: Axes, cause: str, xs: list[float], ys: list[float]) -> None:
    color, marker, size, _ = COLLISION_STYLE[cause]
    ax.scatter(xs, ys, s=size, c=color, marker=marker, edgecolors="black", linewidths=0.8, zorder=6)


def _numbered_events(record: RunRecord) -> list[tuple[str, EventRecord]]:
    """The events in time order, labelled E1, E2, ... (the same labels in both panels)."""
    events = sorted(record.events, key=lambda e: e.stamp)
    return [(f"E{i}", event) for i, event in enumerate(events, start=1)]


# kind -> (colour, marker)
_FREEZE_STYLE = {PHANTOM: (PHANTOM_COLOR, "X"), TRUE_BLOCK: (TRUE_BLOCK_COLOR, "o")}


def _legend(figure: Figure, record: RunRecord) -> None:
    """One legend for all panels, along the bottom: freezes, events, and the cost colours."""
    phantom = sum(1 for f in record.freezes if f.phantom)
    true = sum(1 for f in record.freezes if f.true_block)
    handles: list[Artist] = [
        Line2D(
            [],
            [],
            color=PHANTOM_COLOR,
            marker="X",
            markersize=10,
            linestyle="none",
            label=f"phantom freeze ({phantom})",
        ),
        Line2D(
            [],
            [],
            color=TRUE_BLOCK_COLOR,
            marker="o",
            markersize=9,
            linestyle="none",
            label=f"true-block freeze ({true})",
        ),
        Line2D(
            [],
            [],
            color=EVENT_COLOR,
            marker="^",
            markersize=9,
            linestyle="--",
            label=f"event ({len(record.events)})",
        ),
    ]
    for cause, group in _collisions_by_cause(record):
        color, marker, size, label = COLLISION_STYLE[cause]
        handles.append(
            Line2D(
                [],
                [],
                color=color,
                marker=marker,
                markeredgecolor="black",
                markersize=12 if marker == "*" else 8,
                linestyle="none",
                label=f"{label} ({len(group)})",
            )
        )
    colors = cost_colormap().colors
    for cost, label in (
        (FREE, "free"),
        (MAX_GRADED // 2, "inflated"),
        (INSCRIBED, "inscribed"),
        (LETHAL, "lethal"),
        (UNKNOWN, "unknown"),
    ):
        handles.append(Patch(facecolor=colors[int(cost)], edgecolor="0.5", label=label))
    figure.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=10)


def _marker_area(seconds: float) -> float:
    """[pt^2] a freeze's marker for ``seconds`` [s] of one kind: 60 for a short one,
    growing with the seconds, at most 400."""
    return min(60.0 + 20.0 * seconds, 400.0)


MAX_UNIT_LABELS = 40
"""The timeline names at most this many units (every k-th of a larger fleet), so the names
stay legible: a row per unit of ``thousand_units`` is under a pixel."""


def _draw_timeline(ax: Axes, record: RunRecord, end: float) -> None:
    units = sorted(
        {u.unit_id for u in record.units}
        | {f.unit_id for f in record.freezes}
        | {c.unit_id for c in record.incidents},
        key=_natural_key,
    )
    row = {unit: i for i, unit in enumerate(units)}
    for freeze in record.freezes:
        for segment in freeze.segments:
            ax.broken_barh(
                [(segment.start, max(segment.duration, end * 2e-3))],
                (row[freeze.unit_id] - 0.35, 0.7),
                facecolors=_FREEZE_STYLE[segment.kind][0],
            )
    for label, event in _numbered_events(record):
        ax.axvline(event.stamp, color=EVENT_COLOR, linestyle="--", linewidth=1.0)
        ax.text(
            event.stamp,
            1.01,
            label,
            ha="center",
            va="bottom",
            fontsize=8,
            color="darkgreen",
            transform=ax.get_xaxis_transform(),
        )
    for cause, group in _collisions_by_cause(record):
        color = COLLISION_STYLE[cause][0]
        for incident in group:
            y = row[incident.unit_id]
            ax.plot([incident.start, incident.end], [y, y], color=color, linewidth=2.5)
        _scatter_collisions(ax, cause, [c.start for c in group], [row[c.unit_id] for c in group])
    if not units:
        ax.text(0.5, 0.5, "no units recorded", ha="center", va="center", transform=ax.transAxes)
    step = max(1, math.ceil(len(units) / MAX_UNIT_LABELS))  # a fleet of hundreds: some
    named = range(0, len(units), step)
    ax.set_yticks(list(named), [units[i] for i in named], fontsize=8 if len(units) > 12 else 9)
    if step > 1:
        ax.set_ylabel(f"{len(units)} units, one in {step} named")
    ax.set_ylim(max(len(units), 1) - 0.5, -0.5)
    ax.set_xlim(0.0, max(end, 1.0))
    ax.set_xlabel("sim time [s]")
    ax.set_title("freezes, events and collisions per unit", pad=16)
    ax.grid(axis="x", alpha=0.3)


def _draw_time_to_clear(ax: Axes, record: RunRecord, end: float) -> None:
    ax.set_title("time to clear per removed object")
    ax.set_ylabel("seconds from removal")
    if not record.time_to_clear:
        ax.text(0.5, 0.5, "no removal events", ha="center", va="center", transform=ax.transAxes)
        ax.set_xticks([])
        return
    removed_at = {  # the last event that took each object from its place
        e.object_id: e.stamp
        for e in sorted(record.events, key=lambda e: e.stamp)
        if e.kind in REMOVAL_KINDS
    }
    objects = sorted(record.time_to_clear, key=lambda o: (removed_at.get(o, 0.0), o))
    finite = [v for v in record.time_to_clear.values() if v is not None]
    for i, obj in enumerate(objects):
        seconds = record.time_to_clear[obj]
        if seconds is None:
            height = end - removed_at[obj] if obj in removed_at else max(finite, default=1.0)
            ax.bar(i, height, color="none", edgecolor=NEVER_COLOR, hatch="//")
            ax.annotate(
                "never",
                (i, height),
                xytext=(0, 3),
                textcoords="offset points",
                ha="center",
                fontsize=9,
                color=NEVER_COLOR,
                fontweight="bold",
            )
        else:
            ax.bar(i, seconds, color=CLEARED_COLOR)
            ax.annotate(
                f"{seconds:.2f} s",
                (i, seconds),
                xytext=(0, 3),
                textcoords="offset points",
                ha="center",
                fontsize=9,
            )
    ax.set_xticks(range(len(objects)), objects, fontsize=9, rotation=30 if len(objects) > 6 else 0)
    ax.margins(y=0.15)
    ax.grid(axis="y", alpha=0.3)


def throughput_rows(record: RunRecord) -> list[tuple[str, str]]:
    """(title, value) rows of the throughput table: the metric registry's, in its order,
    that the record has."""
    table = shown_in(View.REPORT_TABLE)
    return [(m.title, m.text(m.stored(record.metrics))) for m in table if m.present(record.metrics)]


def _draw_throughput(ax: Axes, record: RunRecord) -> None:
    ax.set_axis_off()
    ax.set_title("throughput")
    rows = throughput_rows(record)
    if not rows:
        ax.text(0.5, 0.5, "no throughput metrics", ha="center", va="center")
        return
    table = ax.table(cellText=rows, colWidths=(0.7, 0.3), loc="upper center", edges="horizontal")
    table.auto_set_font_size(False)
    squeeze = min(1.0, TABLE_FULL_ROWS / len(rows))
    table.set_fontsize(9 if squeeze == 1.0 else 8)
    table.scale(1.0, TABLE_ROW_SCALE * squeeze)
    for (_, col), cell in table.get_celld().items():
        cell.set_text_props(ha="left" if col == 0 else "right")


def _natural_key(text: str) -> list[int | str]:
    """Sort key that puts ``u2`` before ``u10``."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]
