"""``MapClient``: typed access to the map server's HTTP API (docs/http-api.md).

This module is the one place that knows the server's URLs. ``MapClient`` wraps an
injected ``httpx.Client`` whose ``base_url`` names the server, so tests pass an
``httpx.Client(transport=httpx.MockTransport(handler))`` or
``httpx.Client(transport=httpx.ASGITransport(app))`` and production code a plain client::

    with httpx.Client(base_url="http://127.0.0.1:8700") as http:
        client = MapClient(http, token="...", timeout=2.0)
        ack = client.post_scan(scan)
        costs = client.follow_costmap(None)          # full costmap the first time ...
        costs = client.follow_costmap(costs)         # ... then only the changed patches

The client never closes, configures or mutates the injected ``httpx.Client``; it adds the
``Authorization: Bearer TOKEN`` header and an explicit timeout [s] to each request. A
reply that says "try later" (429, the server's reads are saturated, or 503) is retried up
to ``retries`` times after its ``Retry-After`` [s] (1 s without one, at most
``max_retry_wait_s``); every request of the API may be repeated safely.

Errors - every failure raises a subclass of ``MapClientError``; each names the endpoint
(``"POST /v1/scans"``) and carries the offending value:

- ``MapClientError`` - base.

  - ``MapServerUnavailable`` - no reply: connection refused or dropped, or a timeout.
    Wraps the ``httpx.TransportError`` (``cause``). After this error on ``post_scan`` the
    scan may or may not be durable: only a received ``ScanAck`` promises it. Re-sending
    the very same scan is safe: the server answers a retry with the original ack and
    fuses it once (another scan at the same stamp is a 409).
  - ``MapRequestError`` - the server refused the request (any 4xx; nothing changed).
    ``status`` and ``detail`` (the ``{"detail": ...}`` of the body, or the body text).

    - ``Unauthorized`` - 401: missing or wrong token.
    - ``Forbidden`` - 403: the token's role may not do this (a reader posting scans).
    - ``Conflict`` - 409: e.g. a unit's stamp went backwards.
    - ``InvalidRequest`` - 400, 413 (body too large) or 422 (a field failed validation).

  - ``MapServerError`` - 5xx: a server bug. ``status`` and ``detail`` as above.
  - ``MapProtocolError`` - a 2xx reply that breaks the contract: not JSON, a missing or
    mistyped field (replies are validated strictly by the API's own pydantic models,
    ``mapserver.api.schemas``) or header, a raw body whose size is not ``width * height``.
    Fields the models do not know are ignored, so a newer server that adds a field to a
    reply does not break an older client.

Wire format notes:

- ``Scan`` objects are sent in the binary scan encoding (docs/scan-binary.md: a fixed
  header and float32 ranges, ``Content-Type: application/vnd.fleetmap.scan``), unless the
  client was made with ``scan_encoding="json"``. A scan given as a mapping goes as JSON,
  as given, ``Infinity`` tokens included (docs/http-api.md 2.1 allows them), so bodies are
  encoded here rather than by httpx, which refuses non-finite floats; a ``Scan`` sent as
  JSON has its no-return beams as ``2 * range_max + 1`` (no return under REP 117, and
  strict JSON).
- ``POST /v1/scans/batch`` takes ``{"scans": [scan, ...]}`` and replies
  ``200 {"acks": [{"seq": n, "map_version": v}, ...]}``, one ack per scan in order
  (this reply shape is the project's extension of docs/http-api.md 2.1).
- ``POST /v1/units`` and ``GET /v1/units`` (``publish_units``, ``units``) carry units'
  poses, planned paths and freezes for the live viewer: the project's extension of
  docs/http-api.md.
- Grids are fetched as ``format=raw``: row-major bytes, row 0 at the origin's y (the
  bottom row), so ``data[row, col]`` is cell (col, row) of ``GridGeometry``.
"""

from __future__ import annotations

import json
import math
import numbers
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import httpx
import numpy as np
import orjson
from pydantic import BaseModel, ValidationError

from mapserver.api.schemas import (
    CellOut,
    CellsOut,
    ClockOut,
    CostmapUpdates,
    MapMeta,
    PlanOut,
    ScanAck,
    ScanBatchAck,
    SegmentOut,
    SegmentsOut,
    UnitsAck,
    UnitsOut,
    UnitState,
)
from mapserver.core.errors import FleetmapError, dotted
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan, json_ranges
from mapserver.core.scan_binary import CONTENT_TYPE as BINARY_SCAN_TYPE
from mapserver.core.scan_binary import encode_batch, encode_scan

# ---------------------------------------------------------------------------- errors


class MapClientError(FleetmapError, Exception):
    """Base of every error ``MapClient`` raises; ``endpoint`` is e.g. ``"GET /v1/map"``."""

    def __init__(self, endpoint: str, message: str) -> None:
        self.endpoint = endpoint
        super().__init__(f"{endpoint}: {message}")


class MapServerUnavailable(MapClientError):
    """No reply (connect error, dropped connection, timeout); ``cause`` is the httpx error."""

    def __init__(self, endpoint: str, cause: httpx.TransportError) -> None:
        self.cause = cause
        super().__init__(endpoint, f"map server unavailable ({type(cause).__name__}: {cause})")


class _StatusError(MapClientError):
    """An error status: ``status`` (HTTP code) and ``detail`` (the body's ``detail``)."""

    def __init__(self, endpoint: str, status: int, detail: Any) -> None:
        self.status = status
        self.detail = detail
        text = detail if isinstance(detail, str) else repr(detail)
        super().__init__(endpoint, f"HTTP {status}: {_clip(text, 500)}")


class MapRequestError(_StatusError):
    """The server refused the request (4xx); nothing on the server changed."""


class Unauthorized(MapRequestError):
    """401: the bearer token is missing or unknown."""


class Forbidden(MapRequestError):
    """403: the token's role does not allow this request."""


class Conflict(MapRequestError):
    """409: the request contradicts the map's state, e.g. a unit's stamp went backwards."""


class InvalidRequest(MapRequestError):
    """400, 413 or 422: a malformed, too large or invalid request; ``detail`` names the field."""


class MapServerError(_StatusError):
    """5xx: the server failed (a bug, by docs/http-api.md)."""


class MapProtocolError(MapClientError):
    """A successful reply that breaks the contract; ``problem`` says how, ``value`` shows it."""

    def __init__(self, endpoint: str, problem: str, value: Any) -> None:
        self.problem = problem
        self.value = value
        super().__init__(endpoint, f"reply breaks the contract: {problem}, got {_short(value)}")


_REQUEST_ERRORS: dict[int, type[MapRequestError]] = {
    400: InvalidRequest,
    401: Unauthorized,
    403: Forbidden,
    409: Conflict,
    413: InvalidRequest,
    415: InvalidRequest,
    422: InvalidRequest,
}


def _short(value: Any, limit: int = 120) -> str:
    """``repr(value)``, clipped to ``limit`` characters."""
    return _clip(repr(value), limit)


def _clip(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ---------------------------------------------------------------------------- replies


@dataclass(frozen=True, eq=False)
class Grid:
    """A fetched grid: ``data`` (height, width), row 0 at the origin's y, read-only.

    int8 OccupancyGrid values for ``occupancy`` (-1 unknown, 0..100 percent), uint8 Nav2
    costs for ``costmap`` (0 free .. 254 lethal, 255 unknown). ``version`` and ``stamp``
    [s] are the map's at evaluation (``stamp`` None when the server does not say). Raw
    grids come as bytes and ``X-Map-*`` headers, not JSON, so this is the one reply type
    that is not a model of ``mapserver.api.schemas``.
    """

    data: np.ndarray
    geometry: GridGeometry
    version: int
    stamp: float | None


# ---------------------------------------------------------------------------- client


class MapClient:
    """Typed calls to a map server reached through ``http`` (its ``base_url`` names the server).

    token: bearer token sent as ``Authorization: Bearer TOKEN`` (None: no header).
    timeout: per-request timeout [s], or an ``httpx.Timeout``; passed explicitly on every
    request so the injected client's default never applies.
    retries: how many times a 429 or 503 reply is retried (0: never).
    max_retry_wait_s: [s] the longest wait before a retry, whatever ``Retry-After`` says.
    sleep: how to wait [s] (``time.sleep``; a parameter for tests).
    scan_encoding: ``"binary"`` (docs/scan-binary.md; ranges rounded to float32, a quarter
    of the bytes and no number parsing on the server) or ``"json"``, for ``Scan`` objects.
    """

    def __init__(
        self,
        http: httpx.Client,
        token: str | None = None,
        timeout: httpx.Timeout | float = 5.0,
        retries: int = 2,
        max_retry_wait_s: float = 5.0,
        sleep: Callable[[float], None] = time.sleep,
        scan_encoding: str = "binary",
    ) -> None:
        if not http.base_url.host:
            raise ValueError(
                f"http client needs a base_url naming the map server, got {str(http.base_url)!r}"
            )
        if token is not None and (not isinstance(token, str) or not token.strip()):
            raise ValueError(f"token must be a non-empty string or None, got {token!r}")
        if not isinstance(timeout, httpx.Timeout):
            if isinstance(timeout, bool) or not isinstance(timeout, int | float):
                raise ValueError(f"timeout must be seconds or an httpx.Timeout, got {timeout!r}")
            if not (math.isfinite(timeout) and timeout > 0):
                raise ValueError(f"timeout must be a positive number of seconds, got {timeout!r}")
            timeout = httpx.Timeout(float(timeout))
        if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
            raise ValueError(f"retries must be an integer >= 0, got {retries!r}")
        if scan_encoding not in ("binary", "json"):
            raise ValueError(f"scan_encoding must be 'binary' or 'json', got {scan_encoding!r}")
        if not (isinstance(max_retry_wait_s, int | float) and max_retry_wait_s >= 0):
            raise ValueError(f"max_retry_wait_s must be >= 0 seconds, got {max_retry_wait_s!r}")
        self._http = http
        self._headers = {"Authorization": f"Bearer {token}"} if token is not None else {}
        self._timeout = timeout
        self._retries = retries
        self._max_retry_wait_s = float(max_retry_wait_s)
        self._sleep = sleep
        self._binary = scan_encoding == "binary"

    # -- scans (2.1)

    def post_scan(self, scan: Scan | Mapping[str, Any]) -> ScanAck:
        """Send one scan (a ``Scan`` or its docs/http-api.md 2.1 dict as is); durable once acked."""
        return self._json("POST", "/v1/scans", ScanAck, self._scans_payload([scan], batch=False))

    def post_scans(self, scans: Iterable[Scan | Mapping[str, Any]]) -> list[ScanAck]:
        """Send scans in one ``POST /v1/scans/batch``; one ack per scan, in order.

        Replies ``{"acks": [{"seq", "map_version"}, ...]}``; an empty batch sends nothing.
        """
        scans = list(scans)
        if not scans:
            return []
        payload = self._scans_payload(scans, batch=True)
        reply = self._json("POST", "/v1/scans/batch", ScanBatchAck, payload)
        return _same_count("POST /v1/scans/batch", "acks", reply.acks, len(scans))

    def _scans_payload(self, scans: list[Scan | Mapping[str, Any]], batch: bool) -> Payload:
        """Scans as a body: binary (docs/scan-binary.md) when all are ``Scan`` objects and
        the client sends binary, else JSON (a mapping goes as given)."""
        all_scans = all(isinstance(scan, Scan) for scan in scans)
        if self._binary and all_scans:
            content = encode_batch(scans) if batch else encode_scan(scans[0])
            return content, BINARY_SCAN_TYPE
        bodies = [_scan_body(scan, plain=not all_scans) for scan in scans]
        return _json_payload({"scans": bodies} if batch else bodies[0], all_scans)

    # -- map (2.2, 2.3)

    def map_meta(self) -> MapMeta:
        """The map's geometry, version, stamp and settings."""
        return self._json("GET", "/v1/map/meta", MapMeta)

    def occupancy(self, at: float | None = None) -> Grid:
        """The OccupancyGrid (int8) evaluated at stamp ``at`` [s] (default: the map's now)."""
        return self._raw_grid("/v1/map", at, np.int8)

    def costmap(self, at: float | None = None) -> Grid:
        """The Nav2 costmap (uint8) evaluated at stamp ``at`` [s] (default: the map's now)."""
        return self._raw_grid("/v1/costmap", at, np.uint8)

    def costmap_updates(self, since: int) -> CostmapUpdates:
        """Patches of the costmap cells changed after version ``since``."""
        if isinstance(since, bool) or not isinstance(since, int | np.integer):
            raise ValueError(f"since must be an integer costmap version, got {since!r}")
        params = {"since": int(since)}
        return self._json("GET", "/v1/costmap/updates", CostmapUpdates, params=params)

    def follow_costmap(self, local: Grid | None) -> Grid:
        """Bring a costmap fetched by ``costmap()`` (or None) up to the server's latest.

        Applies the patches since ``local.version`` to a copy (``local`` is not changed),
        or fetches the whole costmap when ``local`` is None or the server answers
        ``full``; returns ``local`` itself when nothing changed. The result's ``stamp`` is
        the one the updates reply carries (None if it carries none). ``local`` must be
        the server's latest at the time (fetched without ``at``).
        """
        if local is None:
            return self.costmap()
        if local.data.dtype != np.uint8:
            raise ValueError(f"follow_costmap needs a uint8 costmap, got dtype {local.data.dtype}")
        updates = self.costmap_updates(local.version)
        if updates.full:
            return self.costmap()
        if not updates.patches and updates.version == local.version:
            return local  # nothing changed: the local grid (immutable) is current
        costs = local.data.copy()
        for patch in updates.patches:
            if patch.x0 + patch.width > costs.shape[1] or patch.y0 + patch.height > costs.shape[0]:
                raise MapProtocolError(
                    "GET /v1/costmap/updates",
                    f"patch exceeds the {costs.shape[1]} x {costs.shape[0]} local grid",
                    (patch.x0, patch.y0, patch.width, patch.height),
                )
            patch.to_patch().apply_to(costs)
        costs.flags.writeable = False
        return Grid(costs, local.geometry, updates.version, updates.stamp)

    # -- queries (2.4, 2.5)

    def query_cells(
        self, points: Sequence[Sequence[float]] | np.ndarray, at: float | None = None
    ) -> list[CellOut]:
        """State, probability, cost and freshness of the cells at ``points`` [(x, y) m].

        at: stamp [s] to evaluate decay at (default: the map's now).
        """
        body: dict[str, Any] = {"points": _rows("points", points, 2)}
        if at is not None:
            body["at"] = float(at)
        reply = self._json("POST", "/v1/query/cells", CellsOut, _json_payload(body))
        return _same_count("POST /v1/query/cells", "cells", reply.cells, len(body["points"]))

    def query_segments(self, segments: Sequence[Sequence[float]] | np.ndarray) -> list[SegmentOut]:
        """Cost, blockage and unknown share along each segment ``(x0, y0, x1, y1)`` [m]."""
        body = {"segments": _rows("segments", segments, 4)}
        reply = self._json("POST", "/v1/query/segments", SegmentsOut, _json_payload(body))
        sent = len(body["segments"])
        return _same_count("POST /v1/query/segments", "segments", reply.segments, sent)

    # -- planning (2.6)

    def plan(
        self,
        start: Sequence[float],
        goal: Sequence[float],
        algorithm: str = "astar",
        allow_unknown: bool = True,
        unit_id: str | None = None,
    ) -> PlanOut:
        """A path from ``start`` to ``goal`` [(x, y) m] on the server's costmap.

        algorithm: "astar" or "dijkstra"; allow_unknown: may the path cross unknown cells;
        unit_id: the asking unit (optional).
        """
        body: dict[str, Any] = {
            "start": _row("start", start, 2),
            "goal": _row("goal", goal, 2),
            "algorithm": algorithm,
            "allow_unknown": bool(allow_unknown),
        }
        if unit_id is not None:
            body["unit_id"] = unit_id
        return self._json("POST", "/v1/plan", PlanOut, _json_payload(body))

    # -- units (project extension, for the viewer)

    def publish_units(self, units: Iterable[UnitState]) -> int:
        """Publish units' poses, planned paths and freezes (all or none); returns how many
        units the server now holds a state for. Publishing nothing sends nothing (0)."""
        bodies = [_unit_body(f"units[{i}]", unit) for i, unit in enumerate(units)]
        if not bodies:
            return 0
        return self._json("POST", "/v1/units", UnitsAck, _json_payload({"units": bodies})).tracked

    def units(self) -> list[UnitState]:
        """The latest published state of every unit, ordered by ``unit_id``."""
        return self._json("GET", "/v1/units", UnitsOut).units

    # -- the map's clock (docs/map-time.md; project extension)

    def clock(self) -> ClockOut:
        """What a scan's stamp is judged against now (``GET /v1/clock``)."""
        return self._json("GET", "/v1/clock", ClockOut)

    def declare_clock(self, now: float) -> ClockOut:
        """Declare the simulation's clock: it reads ``now`` [s] (``PUT /v1/clock``, as
        ROS's ``/clock``); stamps are judged against it for ``clock.sim_ttl_s``."""
        if isinstance(now, bool) or not isinstance(now, numbers.Real) or not math.isfinite(now):
            raise ValueError(f"now must be a finite number of seconds, got {now!r}")
        return self._json("PUT", "/v1/clock", ClockOut, _json_payload({"now": float(now)}))

    # -- operations (2.7)

    def healthz(self) -> bool:
        """True when the server is ready; False on a 5xx or when it cannot be reached.

        A 4xx (e.g. 404: not a map server at this URL) still raises ``MapRequestError``.
        """
        try:
            self._send("GET", "/healthz")
        except (MapServerUnavailable, MapServerError):
            return False
        return True

    def metrics_text(self) -> str:
        """The Prometheus text exposition of ``GET /metrics``."""
        return self._send("GET", "/metrics").text

    # -- plumbing

    def _send(
        self,
        method: str,
        path: str,
        params: Mapping[str, Any] | None = None,
        payload: Payload | None = None,
    ) -> httpx.Response:
        """One request with auth and timeout; returns a 2xx response or raises.

        payload: the body and its content type (``_json_payload``, ``_scans_payload``).
        """
        endpoint = f"{method} {path}"
        headers = dict(self._headers)
        content = None
        if payload is not None:
            content, headers["Content-Type"] = payload
        for attempt in range(self._retries + 1):
            try:
                response = self._http.request(
                    method, path, params=params, content=content, headers=headers,
                    timeout=self._timeout,
                )  # fmt: skip
            except httpx.TransportError as exc:
                raise MapServerUnavailable(endpoint, exc) from exc
            if response.status_code not in (429, 503) or attempt == self._retries:
                break
            self._sleep(self._retry_wait(response))
        status = response.status_code
        if 200 <= status < 300:
            return response
        if 400 <= status < 500:
            raise _REQUEST_ERRORS.get(status, MapRequestError)(endpoint, status, _detail(response))
        if status >= 500:
            raise MapServerError(endpoint, status, _detail(response))
        raise MapProtocolError(endpoint, "unexpected HTTP status", status)

    def _retry_wait(self, response: httpx.Response) -> float:
        """[s] to wait before retrying ``response``: its Retry-After (seconds), capped."""
        try:
            wait = float(response.headers.get("Retry-After", "1"))
        except ValueError:  # an HTTP date or garbage: the default
            wait = 1.0
        return min(max(wait, 0.0), self._max_retry_wait_s) if math.isfinite(wait) else 1.0

    def _json(
        self,
        method: str,
        path: str,
        model: type[Reply],
        payload: Payload | None = None,
        params: Mapping[str, Any] | None = None,
    ) -> Reply:
        """A request whose reply is the JSON object ``model`` (a schema of the API),
        validated strictly: a reply that breaks it is a ``MapProtocolError``. Fields the
        model does not know are dropped (a newer server may add some)."""
        response = self._send(method, path, params, payload)
        try:
            return model.model_validate_json(response.content, strict=True, extra="ignore")
        except ValidationError as exc:
            raise _protocol_error(f"{method} {path}", exc, response.text) from None

    def _raw_grid(self, path: str, at: float | None, dtype: type[np.generic]) -> Grid:
        """``GET path?format=raw[&at=]``: bytes plus ``X-Map-*`` headers."""
        params: dict[str, Any] = {"format": "raw"}
        if at is not None:
            params["at"] = float(at)
        response = self._send("GET", path, params)
        endpoint = f"GET {path}"
        header = _Headers(endpoint, response.headers)
        try:
            geometry = GridGeometry(
                width=header.get("X-Map-Width", int),
                height=header.get("X-Map-Height", int),
                resolution=header.get("X-Map-Resolution", float),
                origin_x=header.get("X-Map-Origin-X", float),
                origin_y=header.get("X-Map-Origin-Y", float),
            )
        except ValueError as exc:  # the geometry's own check names the field
            raise MapProtocolError(
                endpoint, "X-Map-* headers give no valid grid", str(exc)
            ) from None
        body = response.content
        if len(body) != geometry.size:
            raise MapProtocolError(
                endpoint,
                f"raw body must hold width * height = {geometry.width} * {geometry.height}"
                f" = {geometry.size} bytes",
                len(body),
            )
        data = np.frombuffer(body, dtype=dtype).reshape(geometry.shape)
        return Grid(
            data=data,
            geometry=geometry,
            version=header.get("X-Map-Version", int),
            stamp=header.get("X-Map-Stamp", float, nullable=True),
        )


# ---------------------------------------------------------------------------- parsing

Reply = TypeVar("Reply", bound=BaseModel)
Payload = tuple[bytes, str]
"""A request body and its content type."""
JSON_TYPE = "application/json"
Item = TypeVar("Item")


def _protocol_error(endpoint: str, exc: ValidationError, text: str) -> MapProtocolError:
    """The first problem pydantic found in a reply, as the client's protocol error: the
    field (``cells[2].state``), what is wrong and the value sent."""
    error = exc.errors(include_url=False)[0]
    if error["type"] == "json_invalid":
        return MapProtocolError(endpoint, "reply is not JSON", text)
    field = dotted(error["loc"])
    if error["type"] == "missing":
        present = sorted(error["input"]) if isinstance(error["input"], dict) else error["input"]
        return MapProtocolError(endpoint, f"field {field!r} is missing (fields present)", present)
    where = f"field {field!r}" if field else "reply"
    reason = error["ctx"]["error"] if error["type"] == "value_error" else error["msg"]
    return MapProtocolError(endpoint, f"{where}: {reason}", error["input"])


@dataclass(frozen=True)
class _Headers:
    """Typed access to a raw reply's ``X-Map-*`` headers."""

    endpoint: str
    headers: httpx.Headers

    def get(self, name: str, kind: type[int] | type[float], nullable: bool = False) -> Any:
        """Header ``name`` parsed as ``kind``; with nullable, "nan", "null" or "" give None
        (the server's way of saying "no stamp yet")."""
        text = self.headers.get(name)
        if text is None:
            raise MapProtocolError(self.endpoint, f"header {name} is missing", dict(self.headers))
        if nullable and text.strip().lower() in ("", "null", "none", "nan"):
            return None
        try:
            return kind(text)
        except ValueError:
            expected = "an integer" if kind is int else "a number"
            raise MapProtocolError(
                self.endpoint, f"header {name} must be {expected}", text
            ) from None


def _detail(response: httpx.Response) -> Any:
    """The ``detail`` of an error body ``{"detail": ...}``, else the body text."""
    try:
        data = json.loads(response.content)
    except ValueError:
        return response.text
    if isinstance(data, dict) and "detail" in data:
        return data["detail"]
    return data


def _same_count(endpoint: str, key: str, items: list[Item], sent: int) -> list[Item]:
    """``items``, the reply's list ``key``, which must hold one entry per item sent."""
    if len(items) != sent:
        raise MapProtocolError(
            endpoint, f"one answer per item asked ({sent}) in {key!r}", len(items)
        )
    return items


def _json_payload(body: Any, fast: bool = False) -> Payload:
    """``body`` as JSON bytes. ``fast``: it holds only finite floats outside numpy arrays
    (bodies built from ``Scan`` objects), so orjson encodes it (NaN in arrays as null, an
    invalid beam); other bodies go through ``json`` so that ``Infinity`` tokens pass as
    given (httpx refuses non-finite floats)."""
    if fast:
        return orjson.dumps(body, option=orjson.OPT_SERIALIZE_NUMPY), JSON_TYPE
    return json.dumps(body, separators=(",", ":")).encode(), JSON_TYPE


def _scan_body(scan: Scan | Mapping[str, Any], plain: bool) -> Any:
    """A scan's docs/http-api.md 2.1 JSON object; a mapping is sent as is (the server validates).

    A Scan's no-return beams (+inf) are sent as ``2 * range_max + 1``: also "no return"
    under REP 117 (any value above range_max), but strict JSON, which the server parses
    about ten times faster than text holding ``Infinity``. Its ranges are a numpy array
    (for orjson), or with ``plain`` a list holding None for invalid beams (for ``json``).
    """
    if isinstance(scan, Scan):
        body = scan.to_dict(with_ranges=False)
        no_return = 2.0 * scan.range_max + 1.0
        ranges = np.where(scan.ranges == math.inf, no_return, scan.ranges)
        body["ranges"] = json_ranges(ranges) if plain else ranges
        return body
    if isinstance(scan, Mapping):
        return dict(scan)
    raise TypeError(f"scan must be a Scan or a dict, got {type(scan).__name__}: {_short(scan)}")


def _unit_body(name: str, unit: UnitState) -> dict[str, Any]:
    """A UnitState as the JSON object of ``POST /v1/units`` (the model checked its fields)."""
    if not isinstance(unit, UnitState):
        raise TypeError(f"{name} must be a UnitState, got {type(unit).__name__}: {_short(unit)}")
    return unit.model_dump(mode="json")


def _rows(name: str, values: Iterable[Iterable[float]], n: int) -> list[list[float]]:
    """``values`` as a list of rows of ``n`` floats; ValueError names the bad row."""
    return [_row(f"{name}[{i}]", row, n) for i, row in enumerate(values)]


def _row(name: str, row: Iterable[float], n: int) -> list[float]:
    """``row`` as a list of ``n`` floats; ValueError names it."""
    if type(row) is list or type(row) is tuple:  # the common case, without ABC checks
        items = row
    else:
        items = list(row) if isinstance(row, Iterable) else [row]
    if len(items) != n or not all(_is_number(v) for v in items):
        raise ValueError(f"{name} must be {n} numbers, got {_short(row)}")
    return [float(v) for v in items]


def _is_number(value: Any) -> bool:
    """A real number (Python or numpy), not a bool."""
    kind = type(value)
    if kind is float or kind is int:  # the common case, without ABC checks
        return True
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)
