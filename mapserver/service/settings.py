"""The map server's settings: defaults, a YAML config file, ``FLEETMAP_*`` variables, flags.

Precedence, highest first: explicit overrides (the command line's flags), environment
variables, the YAML config file, the defaults below. Environment variables are named
``FLEETMAP_`` + the field, ``__`` between nested names, any letter case::

    FLEETMAP_PORT=8800
    FLEETMAP_SENSOR_MODEL__P_HIT=0.75
    FLEETMAP_TOKENS='[{"token": "s3cret", "role": "admin"}]'

A config file is a YAML mapping with the same names (see ``Settings``); unknown names are
errors, so a typo never passes silently. Relative paths in a config file (``data_dir``,
``map_yaml``) are relative to the file's folder; elsewhere to the working directory.

Everything is checked when the settings are built, by the domain classes themselves
(``GridGeometry``, ``SensorModel``, ``DecayParams``, ``InflationParams``, ``BeliefGrid``
for the rules that join them, ``read_ros_map`` for ``map_yaml``): their error becomes a
pydantic error at the field it names, e.g. ``sensor_model.p_hit``. ``load_settings``
turns all problems into one ``SettingsError`` with one line per problem.

Security: bearer tokens with roles (``unit`` posts scans and unit states as the units it
lists, ``reader`` reads, ``admin`` does both, as any unit). With no token configured the
server is open, and an open server may only bind a loopback address (127.0.0.0/8, ::1,
``localhost``) and answers only loopback Host and Origin headers. ``limits``, ``server``
and ``ingest`` bound what one client can take: docs/server-safety.md lists them.
"""

from __future__ import annotations

import ipaddress
import logging
import math
import os
import re
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from enum import StrEnum
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

import yaml
from pydantic import (
    Field,
    PrivateAttr,
    SecretStr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)
from pydantic_settings import SettingsError as EnvironmentValueError

from mapserver.core.belief import BeliefGrid
from mapserver.core.errors import FleetmapError, dotted
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams
from mapserver.core.scan import DEFAULT_MAX_BEAMS
from mapserver.core.sensor_model import DEFAULT_POLICY, DecayParams, Policy, SensorModel
from mapserver.service.map_clock import (
    DEFAULT_MAX_LEAD_S,
    DEFAULT_MAX_SIM_RATE,
    DEFAULT_SIM_TTL_S,
)
from mapserver.service.validation import (
    Section,
    domain_section,
    error,
    located,
    mark_unknown_keys,
    problems,
)
from mapserver.store.mapfiles import MapFileError, RosMap, read_ros_map
from mapserver.store.retention import RetentionPolicy

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8700
DEFAULT_DATA_DIR = Path("fleetmap-data")
MIB = 1024 * 1024
logger = logging.getLogger(__name__)

# The YAML config file's contents while ``Settings.from_yaml`` builds an instance.
_CONFIG_FILE_DATA: ContextVar[Mapping[str, Any]] = ContextVar(
    "fleetmap_config", default=MappingProxyType({})
)


class SettingsError(FleetmapError, ValueError):
    """Invalid settings or an unreadable config file; ``problems`` holds one line each.

    Each problem reads ``field: what is wrong, got value`` (``field`` dotted, e.g.
    ``sensor_model.p_hit``, or ``config`` for the file itself); ``fields`` holds the same
    problems as (field, what is wrong, got value) pairs, for code that places them.
    """

    def __init__(
        self,
        problems: list[str],
        source: str = "",
        fields: list[tuple[str, str]] | None = None,
    ) -> None:
        self.problems = problems
        self.source = source
        self.fields = fields if fields is not None else []
        where = f" ({source})" if source else ""
        lines = "\n".join(f"  {problem}" for problem in problems)
        super().__init__(f"invalid fleetmap settings{where}:\n{lines}")

    def lines(self) -> list[str]:
        """One line per problem, each naming the config file when there is one (what a
        command prints after its ``error:``)."""
        return [f"{self.source}: {p}" if self.source else p for p in self.problems]


class Role(StrEnum):
    """What a bearer token may do (docs/http-api.md)."""

    UNIT = "unit"  # post scans
    READER = "reader"  # read maps, costmaps, queries
    ADMIN = "admin"  # everything


# ---------------------------------------------------------------------------- sections
GridSettings = domain_section(
    GridGeometry,
    "GridSettings",
    """The grid when no ``map_yaml`` is given (the default: 100 m x 50 m at 5 cm).

    width, height: [cells]. resolution: [m/cell]. origin_x, origin_y: [m] world position
    of the outer corner of cell (0, 0) (``GridGeometry``).
    """,
    width=2000,
    height=1000,
    resolution=0.05,
)
SensorModelSettings = domain_section(
    SensorModel,
    "SensorModelSettings",
    "The inverse sensor model (``SensorModel`` documents each value and its units).",
)
DecaySettings = domain_section(
    DecayParams,
    "DecaySettings",
    "Freshness decay of the ``decay`` policy: half lives [s], fade bound [log-odds].",
)
InflationSettings = domain_section(
    InflationParams,
    "InflationSettings",
    "Nav2-style inflation (``InflationParams``): radii [m], cost_scaling_factor [1/m].",
)


class TokenSettings(Section):
    """One bearer token: the secret, its role, and a name for logs and errors (never the
    secret; ``tokens[i]`` when not given).

    units: the unit ids a ``unit`` token may post scans and unit states as: exact ids
        (``"u1"``), prefixes ending in ``*`` (``"dock-a-*"``: every id starting with
        ``dock-a-``) or ``"*"`` (any unit, e.g. one simulator posting for its whole fleet).
        Required for ``unit`` tokens (a token that forgot its units is refused at load
        rather than silently allowed to post as anyone); not allowed for ``reader``
        (posts nothing) or ``admin`` (posts as any unit).
    """

    token: SecretStr
    role: Role
    name: str | None = None
    units: list[str] | None = None

    @field_validator("units")
    @classmethod
    def _units_are_ids_or_prefixes(cls, value: list[str] | None) -> list[str] | None:
        for pattern in value or ():
            if not pattern or "*" in pattern[:-1] or pattern != pattern.strip():
                raise PydanticCustomError(
                    "units",
                    "each entry must be a unit id, a prefix ending in '*', or '*', got {pattern}",
                    {"pattern": repr(pattern)},
                )
        return value

    @model_validator(mode="after")
    def _units_match_role(self) -> TokenSettings:
        if self.role is Role.UNIT and not self.units:
            raise error(
                ("units",),
                self.units,
                "a unit token must list the unit ids it may post as "
                '(e.g. ["u1", "u2"], ["u*"] for a prefix, ["*"] for any unit)',
            )
        if self.role is not Role.UNIT and self.units is not None:
            raise error(
                ("units",), self.units, f"only unit tokens are bound to units, not {self.role}"
            )
        return self

    def may_post_as(self, unit_id: str) -> bool:
        """True when this token may post scans and unit states for ``unit_id``."""
        if self.role is Role.ADMIN:
            return True
        return any(
            unit_id.startswith(p[:-1]) if p.endswith("*") else unit_id == p
            for p in self.units or ()
        )

    @field_validator("token")
    @classmethod
    def _token_is_usable(cls, value: SecretStr) -> SecretStr:
        secret = value.get_secret_value()
        if not secret or any(ch.isspace() for ch in secret):
            raise PydanticCustomError(
                "token", "must be a non-empty string without whitespace (value not shown)"
            )
        return value


class LimitsSettings(Section):
    """Request limits: body size [bytes], beams per scan, scans per batch."""

    max_body_bytes: int = Field(default=2 * MIB, gt=0)
    max_beams: int = Field(default=DEFAULT_MAX_BEAMS, gt=0)
    max_batch: int = Field(default=256, gt=0)


class ClockSettings(Section):
    """The map's clock (``mapserver.service.map_clock``, docs/map-time.md): a stamp ahead
    of "now" is refused, "now" being a reference no group of units controls.

    max_lead_s: [s] how far a scan's stamp may lead the reference (the server's wall
        clock; a declared simulation clock; the map's simulated time); a scan leading
        further is refused (422).
    sim_ttl_s: [s] of wall time a declared simulation clock (``PUT /v1/clock``) binds
        after it was declared, and a simulated map's time holds epoch stamps off after
        it last advanced.
    max_sim_rate: how many times faster than real time a simulation with no declared
        clock may run while all its units are silent (the map's simulated time may have
        run on this much since it last advanced).
    """

    max_lead_s: float = Field(default=DEFAULT_MAX_LEAD_S, gt=0, allow_inf_nan=False)
    sim_ttl_s: float = Field(default=DEFAULT_SIM_TTL_S, gt=0, le=86400, allow_inf_nan=False)
    max_sim_rate: float = Field(default=DEFAULT_MAX_SIM_RATE, gt=0, le=1e6, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _removed_keys(cls, data: Any) -> Any:
        """``window_scans`` (the fleet median's window, removed with that rule) is
        accepted and ignored with a warning, so an old config file still loads."""
        if isinstance(data, Mapping) and "window_scans" in data:
            logger.warning(
                "clock.window_scans is ignored: the map's time no longer depends on the "
                "fleet's median (docs/map-time.md); remove it from the settings"
            )
            data = {k: v for k, v in data.items() if k != "window_scans"}
        return data


class ReadSettings(Section):
    """Heavy reads (cell and segment queries, plans) run on worker threads beside the
    ingest, never holding the map's lock while they compute; they are admitted so that
    they cannot starve scan ingest or ``/healthz``.

    max_concurrent_queries: cell and segment queries computing at once.
    max_queued_queries: queries waiting for a turn; beyond it a query gets 429.
    max_queued_plans: plans waiting for the planner (one plans at a time); beyond, 429.
    retry_after_s: [s] the ``Retry-After`` a 429 carries.
    nice: how much lower the CPU priority of the threads computing reads is (Linux nice
        steps, 0..19; 0: the same as ingest's), so that ingest gets the CPU first.
    query_busy_share: the share of time queries may compute back to back (0..1]: they
        run Python, which holds the GIL that scan ingest needs too; after a query of t
        seconds the next waits t x (1 / share - 1). Plans search in numba, without the
        GIL, and are not paced.
    costmap_refresh_s: [s] how long the costmap may lag the belief while nobody reads
        it; a read (costmap, updates, queries, plans) always brings it up to every
        acknowledged scan first. Scans of the same places between two refreshes are
        composed and inflated once; 0 refreshes after every group of scans.
    plan_landmarks: ALT landmarks that raise ``POST /v1/plan``'s A* heuristic, their
        tables built once on the static map's lower bound of the costmap
        (``mapserver.costmap.lower_bound``) and kept while scans change the costmap
        above it; only with a static map (``map_yaml``); 8 B per cell each; 0: none.
    """

    max_concurrent_queries: int = Field(default=2, gt=0)
    max_queued_queries: int = Field(default=16, ge=0)
    max_queued_plans: int = Field(default=8, ge=0)
    retry_after_s: int = Field(default=1, gt=0)
    nice: int = Field(default=10, ge=0, le=19)
    query_busy_share: float = Field(default=0.5, gt=0, le=1)
    costmap_refresh_s: float = Field(default=0.2, ge=0, le=60)
    plan_landmarks: int = Field(default=6, ge=0, le=32)


class IngestSettings(Section):
    """Fair ingest (``mapserver.api.ingest_budget``, docs/server-safety.md): what one unit,
    and one token, may post. A request past a budget is refused with 429 and
    ``Retry-After`` before its scans are queued; the budgets refill continuously.

    unit_beams_per_s, unit_scans_per_s: [beams/s], [scans/s] one unit id may post,
        summed over every token and connection posting as it. Defaults 60,000 and 100:
        1.5x and 5x what a 20 Hz, 2,000-beam LiDAR posts (40,000 beams/s, 20 scans/s).
    token_beams_per_s, token_scans_per_s: [beams/s], [scans/s] one token may post,
        whichever units it posts as (only on a server with tokens; an open server cannot
        tell its clients apart). Defaults 2,000,000 and 2,000: a simulator posting a
        100-unit fleet at 10 Hz x 1,080 beams (1.08 M beams/s) behind one token, with
        about 2x headroom.
    burst_s: [s] of each budget a unit or token may post at once on top of its rate (the
        bucket's size): a unit quiet that long may post that much in one go, e.g. a
        backlog after a network drop (the default 10 s: 600,000 beams, 15 s of the 20 Hz
        LiDAR's scans). A request larger than the whole burst still passes from a full
        bucket; the unit then waits off the excess.
    max_tracked: units and tokens whose buckets are remembered at most (a bucket that
        has refilled is forgotten; past this the least recently used goes first).
    Any rate null or 0: that limit is off.
    """

    unit_beams_per_s: float | None = Field(default=60_000.0, ge=0, allow_inf_nan=False)
    unit_scans_per_s: float | None = Field(default=100.0, ge=0, allow_inf_nan=False)
    token_beams_per_s: float | None = Field(default=2_000_000.0, ge=0, allow_inf_nan=False)
    token_scans_per_s: float | None = Field(default=2_000.0, ge=0, allow_inf_nan=False)
    burst_s: float = Field(default=10.0, gt=0, le=3600, allow_inf_nan=False)
    max_tracked: int = Field(default=100_000, gt=0)


class ServerSettings(Section):
    """How ``fleetmap serve`` treats connections and its log (docs/server-safety.md).

    keep_alive_s: [s] an idle keep-alive connection is closed this long after its last
        response.
    header_timeout_s: [s] a connection is closed when a request's line and headers have not
        all arrived this long after it opened or after its previous response (slow or
        silent clients: uvicorn itself waits forever).
    body_timeout_s: [s] a request whose body has not all arrived this long after its
        headers is answered 408.
    max_connections: open connections at most; a request arriving past it is answered
        503 by uvicorn.
    shutdown_timeout_s: [s] on SIGTERM the server stops accepting, lets requests in flight
        finish for at most this long, then cancels them and exits.
    local_hostnames: Host names an open server (no tokens) accepts besides ``localhost``
        and loopback addresses, e.g. a name that /etc/hosts points at 127.0.0.1.
    log_burst, log_interval_s [s]: at most ``log_burst`` log records per message template
        per ``log_interval_s``; the next one after that names how many were suppressed.
    map_process: run the map (gate, journal, fusion, costmap) in a process of its own
        beside the HTTP front (``mapserver.service.map_process``), so the two do not share
        one interpreter's GIL; the durability promises and the journal order are the same.
    """

    keep_alive_s: float = Field(default=5.0, gt=0, le=3600, allow_inf_nan=False)
    header_timeout_s: float = Field(default=10.0, gt=0, le=3600, allow_inf_nan=False)
    body_timeout_s: float = Field(default=30.0, gt=0, le=3600, allow_inf_nan=False)
    max_connections: int = Field(default=512, gt=0)
    shutdown_timeout_s: float = Field(default=10.0, gt=0, le=3600, allow_inf_nan=False)
    local_hostnames: list[str] = []
    log_burst: int = Field(default=20, gt=0)
    log_interval_s: float = Field(default=60.0, gt=0, allow_inf_nan=False)
    map_process: bool = False


class JournalSettings(Section):
    """Durability and history.

    synchronous: SQLite's ``FULL`` (acknowledged scans survive power loss), ``NORMAL``
        or ``OFF`` (they survive a process crash only); ``mapserver.store.journal`` explains.
    snapshot_every_scans, snapshot_every_seconds [s]: snapshot the grid after this many
        scans or this long since the last snapshot, whichever comes first.
    snapshot_max_share: at most this share of wall time goes to saving snapshots: after
        one that took s seconds, the next waits at least s / snapshot_max_share seconds
        from the start of that one (``mapserver.service.snapshot_schedule``). Default
        0.1. At high scan rates on large grids, start-up then replays more scans.
    keep_snapshots: how many of the newest snapshots the journal always keeps.
    history: how many costmap versions' patches are kept for ``/v1/costmap/updates``.
    retain_seconds: [s] wall time a journaled scan is kept at least (Kafka's
        ``retention.ms``); older scans that a kept snapshot covers are deleted, in small
        batches on the snapshot thread. Default 86400 (one day: every shift of a 24/7
        site can be replayed the next day). null: no age limit.
    retain_bytes: [bytes] the journal file's used size retention cuts back to (Kafka's
        ``retention.bytes``), whichever limit comes first. Default 20 GiB: a cap that
        keeps a large site's journal within an ordinary server disk (100 units x 10 Hz x
        1,080 beams fill it in about 2 hours, docs/durability.md). null: no size limit.
        Both null: nothing is deleted, as before retention.
    quarantine_max_rows: quarantined records kept at most (the newest); those at or
        before retention's cut go with the scans. Default 10000. null: no cap.
    ``mapserver.store.retention`` has the rules; docs/durability.md how to size them.
    """

    synchronous: Literal["FULL", "NORMAL", "OFF"] = "FULL"
    snapshot_every_scans: int = Field(default=2000, gt=0)
    snapshot_every_seconds: float = Field(default=60.0, gt=0, allow_inf_nan=False)
    snapshot_max_share: float = Field(default=0.1, gt=0, le=1, allow_inf_nan=False)
    keep_snapshots: int = Field(default=2, gt=0)
    history: int = Field(default=256, gt=0)
    retain_seconds: float | None = Field(default=86400.0, ge=0, allow_inf_nan=False)
    retain_bytes: int | None = Field(default=20 << 30, ge=0)
    quarantine_max_rows: int | None = Field(default=10_000, ge=0)

    def retention(self) -> RetentionPolicy:
        """These settings as the journal's ``RetentionPolicy``."""
        return RetentionPolicy(
            self.retain_seconds, self.retain_bytes, self.keep_snapshots, self.quarantine_max_rows
        )

    @field_validator("synchronous", mode="before")
    @classmethod
    def _upper_case(cls, value: Any) -> Any:
        return value.upper() if isinstance(value, str) else value


# ---------------------------------------------------------------------------- settings
class Settings(BaseSettings):
    """All of the map server's settings; see the module docstring for where they come from.

    host, port: where to listen (port 0: any free port).
    data_dir: the journal and snapshots live here; a restart on it restores the map.
    map_yaml: a ROS map (YAML + image): gives the grid's size, resolution and origin
        (``grid`` is then ignored) and seeds the static layer.
    grid: the grid without ``map_yaml``.
    sensor_model, policy, decay: how scans become beliefs (``BeliefGrid``).
    inflation: how lethal cells inflate into the costmap.
    max_clearing_range: [m] cap on how far a no-return beam clears (None: the scan's
        own range_max), on top of ``sensor_model.no_return_range`` (the smaller wins).
    tokens: bearer tokens (``TokenSettings``); none means an open server on loopback only,
        which accepts only requests whose Host is loopback and whose Origin, if any, is.
    limits, clock, reads, server, journal, ingest: see their sections.
    """

    model_config = SettingsConfigDict(
        env_prefix="FLEETMAP_",
        env_nested_delimiter="__",
        extra="forbid",
        frozen=True,
    )

    host: str = DEFAULT_HOST
    port: int = Field(default=DEFAULT_PORT, ge=0, le=65535)
    data_dir: Path = DEFAULT_DATA_DIR
    map_yaml: Path | None = None
    grid: GridSettings = GridSettings()
    sensor_model: SensorModelSettings = SensorModelSettings()
    policy: Policy = DEFAULT_POLICY
    decay: DecaySettings = DecaySettings()
    inflation: InflationSettings = InflationSettings()
    max_clearing_range: float | None = None
    tokens: list[TokenSettings] = []
    limits: LimitsSettings = LimitsSettings()
    clock: ClockSettings = ClockSettings()
    reads: ReadSettings = ReadSettings()
    server: ServerSettings = ServerSettings()
    journal: JournalSettings = JournalSettings()
    ingest: IngestSettings = IngestSettings()

    _static_map: RosMap | None = PrivateAttr(default=None)

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        """Overrides, then ``FLEETMAP_*`` variables, then the config file (no .env files)."""
        return (init_settings, env_settings, _ConfigFileSource(settings_cls))

    @classmethod
    def from_yaml(cls, path: str | os.PathLike[str], **overrides: Any) -> Settings:
        """Settings from a YAML config file, under ``FLEETMAP_*`` variables and ``overrides``.

        Raises SettingsError when the file cannot be read or is not a YAML mapping, and
        pydantic's ValidationError when a value is invalid (``load_settings`` wraps both).
        """
        with _config_file_data(read_config_file(path)):
            return cls(**overrides)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        return mark_unknown_keys(cls, data)

    @field_validator("host")
    @classmethod
    def _host_not_empty(cls, value: str) -> str:
        if not value.strip():
            raise PydanticCustomError("host", "must be a host name or IP address")
        return value.strip()

    @model_validator(mode="after")
    def _check_whole(self) -> Settings:
        if not self.tokens and not is_loopback(self.host):
            raise error(
                ("host",),
                self.host,
                "an open server (no tokens configured) may only bind a loopback address "
                "(127.0.0.0/8, ::1, localhost); configure tokens to bind anything else",
            )
        seen: set[str] = set()
        for i, token in enumerate(self.tokens):
            secret = token.token.get_secret_value()
            if secret in seen:
                raise error(("tokens", i, "token"), None, "duplicates an earlier token")
            seen.add(secret)
        if self.map_yaml is not None:
            try:
                self._static_map = read_ros_map(self.map_yaml)
            except (MapFileError, OSError) as exc:
                raise error(("map_yaml",), str(self.map_yaml), str(exc)) from None
        try:  # the rules that join sensor model, policy, decay and clearing range
            self.belief_grid(GridGeometry(1, 1, 1.0))
        except ValueError as exc:
            raise located(self, exc) from None
        return self

    # ------------------------------------------------------------ domain objects
    @property
    def open_access(self) -> bool:
        """True when no token is configured: every request is allowed (loopback only)."""
        return not self.tokens

    def token_roles(self) -> dict[str, Role]:
        """Each configured token's secret -> its role."""
        return {secret: t.role for secret, t in self.token_table().items()}

    def token_table(self) -> dict[str, TokenSettings]:
        """Each configured token's secret -> its settings, ``name`` filled in
        (``tokens[i]`` when the config gave none)."""
        return {
            t.token.get_secret_value(): t.model_copy(update={"name": t.name or f"tokens[{i}]"})
            for i, t in enumerate(self.tokens)
        }

    def static_map(self) -> RosMap | None:
        """The map read from ``map_yaml`` at validation, or None without one."""
        return self._static_map

    def geometry(self) -> GridGeometry:
        """The grid's geometry: ``map_yaml``'s when given, else ``grid``'s."""
        if self._static_map is not None:
            return self._static_map.geometry
        return self.grid.build()

    def build_sensor_model(self) -> SensorModel:
        """The inverse sensor model."""
        return self.sensor_model.build()

    def build_decay(self) -> DecayParams:
        """The decay parameters."""
        return self.decay.build()

    def build_inflation(self) -> InflationParams:
        """The inflation parameters."""
        return self.inflation.build()

    def clearing_range(self) -> float:
        """[m] the cap on a no-return beam's clearing (inf: the scan's own range_max)."""
        return math.inf if self.max_clearing_range is None else self.max_clearing_range

    def belief_grid(self, geometry: GridGeometry | None = None) -> BeliefGrid:
        """A new, empty belief grid with these settings (on ``geometry()`` by default)."""
        return BeliefGrid(
            geometry or self.geometry(),
            sensor_model=self.build_sensor_model(),
            policy=self.policy,
            decay=self.build_decay(),
            max_clearing_range=self.clearing_range(),
        )


class _ConfigFileSource(PydanticBaseSettingsSource):
    """The config file's mapping, as ``Settings.from_yaml`` read it (lowest priority)."""

    def get_field_value(self, field: Any, field_name: str) -> tuple[Any, str, bool]:
        return _CONFIG_FILE_DATA.get().get(field_name), field_name, False

    def __call__(self) -> dict[str, Any]:
        return dict(_CONFIG_FILE_DATA.get())


@contextmanager
def _config_file_data(data: Mapping[str, Any]) -> Iterator[None]:
    token = _CONFIG_FILE_DATA.set(data)
    try:
        yield
    finally:
        _CONFIG_FILE_DATA.reset(token)


# ---------------------------------------------------------------------------- loading
_PATH_KEYS = ("data_dir", "map_yaml")


def read_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The mapping in a YAML config file, relative paths resolved against its folder.

    Raises SettingsError (field ``config``) when the file cannot be read, is not YAML or
    does not hold a mapping. An empty file is an empty mapping.
    """
    source = Path(path)
    where = f"config {source}"
    try:
        text = source.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SettingsError([f"config: cannot read the file ({exc})"], where) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SettingsError([f"config: not valid YAML ({exc})"], where) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise SettingsError(
            [f"config: must be a mapping of setting names to values, got {type(data).__name__}"],
            where,
        )
    for key in _PATH_KEYS:
        value = data.get(key)
        if isinstance(value, str) and value and not Path(value).is_absolute():
            data[key] = str(source.parent / value)
    return data


def load_settings(
    config_path: str | os.PathLike[str] | None, overrides: Mapping[str, Any]
) -> Settings:
    """Settings from an optional config file, ``FLEETMAP_*`` variables and overrides.

    overrides: values that beat everything else (the command line's flags). A None value
        means "not given" and is dropped; a dotted key sets a nested value
        (``{"sensor_model.p_hit": 0.8}``).
    Raises SettingsError listing every problem, one ``field: problem, got value`` a line.
    """
    values = _nest(overrides)
    source = f"config {config_path}" if config_path is not None else ""
    try:
        if config_path is None:
            return Settings(**values)
        return Settings.from_yaml(config_path, **values)
    except ValidationError as exc:
        fields = [(f, m + _variable_note(f, values)) for f, m in located_errors(exc)]
        raise SettingsError([f"{f}: {m}" for f, m in fields], source, fields) from None
    except EnvironmentValueError as exc:  # a variable of a list or section that is no JSON
        raise SettingsError([_unreadable_variable(exc)], source) from None


def located_errors(exc: ValidationError) -> list[tuple[str, str]]:
    """(field, ``problem, got value``) per pydantic error (token secrets hidden)."""
    found = problems(exc, "settings", hidden=lambda loc: bool(loc) and loc[-1] == "token")
    return [(dotted(p.loc, "settings"), p.detail()) for p in found]


def variable_of(field: str, overrides: Mapping[str, Any]) -> str | None:
    """The ``FLEETMAP_*`` variable (as the environment spells it) that gave ``field``
    (dotted, ``sensor_model.p_hit``, ``tokens[0].role``), or the section holding it
    (``FLEETMAP_SENSOR_MODEL`` as JSON); None when ``overrides`` (nested: the flags) gave
    it, which beat the variables, or no variable names it."""
    parts = [p for p in re.split(r"[.\[\]]", field) if p and not p.isdigit()]
    given: Any = overrides
    for part in parts:
        if not isinstance(given, Mapping) or part not in given:
            break
        given = given[part]
    else:
        return None
    variables = {name.upper(): name for name in os.environ}
    for n in range(len(parts), 0, -1):
        name = variables.get("FLEETMAP_" + "__".join(parts[:n]).upper())
        if name is not None:
            return name
    return None


def _variable_note(field: str, overrides: Mapping[str, Any]) -> str:
    """`` (set by FLEETMAP_X: ...)`` when a variable gave ``field``'s value, else ``""``."""
    name = variable_of(field, overrides)
    return "" if name is None else f" (set by the environment variable {name}: correct or unset it)"


def _unreadable_variable(exc: EnvironmentValueError) -> str:
    """The problem of a ``FLEETMAP_*`` variable pydantic-settings could not decode as JSON
    (a list or a section), naming it and what it must hold."""
    found = re.search(r'field "(\w+)"', str(exc))
    field = found.group(1) if found else "?"
    prefix = f"FLEETMAP_{field}".upper()
    names = sorted(n for n in os.environ if n.upper().startswith(prefix)) or [prefix]
    cause = exc.__cause__ or exc
    return (
        f"{', '.join(names)}: not valid JSON ({cause}) ({field} holds a list or mapping: "
        f'give it as JSON, e.g. FLEETMAP_TOKENS=\'[{{"token": "s3cret", "role": '
        f'"admin"}}]\', or unset it)'
    )


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    name = host.strip().strip("[]").lower()
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def _nest(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Drop None values and expand dotted keys into nested mappings."""
    nested: dict[str, Any] = {}
    for key, value in overrides.items():
        if value is None:
            continue
        *parents, leaf = key.split(".")
        target = nested
        for part in parents:
            target = target.setdefault(part, {})
        target[leaf] = value
    return nested
