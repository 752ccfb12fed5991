"""The binary scan encoding (docs/scan-binary.md): a fixed little-endian header and the
ranges as float32, a quarter of the JSON text's bytes and no number parsing.

Content type ``application/vnd.fleetmap.scan``. A ``POST /v1/scans`` body is one record;
a ``POST /v1/scans/batch`` body is a ``uint32`` count, then that many records. A record:

==========  =======  =====================================================
offset [B]  type     field
==========  =======  =====================================================
0           4 bytes  magic ``FMSC``
4           uint8    format version (``VERSION``, 1)
5           uint8    flags: bit 0 set when ``pose_std`` is given; others 0
6           uint16   unit_id length L [bytes of UTF-8], 1 ..
8           uint32   beam count N
12          float64  stamp [s]
20          float64  pose.x [m], then pose.y [m], pose.yaw [rad]
44          float64  angle_min [rad], angle_increment [rad]
60          float64  range_min [m], range_max [m]
76          float64  pose_std.xy [m], pose_std.yaw [rad] (0 without the flag)
92          L bytes  unit_id, UTF-8
92 + L      N x f32  ranges [m]: REP 117 as in JSON; NaN invalid, +inf no return
==========  =======  =====================================================

``decode_scans`` only takes the record apart: it returns the scans as the mappings of
docs/http-api.md 2.1, which ``Scan.from_dict`` validates as it does a JSON body, so both
encodings are held to the same rules and give the same errors and the same maps.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from typing import Any

import numpy as np

from mapserver.core.errors import FleetmapError
from mapserver.core.scan import MAP_FRAME, Scan

CONTENT_TYPE = "application/vnd.fleetmap.scan"
MAGIC = b"FMSC"
VERSION = 1
FLAG_POSE_STD = 1
HEADER = struct.Struct("<4sBBHI10d")
COUNT = struct.Struct("<I")
RANGE = np.dtype("<f4")


class ScanEncodingError(FleetmapError, ValueError):
    """A binary scan body that cannot be taken apart: ``offset`` [bytes] into the body
    where the problem is, and ``reason``."""

    def __init__(self, offset: int, reason: str) -> None:
        self.offset = offset
        self.reason = reason
        super().__init__(f"body: {reason} (at byte {offset})")


class UnknownFlagError(ScanEncodingError):
    """A record sets a flag bit this version does not define: it announces a field this
    server does not know (the binary form of a JSON key that is no field of a scan)."""


def encode_scan(scan: Scan) -> bytes:
    """One scan as a binary record (its ranges rounded to float32)."""
    unit_id = scan.unit_id.encode()
    std = scan.pose_std
    header = HEADER.pack(
        MAGIC, VERSION, FLAG_POSE_STD if std is not None else 0, len(unit_id), scan.beam_count,
        scan.stamp, scan.pose.x, scan.pose.y, scan.pose.yaw, scan.angle_min,
        scan.angle_increment, scan.range_min, scan.range_max,
        std.xy if std is not None else 0.0, std.yaw if std is not None else 0.0,
    )  # fmt: skip
    return header + unit_id + np.asarray(scan.ranges, dtype=RANGE).tobytes()


def encode_batch(scans: Iterable[Scan]) -> bytes:
    """Scans as a batch body: their count, then their records."""
    records = [encode_scan(scan) for scan in scans]
    return COUNT.pack(len(records)) + b"".join(records)


def decode_scans(body: bytes, batch: bool) -> list[dict[str, Any]]:
    """The scans of a binary body (one record, or a batch when ``batch``) as
    docs/http-api.md 2.1 mappings (``ranges`` a float32 array); ScanEncodingError when the
    bytes do not hold exactly that."""
    offset, count = 0, 1
    if batch:
        if len(body) < COUNT.size:
            raise ScanEncodingError(
                0, f"a batch starts with a 4-byte scan count, got {len(body)} bytes"
            )
        (count,) = COUNT.unpack_from(body, 0)
        offset = COUNT.size
    scans = []
    for index in range(count):
        scan, offset = _record(body, offset, f"scan {index}" if batch else "the scan")
        scans.append(scan)
    if offset != len(body):
        raise ScanEncodingError(
            offset, f"{len(body) - offset} bytes follow the last scan record, expected none"
        )
    return scans


def _record(body: bytes, offset: int, name: str) -> tuple[dict[str, Any], int]:
    """The record at ``offset``: (its mapping, the offset after it)."""
    if len(body) - offset < HEADER.size:
        raise ScanEncodingError(
            offset,
            f"truncated: {name} needs a {HEADER.size}-byte header, got {len(body) - offset} bytes",
        )
    magic, version, flags, id_length, beams, *values = HEADER.unpack_from(body, offset)
    if magic != MAGIC:
        raise ScanEncodingError(offset, f"{name} does not start with {MAGIC!r}, got {magic!r}")
    if version != VERSION:
        raise ScanEncodingError(
            offset + 4, f"{name} is format version {version}; this server reads {VERSION}"
        )
    if flags & ~FLAG_POSE_STD:
        raise UnknownFlagError(
            offset + 5,
            f"{name} sets flag bits {flags & ~FLAG_POSE_STD:#04x}, no field of a scan: "
            f"format version {VERSION} defines bit 0 (pose_std) only",
        )
    start = offset + HEADER.size
    end = start + id_length + beams * RANGE.itemsize
    if end > len(body):
        raise ScanEncodingError(
            start,
            f"truncated: {name} declares a {id_length}-byte unit_id and {beams} beams "
            f"({end - start} bytes), got {len(body) - start}",
        )
    try:
        unit_id = body[start : start + id_length].decode()
    except UnicodeDecodeError:
        raise ScanEncodingError(start, f"{name}'s unit_id is not UTF-8") from None
    stamp, x, y, yaw, angle_min, angle_increment, range_min, range_max, std_xy, std_yaw = values
    scan: dict[str, Any] = {
        "unit_id": unit_id,
        "stamp": stamp,
        "frame": MAP_FRAME,
        "pose": {"x": x, "y": y, "yaw": yaw},
        "angle_min": angle_min,
        "angle_increment": angle_increment,
        "range_min": range_min,
        "range_max": range_max,
        "ranges": np.frombuffer(body, RANGE, beams, start + id_length),
    }
    if flags & FLAG_POSE_STD:
        scan["pose_std"] = {"xy": std_xy, "yaw": std_yaw}
    return scan, end
