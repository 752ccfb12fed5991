"""``report.png``'s map-against-truth panel: phantom and forgotten cells [cells] (left
axis) and the unknown share of the reachable floor [%] (right axis) at every map read
(``record.map_truth``, ``scenarios.score.map_truth``), over sim time [s]."""

from __future__ import annotations

from matplotlib.axes import Axes

from scenarios.run.record import RunRecord

PHANTOM_CELLS_COLOR = "#d62728"
FORGOTTEN_CELLS_COLOR = "#9467bd"
UNKNOWN_SHARE_COLOR = "#7f7f7f"


def draw_map_truth(ax: Axes, record: RunRecord, end: float) -> Axes | None:
    """Draw the panel on ``ax`` up to ``end`` [s]; returns the right (share) axis, or None
    when the run has no map read (the panel then says so)."""
    ax.set_title("shared map against ground truth, at every map read")
    ax.set_xlim(0.0, max(end, 1.0))
    ax.set_xlabel("sim time [s]")
    samples = sorted(record.map_truth, key=lambda s: s.stamp)
    if not samples:
        ax.text(0.5, 0.5, "no map reads", ha="center", va="center", transform=ax.transAxes)
        return None
    stamps = [s.stamp for s in samples]
    ax.plot(stamps, [s.phantom_cells for s in samples], color=PHANTOM_CELLS_COLOR,
            label="phantom cells")  # fmt: skip
    ax.plot(stamps, [s.forgotten_cells for s in samples], color=FORGOTTEN_CELLS_COLOR,
            label="forgotten cells")  # fmt: skip
    ax.set_ylabel("cells")
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    share = ax.twinx()
    share.plot(stamps, [100.0 * s.unknown_share for s in samples], color=UNKNOWN_SHARE_COLOR,
               linestyle="--", label="unknown, of reachable floor")  # fmt: skip
    share.set_ylabel("unknown [% of reachable floor]")
    share.set_ylim(0.0, 100.0)
    lines = ax.get_lines() + share.get_lines()
    ax.legend(lines, [line.get_label() for line in lines], loc="upper right", fontsize=8)
    return share
