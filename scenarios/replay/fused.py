"""The scans a run's map server fused and its map settings, as ``replay.mcap`` keeps them
so that ``fleetmap replay`` rebuilds the server's map bit for bit.

Source: the data dir of the run's own server once it has stopped: its map settings
(``map-settings.json``: grid, sensor model, policy, decay, max clearing range) and its
journal read as the server reads it at start-up (``mapserver.service.replay.journal_records``:
seq order, damaged records and clock-rule breakers left out), which is the order the
server fused them in. The journal is read while the replay is written, one scan at a
time, so a long run's scans are never all in memory (for a long run, in a child process:
``scenarios.replay.fused_worker``).

In the MCAP file:

- channel ``/fleetmap/scans``, JSON messages with the JSON schema ``fleetmap.FusedScan``,
  one per fused scan, log and publish time its stamp [ns], written in seq order (a run's
  fleet posts tick by tick, so the stamps never go down along it)::

      {"seq": 17,                      # the server journal's seq (fusion order)
       "scan": {...},                  # docs/http-api.md 2.1 scan object without "ranges"
       "ranges_shuffled": "AAAA..."}   # base64 of the ranges' float64 bytes by plane

  Floats in ``scan`` are written as their shortest round-trip decimal, so they read
  back as the same float64. ``ranges_shuffled`` holds the journal's own float64 values
  (NaN invalid, +inf no return), little-endian, byte-shuffled: byte 0 of every beam,
  then byte 1 of every beam, ..., byte 7 (``shuffle_f8``); the chunk compression (zstd)
  packs the planes about a fifth smaller than the plain bytes.
- metadata record ``fleetmap.map_settings``: key ``json``, the settings' JSON text.

A run against an outside server (``fleetmap run --server``) has no data dir to read: its
replay has neither, and ``fleetmap replay`` falls back to the sampled LaserScans.

A run on zones (``map_server.zones``, docs/scaling.md) has a data dir per zone server.
``read_zoned_fused`` gives what one server of the whole site would have fused
(``ZonedFusedScans``): the site's settings (zone 0's with the site's grid) and the zones'
journals merged in the order the fleet posted, each scan once (a scan near a cut is in
several journals). The fleet posts tick by tick, a tick's scans stamped alike and in its
units' order, so that order is (stamp, unit); each journal is checked to follow it. The
stitched map of the zones is one server's fed that sequence, cell for cell, so
``fleetmap replay`` rebuilds it bit for bit as it does one server's.
"""

from __future__ import annotations

import base64
import heapq
import json
import weakref
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

import numpy as np
import orjson

from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.service.replay import ReplayError, journal_records, read_settings
from mapserver.store.journal import JOURNAL_FILENAME

FUSED_TOPIC = "/fleetmap/scans"
FUSED_SCHEMA_NAME = "fleetmap.FusedScan"
MAP_SETTINGS_METADATA = "fleetmap.map_settings"

FUSED_SCHEMA: dict[str, Any] = {
    "title": FUSED_SCHEMA_NAME,
    "type": "object",
    "properties": {
        "seq": {"type": "integer", "minimum": 1},
        "scan": {"type": "object"},
        "ranges_shuffled": {"type": "string", "contentEncoding": "base64"},
    },
    "required": ["seq", "scan", "ranges_shuffled"],
}
"""JSON schema of a ``/fleetmap/scans`` message (``scan``: docs/http-api.md 2.1, no ``ranges``)."""


@dataclass(frozen=True)
class FusedScans:
    """What a run's server fused: its map settings (as in ``map-settings.json``) and its
    journal file."""

    settings: dict[str, Any]
    journal: Path

    def scans(self) -> Iterator[tuple[int, Scan]]:
        """The fused scans as (journal seq, scan), in seq order, read one at a time."""
        return journal_fused(self.journal)


def journal_fused(journal: Path) -> Iterator[tuple[int, Scan]]:
    """(seq, scan) of each scan in the server's ``journal`` that it fuses at start-up, in
    seq order, read one at a time."""
    for record in journal_records(journal):
        if record.scan is not None:
            yield record.seq, record.scan


def read_fused(data_dir: Path, folder: TemporaryDirectory | None = None) -> FusedScans:
    """The map settings and journal of a stopped server's ``data_dir``
    (``mapserver.service.replay.ReplayError`` when it holds no settings); ``folder``, the
    temporary folder that holds ``data_dir``, is removed when the result is."""
    fused = FusedScans(read_settings(data_dir), Path(data_dir) / JOURNAL_FILENAME)
    if folder is not None:
        weakref.finalize(fused, folder.cleanup)
    return fused


@dataclass(frozen=True)
class ZonedFusedScans:
    """What a zoned run's servers fused, as one server of the whole site (module
    docstring): the site's map settings, the zones' journals and the fleet's units in the
    order it posts a tick's scans."""

    settings: dict[str, Any]
    journals: tuple[Path, ...]
    unit_order: tuple[str, ...]

    def scans(self) -> Iterator[tuple[int, Scan]]:
        """The fused scans as (seq from 1, scan) in posting order, each once, read one at
        a time; ReplayError when a journal holds a unit the fleet has not or breaks that
        order."""
        rank = {unit: k for k, unit in enumerate(self.unit_order)}
        merged = heapq.merge(*(self._keyed(j, rank) for j in self.journals), key=_key_of)
        seq, previous = 0, None
        for key, scan in merged:
            if key != previous:  # else the same scan, journaled by another zone too
                seq += 1
                previous = key
                yield seq, scan

    @staticmethod
    def _keyed(journal: Path, rank: dict[str, int]) -> Iterator[tuple[tuple[float, int], Scan]]:
        last = None
        for seq, scan in journal_fused(journal):
            if scan.unit_id not in rank:
                raise ReplayError(f"{journal}: seq {seq} is unit {scan.unit_id!r}, not the fleet's")
            key = (scan.stamp, rank[scan.unit_id])
            if last is not None and key <= last:
                raise ReplayError(
                    f"{journal}: seq {seq} (unit {scan.unit_id!r}, stamp {scan.stamp}) is not "
                    "in the fleet's posting order (stamp, then unit)"
                )
            last = key
            yield key, scan


def read_zoned_fused(
    data_dirs: Sequence[Path],
    site: GridGeometry,
    unit_order: Sequence[str],
    folder: TemporaryDirectory | None = None,
) -> ZonedFusedScans:
    """What the stopped zone servers of ``data_dirs`` fused, as one server of ``site``
    (module docstring); ReplayError when a dir holds no settings or the zones' settings
    differ but for their grids. ``folder`` as ``read_fused``'s."""
    settings = [read_settings(d) for d in data_dirs]
    first = {k: v for k, v in settings[0].items() if k != "grid"}
    for data_dir, other in zip(data_dirs[1:], settings[1:], strict=True):
        if {k: v for k, v in other.items() if k != "grid"} != first:
            raise ReplayError(f"{data_dir}: its map settings differ from {data_dirs[0]}'s")
    grid = {name: getattr(site, name) for name in settings[0]["grid"]}
    journals = tuple(Path(d) / JOURNAL_FILENAME for d in data_dirs)
    fused = ZonedFusedScans({**settings[0], "grid": grid}, journals, tuple(unit_order))
    if folder is not None:
        weakref.finalize(fused, folder.cleanup)
    return fused


def fused_message(seq: int, scan: Scan) -> bytes:
    """The ``/fleetmap/scans`` message of one fused scan (module docstring)."""
    ranges = shuffle_f8(scan.ranges)
    message = {"seq": seq, "scan": scan.to_dict(with_ranges=False), "ranges_shuffled": ranges}
    return orjson.dumps(message, default=_base64)


def fused_scan(data: bytes) -> tuple[int, Scan]:
    """(seq, scan) of a ``/fleetmap/scans`` message; ValueError when it is not one."""
    message = orjson.loads(data)
    ranges = unshuffle_f8(base64.b64decode(message["ranges_shuffled"], validate=True))
    return int(message["seq"]), Scan.from_dict({**message["scan"], "ranges": ranges})


def shuffle_f8(values: np.ndarray) -> bytes:
    """The little-endian float64 bytes of ``values`` grouped by byte plane: byte 0 of
    each value, then byte 1 of each, ..., byte 7."""
    planes = np.ascontiguousarray(values, dtype="<f8").view(np.uint8).reshape(-1, 8)
    return planes.T.tobytes()


def unshuffle_f8(data: bytes) -> np.ndarray:
    """The float64 values of ``shuffle_f8`` bytes (ValueError: not whole values)."""
    if len(data) % 8:
        raise ValueError(f"{len(data)} bytes are not whole float64 values")
    planes = np.frombuffer(data, dtype=np.uint8).reshape(8, -1)
    return np.ascontiguousarray(planes.T).view("<f8").reshape(-1)


def in_fusion_order(items: Iterable[tuple[int, Scan]]) -> list[Scan]:
    """The scans of (seq, scan) items in seq order; ValueError when a seq repeats."""
    ordered = sorted(items, key=lambda item: item[0])
    seqs = [seq for seq, _ in ordered]
    if len(set(seqs)) != len(seqs):
        raise ValueError("a /fleetmap/scans seq appears twice")
    return [scan for _, scan in ordered]


def settings_metadata(settings: dict[str, Any]) -> dict[str, str]:
    """The ``fleetmap.map_settings`` metadata record's content."""
    return {"json": json.dumps(settings, sort_keys=True)}


def settings_of(metadata: dict[str, str]) -> dict[str, Any]:
    """The map settings of a ``fleetmap.map_settings`` record (ValueError: not JSON)."""
    return json.loads(metadata["json"])


def _key_of(item: tuple[tuple[float, int], Scan]) -> tuple[float, int]:
    return item[0]


def _base64(value: Any) -> str:
    if isinstance(value, bytes):
        return base64.b64encode(value).decode("ascii")
    raise TypeError(f"cannot encode {type(value).__name__}")
