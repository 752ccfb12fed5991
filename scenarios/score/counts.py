"""The run's freeze and plan counts, as ``metrics.json`` (docs/files.md 3) and the replay's
``/metrics`` carry them.

Freezes are split in time (``planner.freeze``): ``phantom_freeze_seconds`` and
``true_block_seconds`` sum their segments of each kind; ``phantom_freezes`` counts the
freezes with phantom seconds and ``true_block_freezes`` those with true-block seconds,
so a freeze with both (a unit held at a pod that is moved away while it waits) counts
once in each. Plans (``planner.plan_safety``): ``stale_free_plans`` those whose legs
cross a truly lethal cell, ``inscribed_plans`` those that cross a truly inscribed cell
and no lethal one (the unit's body would touch an obstacle).
"""

from __future__ import annotations

from collections.abc import Sequence

from planner.freeze import PHANTOM, TRUE_BLOCK
from scenarios.run.record import FreezeRecord, PlanSample
from scenarios.score.metric_registry import feeds

SECONDS_DECIMALS = 3  # [s] 1 ms


@feeds("phantom_freezes", "phantom_freeze_seconds", "true_block_freezes", "true_block_seconds")
def freeze_counts(
    freezes: Sequence[FreezeRecord], until: float | None = None
) -> dict[str, int | float]:
    """The freeze metrics (module docstring) of ``freezes``; with ``until`` [s], as they
    stood then: the freezes begun by then, their seconds up to then."""
    begun = [f for f in freezes if until is None or f.start <= until]
    phantom = [f.seconds(PHANTOM, until) for f in begun]
    true = [f.seconds(TRUE_BLOCK, until) for f in begun]
    return {
        "phantom_freezes": sum(1 for s in phantom if s > 0),
        "phantom_freeze_seconds": round(sum(phantom), SECONDS_DECIMALS),
        "true_block_freezes": sum(1 for s in true if s > 0),
        "true_block_seconds": round(sum(true), SECONDS_DECIMALS),
    }


@feeds("stale_free_plans", "inscribed_plans")
def plan_counts(plans: Sequence[PlanSample]) -> dict[str, int]:
    """``stale_free_plans`` and ``inscribed_plans`` of ``plans`` (module docstring)."""
    return {
        "stale_free_plans": sum(1 for p in plans if p.stale_free),
        "inscribed_plans": sum(1 for p in plans if p.inscribed),
    }
