"""Recordings in: ROS bags, CARMEN logs and scan files read as scans (docs/recordings.md).

``open_recording(path, options)`` picks the reader; every reader is a ``Recording``
(``base.py``) that streams ``Scan`` objects in the map frame, in stamp order.
"""

from mapserver.store.recordings.base import Recording, RecordingError, RecordingOptions
from mapserver.store.recordings.open import open_recording

__all__ = ["Recording", "RecordingError", "RecordingOptions", "open_recording"]
