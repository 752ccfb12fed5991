"""What every recording reader is: options, the ``Recording`` interface, its error.

A reader turns one recording (a ROS bag, a CARMEN log, a scan file) into
``mapserver.core.scan.Scan`` objects in the map frame, in stamp order, streamed: a
recording larger than memory is read one message at a time, and iterating a
``Recording`` again reads it again from the start.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from mapserver.core.errors import FleetmapError
from mapserver.core.scan import Pose2D, Scan
from mapserver.core.text import MAX_ID_CHARS


class RecordingError(FleetmapError, ValueError):
    """A recording cannot be read as asked; the message names the file and what to change."""


@dataclass(frozen=True)
class RecordingOptions:
    """How to read a recording.

    - ``topic``: the LaserScan topic of a bag (None: the only one it has);
    - ``fixed_frame``: the frame the map is built in (a bag's /tf chain starts there);
    - ``pose_topic``: take poses from this Odometry / PoseStamped /
      PoseWithCovarianceStamped topic instead of /tf;
    - ``fixed_sensor``: the sensor stood still at this pose (no poses in the recording);
      used only when given;
    - ``start`` / ``end`` [s]: read only scans this long after the recording's first
      message (None: from the first / to the last);
    - ``unit_id``: the id the scans carry (None: the reader's choice, e.g. the file's name).
    """

    topic: str | None = None
    fixed_frame: str = "map"
    pose_topic: str | None = None
    fixed_sensor: Pose2D | None = None
    start: float | None = None
    end: float | None = None
    unit_id: str | None = None

    def __post_init__(self) -> None:
        for name in ("start", "end"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise RecordingError(f"--{name} must be seconds >= 0, got {value!r}")
        if self.start is not None and self.end is not None and self.end < self.start:
            raise RecordingError(f"--end ({self.end} s) is before --start ({self.start} s)")

    def within(self, offset: float) -> bool:
        """Whether a message ``offset`` [s] after the recording's first one is read."""
        return (self.start is None or offset >= self.start) and (
            self.end is None or offset <= self.end
        )


RECORDING_SUFFIXES = (".gz", ".log", ".clf", ".gfs", ".bag", ".mcap", ".db3", ".jsonl")
"""Suffixes ``unit_id_from_path`` drops from a file's name."""


def unit_id_from_path(path: Path) -> str:
    """A unit id from a recording's file or folder name (``intel-corrected.log.gz`` ->
    ``intel-corrected``): its recording suffixes dropped, every character that is not
    printable or is a separator other than the space made ``_``, cut to MAX_ID_CHARS
    (the id rule of ``mapserver.core.text``); ``recording`` when nothing is left."""
    name = Path(path).name
    while (suffix := Path(name).suffix.lower()) in RECORDING_SUFFIXES and suffix:
        name = name[: -len(suffix)]
    clean = "".join(c if c.isprintable() else "_" for c in name).strip()
    return clean[:MAX_ID_CHARS].strip() or "recording"


class Recording(ABC):
    """One recording opened for reading; iterate it for its scans (again: from the start)."""

    def __init__(self, path: Path, options: RecordingOptions) -> None:
        self.path = Path(path)
        self.options = options

    @abstractmethod
    def __iter__(self) -> Iterator[Scan]:
        """The scans in stamp order, in the map frame, within ``options.start/end``."""

    @abstractmethod
    def scan_count(self) -> int | None:
        """How many scans iterating yields at most (for a progress bar), or None when
        the recording cannot tell without reading it all."""

    @abstractmethod
    def describe(self) -> str:
        """One line for the user: the format, and what is read (topic, frames)."""

    def unit_id(self) -> str:
        """The unit id of the scans: ``options.unit_id``, else one from the file's name."""
        return self.options.unit_id or unit_id_from_path(self.path)

    def duration(self) -> float | None:
        """[s] an estimate of the time from the first to the last scan (the recording's
        own index, e.g. a bag's metadata), or None when it cannot tell without reading
        it all. ``fleetmap import`` uses it to stamp a fast replay in the past."""
        return None
