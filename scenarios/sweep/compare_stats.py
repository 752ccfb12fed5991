"""Statistics of ``fleetmap compare``: a metric's mean and 95 % interval over seeds, and
whether two policies differ beyond that noise.

The interval is Student's t interval for the mean: ``mean ± t(0.975, n-1) * s / sqrt(n)``
with ``s`` the sample standard deviation (n-1 in the denominator) of the n values, one per
seed. One value gives a mean and no interval. Units are the metric's own.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from scipy.stats import t as student_t

from scenarios.score.metric_registry import Better

__all__ = ["CONFIDENCE", "Summary", "summarise", "verdict"]

CONFIDENCE = 0.95


@dataclass(frozen=True)
class Summary:
    """``n`` values' ``mean`` and the half-width of their 95 % interval (``half_width``,
    None when n < 2: one value gives no interval); ``n`` 0 means no value (mean NaN)."""

    n: int
    mean: float
    half_width: float | None


def summarise(values: Sequence[float]) -> Summary:
    """The mean of ``values`` and its Student's t 95 % interval (module docstring)."""
    n = len(values)
    if n == 0:
        return Summary(0, math.nan, None)
    mean = math.fsum(values) / n
    if n == 1:
        return Summary(1, mean, None)
    variance = math.fsum((v - mean) ** 2 for v in values) / (n - 1)
    quantile = float(student_t.ppf(0.5 + CONFIDENCE / 2, n - 1))
    return Summary(n, mean, quantile * math.sqrt(variance) / math.sqrt(n))


def verdict(candidate: Summary, baseline: Summary, better: Better) -> str:
    """``better`` or ``worse`` when the two 95 % intervals do not overlap (``candidate``
    is better when its mean is lower with ``Better.LOWER``, higher with
    ``Better.HIGHER``; ``lower`` or ``higher`` with ``Better.NEITHER``), else ``~``
    (overlapping, or a side without an interval: no difference beyond noise)."""
    if candidate.half_width is None or baseline.half_width is None:
        return "~"
    if candidate.mean + candidate.half_width < baseline.mean - baseline.half_width:
        side = Better.LOWER
    elif candidate.mean - candidate.half_width > baseline.mean + baseline.half_width:
        side = Better.HIGHER
    else:
        return "~"
    if better is Better.NEITHER:
        return side.value
    return "better" if side is better else "worse"
