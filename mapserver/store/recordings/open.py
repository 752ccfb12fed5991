"""``open_recording``: the reader for a path, chosen by what the path is."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from mapserver.store.recordings.base import Recording, RecordingError, RecordingOptions
from mapserver.store.recordings.carmen_log import CarmenLogRecording, is_carmen_log
from mapserver.store.recordings.ros_bag import RosBagRecording, is_bag_file, is_ros2_folder
from mapserver.store.recordings.scan_jsonl import ScanFileRecording

Reader = Callable[[Path, RecordingOptions], Recording]

READERS: list[tuple[str, Callable[[Path], bool], Reader]] = [
    ("scan file (*.jsonl)", lambda p: p.is_file() and p.suffix == ".jsonl", ScanFileRecording),
    ("ROS 2 bag (a folder with metadata.yaml)", is_ros2_folder, RosBagRecording),
    ("ROS bag file (*.bag, *.db3, *.mcap)", is_bag_file, RosBagRecording),
    (
        "CARMEN log (*.log, *.clf, *.gfs, plain or gzip, or by content)",
        is_carmen_log,
        CarmenLogRecording,
    ),
]
"""(what it reads, whether a path is one, the reader), tried in order."""


def open_recording(path: Path | str, options: RecordingOptions | None = None) -> Recording:
    """The recording at ``path`` opened with its reader; RecordingError when the path
    does not exist or no reader knows it (the message lists what is read)."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(
            f"{path}: no such file or folder (give a scan file, a ROS 1 or 2 bag or a CARMEN "
            "log: docs/recordings.md)"
        )
    for _, matches, reader in READERS:
        if matches(path):
            return reader(path, options or RecordingOptions())
    known = "; ".join(what for what, _, _ in READERS)
    raise RecordingError(f"{path}: not a recording fleetmap reads (it reads: {known})")
