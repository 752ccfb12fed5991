"""``fleetmap run --foxglove [--foxglove-port PORT]``: the replay's viewing channels
live, over the Foxglove WebSocket protocol on loopback, while the run goes (the SDK's
server speaks the subprotocol ``foxglove.sdk.v1``).

The server is the Foxglove SDK's (PyPI ``foxglove-sdk``, the optional extra
``fleetmap[foxglove]``); ``FoxgloveLive`` is an episode observer that, after every step,
sends what the run recorded since the step before, built into messages by
``replay_channels``, the same functions that write ``replay.mcap``: the same topics,
schemas and messages, stamped with sim time [ns]. What only the scored run knows is left
out: the freezes' log lines and the ``/metrics`` verdicts (``metrics_channel``), and the
fused scans (``/fleetmap/scans``, read from the server's journal once it has stopped).

The fixed channels (map, scene, ``/tf``, log, metrics) are advertised from the start, a
unit's scan and plan channels with its first scan and plan (a scan channel carries its
first scan's metadata). A client that subscribes to ``/scene`` or a map topic after the
world's objects or the map were sent gets the latest of them again after the next step,
so racks and walls are there whenever Foxglove connects.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, Final

from mapserver.core.errors import FleetmapError
from scenarios.replay.channels import (
    COSTMAP,
    LOG,
    MAP_TRUTH,
    METRICS,
    OCCUPANCY,
    SCENE,
    TF,
    Channel,
    Item,
    SceneObjects,
    encode,
    grid_items,
    log_items,
    map_truth_items,
    metrics_items,
    plan_items,
    scan_items,
    schema_text,
    unit_items,
)
from scenarios.replay.log import event_line, incident_line, unsafe_plan_line

if TYPE_CHECKING:
    from scenarios.run.episode import Episode

HOST: Final = "127.0.0.1"
INSTALL: Final = "pip install 'fleetmap[foxglove]'"
FIXED_CHANNELS: Final = (OCCUPANCY, COSTMAP, SCENE, TF, LOG, METRICS, MAP_TRUTH)
_LATCHED_TOPICS: Final = (SCENE.topic, OCCUPANCY.topic, COSTMAP.topic)


class FoxgloveUnavailable(FleetmapError, RuntimeError):
    """The Foxglove SDK is not installed, or its server cannot listen; the message says
    what to do."""


def foxglove_sdk() -> Any:
    """The ``foxglove`` module of ``foxglove-sdk``; FoxgloveUnavailable, saying how to
    install it, when it is missing."""
    try:
        import foxglove
    except ImportError:
        raise FoxgloveUnavailable(
            f"--foxglove needs the Foxglove SDK (foxglove-sdk): {INSTALL}"
        ) from None
    return foxglove


class FoxgloveLive:
    """Streams a run's viewing channels to Foxglove on ``ws://127.0.0.1:port`` (port 0: a
    free one; ``url`` says which). Pass it to the run as an observer; ``stop`` at the end.
    FoxgloveUnavailable when the SDK is missing or the port cannot be bound."""

    every_s: float | None = None

    def __init__(self, port: int) -> None:
        fox = foxglove_sdk()
        self._fox = fox
        self._context = fox.Context()
        self._subscribed: set[str] = set()  # latched topics a client subscribed to
        self._lock = threading.Lock()
        try:
            self._server = fox.start_server(
                name="fleetmap", host=HOST, port=port, context=self._context,
                server_listener=_Subscriptions(self),
            )  # fmt: skip
        except RuntimeError as exc:
            reason = f"cannot listen on {HOST}:{port} ({exc})"
            raise FoxgloveUnavailable(f"--foxglove: {reason}") from None
        self.port: int = self._server.port
        self._channels: dict[str, Any] = {}  # topic -> SDK channel
        for channel in FIXED_CHANNELS:
            self._channel(channel)
        self._objects = SceneObjects()
        self._seen: dict[str, int] = {}  # record list -> how many items were sent
        self._latest: dict[str, tuple[int, bytes]] = {}  # latched topic -> last message

    @property
    def url(self) -> str:
        return f"ws://{HOST}:{self.port}"

    def observe(self, episode: Episode) -> None:
        """Send what the record gained since the last step (module docstring)."""
        record = episode.record
        lines = [event_line(e) for e in self._new(record.events, "events")]
        lines += [
            unsafe_plan_line(p)
            for p in self._new(record.plans, "unsafe")
            if p.stale_free or p.inscribed
        ]
        lines += [incident_line(i) for i in self._new(record.incidents, "incidents")]
        self._resend_latched()
        streams: tuple[tuple[bool, Iterable[Item]], ...] = (  # (latched, items)
            (True, self._objects.items(self._new(record.objects, "objects"))),
            (True, grid_items(self._new(record.grids, "grids"), record.geometry)),
            (False, unit_items(self._new(record.units, "units"), record.unit_radius,
                               record.unit_height)),
            (False, scan_items(self._new(record.scans, "scans"))),
            (False, plan_items(self._new(record.plans, "plans"))),
            (False, log_items(sorted(lines, key=lambda line: line.stamp))),
            (False, metrics_items(self._new(record.counters, "counters"), None)),
            (False, map_truth_items(self._new(record.map_truth, "map_truth"))),
        )  # fmt: skip
        for latched, stream in streams:
            for ns, channel, message in stream:
                data = encode(message)
                if latched:
                    self._latest[channel.topic] = (ns, data)
                self._channel(channel).log(data, log_time=ns)

    def finish(self, episode: Episode) -> None:
        self.observe(episode)  # the last counters sample

    def stop(self) -> None:
        """Stop the server (clients are disconnected)."""
        self._server.stop()

    # ------------------------------------------------------------------ helpers
    def _new(self, items: list, name: str) -> list:
        start = self._seen.get(name, 0)
        self._seen[name] = len(items)
        return items[start:]

    def _resend_latched(self) -> None:
        with self._lock:
            topics, self._subscribed = self._subscribed, set()
        for topic in sorted(topics):
            if topic in self._latest:
                ns, data = self._latest[topic]
                self._channels[topic].log(data, log_time=ns)

    def subscribed(self, topic: str) -> None:
        """A client subscribed to ``topic`` (the SDK's thread)."""
        if topic in _LATCHED_TOPICS:
            with self._lock:
                self._subscribed.add(topic)

    def _channel(self, channel: Channel) -> Any:
        """The SDK channel of ``channel``'s topic (made on first use, with its metadata)."""
        made = self._channels.get(channel.topic)
        if made is None:
            schema = self._fox.Schema(
                name=channel.schema, encoding="jsonschema", data=schema_text(channel.schema)
            )
            made = self._channels[channel.topic] = self._fox.Channel(
                channel.topic, schema=schema, message_encoding="json",
                context=self._context, metadata=dict(channel.metadata),
            )  # fmt: skip
        return made


class _Subscriptions:
    """The SDK server's listener: tells ``FoxgloveLive`` which topics clients subscribe to."""

    def __init__(self, live: FoxgloveLive) -> None:
        self.live = live

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.live.subscribed(channel.topic)
