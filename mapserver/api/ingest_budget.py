"""Fair ingest: each unit, and each token, may post at most its budget of beams and scans
per second (token buckets with a burst); beyond it a scan request is refused with 429 and
``Retry-After`` before it reaches the ingest queue (docs/server-safety.md, "Fair ingest").

A bucket holds up to ``rate x burst_s`` of each limit (beams, scans), starts full and
refills at ``rate`` per second. A request costing ``c`` passes when the bucket holds at
least ``min(c, capacity)`` and then takes ``c``, so the level may go below zero: a
request larger than the whole burst (a backlog batch) still passes from a full bucket,
and the unit then waits off the debt. A refused request takes nothing. ``Retry-After`` is
the whole seconds until the bucket holds the request's need again (at least 1).

Buckets are kept per key (``unit:<id>``, ``token:<name>``) in last-use order; a bucket
that has refilled to full is the same as none, so it is dropped (``expire``), and at
most ``max_tracked`` are kept (the least recently used goes first): memory stays bounded
however many unit ids a client makes up. A full bucket dropped early only ever helps the
unit it belonged to.

``clock`` (monotonic seconds) is passed in; tests use a fake one.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from fastapi import Request

from mapserver.api.admission import too_many
from mapserver.core.errors import FleetmapError
from mapserver.core.scan import Scan
from mapserver.service.settings import IngestSettings

UNIT = "unit"
TOKEN = "token"
LIMITS = ("beams", "scans")


@dataclass(frozen=True)
class Budget:
    """One scope's limits: ``beams_per_s`` and ``scans_per_s`` (None: that limit is off),
    ``burst_s`` [s] of each kept in the bucket; ``settings`` names the settings (e.g.
    ``ingest.unit``) for messages."""

    beams_per_s: float | None
    scans_per_s: float | None
    burst_s: float
    settings: str

    def rates(self) -> tuple[float | None, float | None]:
        """(beams/s, scans/s), each None when off."""
        return (self.beams_per_s or None, self.scans_per_s or None)

    @property
    def enabled(self) -> bool:
        """True when at least one limit is on."""
        return any(rate is not None for rate in self.rates())


class Throttled(FleetmapError, Exception):
    """A request past a budget: ``retry_after_s`` [whole s] and a message naming the unit
    or token, its rate and the setting."""

    def __init__(self, scope: str, limit: str, retry_after_s: int, message: str) -> None:
        self.scope = scope  # UNIT or TOKEN
        self.limit = limit  # "beams" or "scans"
        self.retry_after_s = retry_after_s
        super().__init__(message)


@dataclass
class _Bucket:
    levels: list[float]  # beams, scans: what the bucket holds at ``at``
    at: float  # [s] clock time the levels were computed
    since: float  # [s] when the bucket was made (for the rate in messages)
    spent: list[float]  # beams, scans taken since ``since``


class IngestBudget:
    """Per-unit and per-token buckets (see the module docstring).

    unit, token: the budgets; a token's applies to everything posted with that token,
    whichever units it posts as. clock: monotonic seconds. max_tracked: buckets kept.
    """

    def __init__(
        self,
        unit: Budget,
        token: Budget,
        clock: Callable[[], float],
        max_tracked: int = 100_000,
    ) -> None:
        if max_tracked < 1:
            raise ValueError(f"max_tracked must be >= 1, got {max_tracked}")
        self.budgets = {UNIT: unit, TOKEN: token}
        self.clock = clock
        self.max_tracked = max_tracked
        self._buckets: OrderedDict[tuple[str, str], _Bucket] = OrderedDict()

    def __len__(self) -> int:
        """Buckets tracked now (not yet refilled to full)."""
        return len(self._buckets)

    def check(
        self, token: str | None, units: Iterable[tuple[str, int]], charge: bool = True
    ) -> None:
        """Admit a request posted with ``token`` (its name; None on an open server) holding
        scans of ``units``, (unit id, beams) each; raise Throttled if any unit or the token
        is past its budget. ``charge``: take the cost (all buckets or none), else only look.
        """
        now = self.clock()
        costs: dict[tuple[str, str], list[float]] = {}
        for unit_id, beams in units:
            if self.budgets[UNIT].enabled:
                cost = costs.setdefault((UNIT, unit_id), [0.0, 0.0])
                cost[0] += beams
                cost[1] += 1
            if token is not None and self.budgets[TOKEN].enabled:
                cost = costs.setdefault((TOKEN, token), [0.0, 0.0])
                cost[0] += beams
                cost[1] += 1
        for key, cost in costs.items():
            self._refuse_past(key, cost, now)
        if charge:
            for key, cost in costs.items():
                bucket = self._bucket(key, now)
                for i in range(2):
                    bucket.levels[i] -= cost[i]
                    bucket.spent[i] += cost[i]
            self.expire(now)

    def check_token(self, token: str | None) -> None:
        """Before a request's body is read: Throttled when ``token``'s bucket cannot admit
        even one scan of one beam (it is in debt), so its body need not be read at all."""
        if token is not None and self.budgets[TOKEN].enabled:
            self._refuse_past((TOKEN, token), [1.0, 1.0], self.clock())

    def expire(self, now: float) -> None:
        """Drop the buckets that have refilled to full by ``now``, and the least recently
        used past ``max_tracked``."""
        while self._buckets:
            key, bucket = next(iter(self._buckets.items()))
            if len(self._buckets) <= self.max_tracked and not self._full(key, bucket, now):
                break
            del self._buckets[key]

    # ------------------------------------------------------------------ internals
    def _capacity(self, scope: str) -> list[float | None]:
        budget = self.budgets[scope]
        return [None if r is None else r * budget.burst_s for r in budget.rates()]

    def _full(self, key: tuple[str, str], bucket: _Bucket, now: float) -> bool:
        """True when the bucket has refilled to its capacity in every limit by ``now``."""
        rates = self.budgets[key[0]].rates()
        return all(
            bucket.levels[i] + (now - bucket.at) * rate >= cap
            for i, (rate, cap) in enumerate(zip(rates, self._capacity(key[0]), strict=True))
            if rate is not None and cap is not None
        )

    def _bucket(self, key: tuple[str, str], now: float) -> _Bucket:
        """The key's bucket refilled to ``now`` (a new, full one if none), now most
        recently used."""
        capacity = self._capacity(key[0])
        bucket = self._buckets.get(key)
        if bucket is None:
            full = [math.inf if cap is None else cap for cap in capacity]
            bucket = self._buckets[key] = _Bucket(full, now, now, [0.0, 0.0])
        else:
            rates = self.budgets[key[0]].rates()
            for i, (rate, cap) in enumerate(zip(rates, capacity, strict=True)):
                if rate is not None and cap is not None:
                    bucket.levels[i] = min(cap, bucket.levels[i] + (now - bucket.at) * rate)
            bucket.at = now
            self._buckets.move_to_end(key)
        return bucket

    def _refuse_past(self, key: tuple[str, str], cost: list[float], now: float) -> None:
        """Raise Throttled when the key's bucket holds less than ``min(cost, capacity)``
        in a limit (looking only: a key without a bucket has a full one)."""
        bucket = self._buckets.get(key)
        if bucket is None:
            return
        scope, name = key
        budget = self.budgets[scope]
        capacity = self._capacity(scope)
        for i, rate in enumerate(budget.rates()):
            cap = capacity[i]
            if rate is None or cap is None:
                continue
            level = min(cap, bucket.levels[i] + (now - bucket.at) * rate)
            need = min(cost[i], cap)
            if level >= need:
                continue
            limit = LIMITS[i]
            wait = max(1, math.ceil((need - level) / rate))
            age = max(now - bucket.since, 1.0)
            who = f"unit {name!r}" if scope == UNIT else f"token {name!r}"
            raise Throttled(
                scope,
                limit,
                wait,
                f"{'unit_id' if scope == UNIT else 'authorization'}: {who} posted "
                f"{bucket.spent[i]:.0f} {limit} in the last {age:.0f} s "
                f"({bucket.spent[i] / age:.0f} {limit}/s), past its budget of {rate:g} "
                f"{limit}/s ({budget.settings}_{limit}_per_s) with a burst of "
                f"{budget.burst_s:g} s (ingest.burst_s); this request needs "
                f"{cost[i]:.0f} {limit}; retry after {wait} s",
            )


def budget_from_settings(settings: IngestSettings, clock: Callable[[], float]) -> IngestBudget:
    """The budgets of the ``ingest`` settings section."""
    unit = Budget(settings.unit_beams_per_s, settings.unit_scans_per_s, settings.burst_s,
                  "ingest.unit")  # fmt: skip
    token = Budget(settings.token_beams_per_s, settings.token_scans_per_s, settings.burst_s,
                   "ingest.token")  # fmt: skip
    return IngestBudget(unit, token, clock, settings.max_tracked)


# ---------------------------------------------------------------- the scan routes' hooks
def refuse_token_in_debt(request: Request) -> None:
    """Before the body is read: 429 when the request's token is past its budget."""
    _enforce(request, lambda budget, token: budget.check_token(token))


def look(request: Request, items: Sequence[Any]) -> None:
    """After the body is parsed, before the scans are validated: 429 when a unit a scan
    names (or the token) is past its budget; nothing is taken (the ids are unchecked)."""
    claims = [_claim(item) for item in items]
    _enforce(request, lambda budget, token: budget.check(token, filter(None, claims), False))


def charge(request: Request, scans: Sequence[Scan]) -> None:
    """The validated scans, before they are queued: take their cost, or 429."""
    claims = [(scan.unit_id, scan.beam_count) for scan in scans]
    _enforce(request, lambda budget, token: budget.check(token, claims))


def _enforce(request: Request, check: Callable[[IngestBudget, str | None], None]) -> None:
    """``check(the app's budget, the request's token name)``; Throttled becomes the
    server's 429 with ``Retry-After``, counted in ``fleetmap_scans_throttled``."""
    token = request.state.token
    try:
        check(request.app.state.ingest_budget, None if token is None else token.name)
    except Throttled as exc:
        request.app.state.metrics.scans_throttled.labels(exc.scope, exc.limit).inc()
        raise too_many(str(exc), exc.retry_after_s) from None


def _claim(item: Any) -> tuple[str, int] | None:
    """(unit id, beams) a scan mapping claims, unvalidated; None when it names no unit
    (validation then refuses it)."""
    if not isinstance(item, Mapping) or not isinstance(item.get("unit_id"), str):
        return None
    ranges = item.get("ranges")
    return item["unit_id"], len(ranges) if hasattr(ranges, "__len__") else 0
