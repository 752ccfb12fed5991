"""The inverse sensor model, the map policies and their parameters.

Log-odds ``L = log(p / (1 - p))``. A scan adds, to each cell it observes, once:
``L <- L + l(z) - L0`` where ``l(z)`` is ``l_hit = logit(p_hit)`` for the cell holding a
return and ``l_miss = logit(p_miss)`` for a cell a beam passes through, and
``L0 = logit(prior)`` is the prior, subtracted once per update so it never accumulates.
Then ``L`` is clamped to ``[clamp_min, clamp_max]`` so that a wrong cell can recover
(Thrun, Burgard, Fox, *Probabilistic Robotics*, 2005, table 9.1; Hornung et al.,
*OctoMap*, Autonomous Robots 2013, eq. 2-4 for the clamping).

Defaults (docs/commands.md), in both units:

- ``p_hit = 0.7``   # = +0.847 log-odds per return
- ``p_miss = 0.4``  # = -0.405 log-odds per pass-through
- ``clamp_min = -5.0``  # = p 0.0067: 6 returns (of +0.847) to flip a saturated free cell
- ``clamp_max = +5.0``  # = p 0.9933: 13 passes to flip a saturated occupied cell
- ``occupied_threshold = 0.65``  # = +0.619 log-odds
- ``free_threshold = 0.25``      # = -1.099 log-odds
- ``p_miss_no_return = 0.45``  # = -0.201 log-odds per no-return pass, half of p_miss's
- ``no_return_range = 1.0``    # [m] how far a no-return beam clears: the unit's own
  surroundings, not through the rack across a 2 m aisle (docs/no-return.md measures it)
- ``fill_between_beams = True``  # clear the cells between two neighbouring returns that
  neither beam crosses (1 degree beams are a 0.1 m cell apart at 5.7 m), so a moved
  obstacle's old place clears in under 2 s from a passing unit (docs/clearing.md)
- ``guard_glancing_faces = True``  # a return glancing along a face stops clearing a cell
  (square to the face) short of it, so the face's cells are not worn away by the passes
  of beams that hit it farther on (docs/clearing.md)

A no-return beam (REP 117: a range > range_max or +inf) reads nothing: the sensor saw no
surface, or it dropped the beam (dust, a black or shiny surface, a glancing angle). It is
weak evidence of free space, so it has a miss probability of its own, closer to the
prior, and clears only out to ``no_return_range`` (OctoMap's ``maxrange`` for insertion,
Nav2's ``inf_is_valid`` + ``raytrace_max_range``); docs/no-return.md has the arithmetic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from enum import StrEnum
from typing import Any

from mapserver.core.errors import FieldError


def logit(p: float) -> float:
    """Log-odds of probability p (0 < p < 1)."""
    return math.log(p / (1.0 - p))


def sigmoid(log_odds: float) -> float:
    """Probability of log-odds L."""
    return 1.0 / (1.0 + math.exp(-log_odds))


class Policy(StrEnum):
    """How evidence accumulates and ages (docs/commands.md).

    - ``decay``: clamped log-odds whose evidence fades toward the prior with time since
      the cell was last observed (the default before ``dual``).
    - ``binary``: the Nav2 obstacle-layer baseline: last ray wins; a return marks the cell
      occupied (``clamp_max``), a pass clears it (``clamp_min``); no decay; a no-return
      beam is a pass out to ``range_max`` (Nav2 with ``inf_is_valid: true``).
    - ``sticky``: log-odds with no clamp and no decay.
    - ``dual`` (the default, ``DEFAULT_POLICY``): structure and transients told apart
      per cell by its history (docs/dual.md): a *new* cell as ``decay``, its hits
      fading with ``transient_half_life``; one hit by ``confirm_hits`` scans in a row is
      *structure*, clamped log-odds that no longer fade while unobserved; one seen free
      for good (``void_threshold``) is *void*, where what appears is transient: the last
      ray wins, as in ``binary``, so one pass clears it, and a hit fades as a new cell's.
    """

    DECAY = "decay"
    BINARY = "binary"
    STICKY = "sticky"
    DUAL = "dual"

    @classmethod
    def parse(cls, value: str | Policy) -> Policy:
        """The policy named ``value``; ValueError naming the choices otherwise."""
        try:
            return cls(value)
        except ValueError:
            choices = ", ".join(p.value for p in cls)
            raise FieldError("policy", value, f"must be one of {choices}") from None


DEFAULT_POLICY = Policy.DUAL
"""The policy a server, a scenario, ``map build`` and a ``BeliefGrid`` use unless told
(a data dir opens under the policy its map settings recorded)."""

# Kernel codes for the policies (numba kernels take integers, not enums): the one table;
# ``fusion_kernel``'s ``POLICY_*`` constants are read from it.
POLICY_CODES = {Policy.DECAY: 0, Policy.BINARY: 1, Policy.STICKY: 2, Policy.DUAL: 3}


def _probability(name: str, value: float) -> float:
    if not (isinstance(value, int | float) and 0.0 < value < 1.0):
        raise FieldError(name, value, "must be a probability strictly between 0 and 1")
    return float(value)


@dataclass(frozen=True)
class SensorModel:
    """Inverse sensor model and state thresholds; validated on construction.

    Each field's description below (``name: text``, continued on more indented lines) is
    also its ``--name`` flag's help in ``fleetmap map build`` and ``evaluate``.

    p_hit: probability that a cell holding a return is occupied (> 0.5).
    p_miss: probability that a cell a beam passes through is occupied (< 0.5).
    prior: occupancy probability before any evidence (L0 = logit(prior)).
    clamp_min: [log-odds] floor of a cell's log-odds (below L0), so that a wrong free
        cell can recover.
    clamp_max: [log-odds] ceiling of a cell's log-odds (above L0), so that a wrong
        occupied cell can recover.
    occupied_threshold: a cell with p > this is occupied (> prior).
    free_threshold: a cell with p < this is free (< prior); between the two it is unknown,
        so evidence fading toward the prior can only turn a known cell unknown.
    p_miss_no_return: probability that a cell only no-return beams pass through is
        occupied, in [p_miss, prior]; prior: no-return beams change nothing.
    no_return_range: [m] how far a no-return beam clears (capped by the scan's
        range_max); None: out to range_max.
    fill_between_beams: where neighbouring beams are more than a cell apart, also clear
        the cells between two neighbouring returns, up to one cell short of the surface
        the two outline (log-odds policies only; docs/clearing.md).
    guard_glancing_faces: a return stops clearing where it comes within one cell of the
        surface it hit, square to that surface, so beams glancing along a face do not
        wear away the face cells square beams hit (log-odds policies only;
        docs/clearing.md).
    void_threshold: probability (below ``free_threshold``) under which a cell counts as
        seen free for good under the ``dual`` policy: from then on it is *void* space,
        where whatever appears is transient (docs/dual.md). The default, 0.05 (-2.94
        log-odds), takes 8 net passes from the prior: more than range noise or a
        grazing beam gives a wall cell, fewer than a floor cell gets from one unit
        driving by.
    confirm_hits: under ``dual``, the scans in a row (no pass between) whose returns
        make a new cell structure, whose evidence then no longer fades: a unit driving
        past a rack face at 1.5 m/s hits its cells with 10 to 30 scans; a person walking
        through a cell, with 1 to 5 per unit that sees them (docs/dual.md).
    confirm_after: [s] under ``dual``, a new cell hit again, with no pass since, at least
        this long after it was last observed is structure too: it stayed where it was. This
        confirms what a slow recording (a scan every few seconds) sees in fewer scans.
    confirm_within: [s] under ``dual``, the longest gap after which a new cell hit again
        still counts as having stayed (``confirm_after``), >= ``confirm_after``. After a
        longer one, with nobody looking, a person walking the same line again is as
        likely as a wall. The default, 60 s, is two of decay's occupied half lives
        (``DecayParams.half_life_occupied``): by then a new cell's first evidence has
        faded to a quarter, and counting it as proof of staying would contradict the fade.
    release_margin: [m] under ``dual``, structure is released (a new cell again, what it
        held dropped) by two scans in a row whose returns cross it and end at least this
        far beyond it, with no hit between (DUFOMap's shortened rays, Duberg et al.,
        RA-L 2024): a pod or a person that stood long enough to be confirmed, then left.
        Passes nearer their endpoint, where range noise and pose error put a face's own
        cells, do not release it. The default, 0.3 m, is 15 sigma of 2 cm range noise
        and three 0.1 m cells.
    transient_half_life: [s] under ``dual``, the fade half life of a transient's
        occupancy evidence while nobody observes its cell: a new cell's (not yet
        confirmed structure) and a void cell's hit (what appears in space seen free). A
        transient is held while it is seen and for a short while after, as the
        Spatio-Temporal Voxel Layer expires its voxels (Macenski et al., IJARS 2020);
        structure never fades. The default, 5 s: a saturated hit (+5) is no longer
        occupied after 15 s unobserved, where decay's 30 s half life takes 90 s.
    """

    p_hit: float = 0.7
    p_miss: float = 0.4
    prior: float = 0.5
    clamp_min: float = -5.0
    clamp_max: float = 5.0
    occupied_threshold: float = 0.65
    free_threshold: float = 0.25
    p_miss_no_return: float = 0.45
    no_return_range: float | None = 1.0
    fill_between_beams: bool = True
    guard_glancing_faces: bool = True
    void_threshold: float = 0.05
    confirm_hits: int = 10
    confirm_after: float = 2.0
    confirm_within: float = 60.0
    release_margin: float = 0.3
    transient_half_life: float = 5.0

    def __post_init__(self) -> None:
        for name in ("fill_between_beams", "guard_glancing_faces"):
            if not isinstance(getattr(self, name), bool):
                raise FieldError(name, getattr(self, name), "must be true or false")
        for name in (
            "p_hit", "p_miss", "prior", "occupied_threshold", "free_threshold", "void_threshold"
        ):  # fmt: skip
            _probability(name, getattr(self, name))
        hits = self.confirm_hits
        if isinstance(hits, bool) or not isinstance(hits, int) or not 1 <= hits <= 252:
            raise FieldError("confirm_hits", hits, "must be a whole number of scans, 1 to 252")
        margin = self.release_margin
        if not (isinstance(margin, int | float) and math.isfinite(margin) and margin > 0):
            raise FieldError("release_margin", margin, "must be a positive distance in metres")
        half_life = self.transient_half_life
        if not (isinstance(half_life, int | float) and math.isfinite(half_life) and half_life > 0):
            raise FieldError("transient_half_life", half_life, "must be positive seconds")
        after = self.confirm_after
        if not (isinstance(after, int | float) and math.isfinite(after) and after > 0):
            raise FieldError("confirm_after", after, "must be positive seconds")
        within = self.confirm_within
        if not (isinstance(within, int | float) and math.isfinite(within) and within >= after):
            raise FieldError(
                "confirm_within", within, f"must be seconds, at least confirm_after ({after})"
            )
        if not self.void_threshold < self.free_threshold:
            raise FieldError(
                "void_threshold",
                self.void_threshold,
                f"must be below free_threshold ({self.free_threshold}): a cell counts as "
                "seen free for good only once it is free",
            )
        _probability("p_miss_no_return", self.p_miss_no_return)
        if not self.p_hit > self.prior:
            raise FieldError("p_hit", self.p_hit, f"must be greater than the prior ({self.prior})")
        if not self.p_miss < self.prior:
            raise FieldError("p_miss", self.p_miss, f"must be less than the prior ({self.prior})")
        if not self.p_miss <= self.p_miss_no_return <= self.prior:
            raise FieldError(
                "p_miss_no_return",
                self.p_miss_no_return,
                f"must be between p_miss ({self.p_miss}) and the prior ({self.prior}): a beam "
                "that reads nothing is no stronger evidence than one that returned",
            )
        value = self.no_return_range
        if value is not None and not (isinstance(value, int | float) and value > 0):
            raise FieldError("no_return_range", value, "must be a positive range in metres or None")
        for name in ("clamp_min", "clamp_max"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise FieldError(name, value, "must be a finite log-odds value")
        if not self.clamp_min < self.l0:
            raise FieldError(
                "clamp_min", self.clamp_min, f"must be below the prior's log-odds ({self.l0:.3f})"
            )
        if not self.clamp_max > self.l0:
            raise FieldError(
                "clamp_max", self.clamp_max, f"must be above the prior's log-odds ({self.l0:.3f})"
            )
        if not self.free_threshold < self.prior:
            raise FieldError(
                "free_threshold",
                self.free_threshold,
                f"must be below the prior ({self.prior}) so that a cell at the prior is unknown",
            )
        if not self.occupied_threshold > self.prior:
            raise FieldError(
                "occupied_threshold",
                self.occupied_threshold,
                f"must be above the prior ({self.prior}) so that a cell at the prior is unknown",
            )

    @property
    def l_hit(self) -> float:
        """[log-odds] evidence of one return."""
        return logit(self.p_hit)

    @property
    def l_miss(self) -> float:
        """[log-odds] evidence of one pass-through (negative)."""
        return logit(self.p_miss)

    @property
    def l_miss_no_return(self) -> float:
        """[log-odds] evidence of one no-return pass (between l_miss and l0)."""
        return logit(self.p_miss_no_return)

    @property
    def no_return_cap(self) -> float:
        """[m] how far a no-return beam clears at most (inf: the scan's range_max)."""
        return math.inf if self.no_return_range is None else float(self.no_return_range)

    @property
    def l0(self) -> float:
        """[log-odds] the prior."""
        return logit(self.prior)

    @property
    def l_occupied(self) -> float:
        """[log-odds] a cell is occupied above this."""
        return logit(self.occupied_threshold)

    @property
    def l_free(self) -> float:
        """[log-odds] a cell is free below this."""
        return logit(self.free_threshold)

    @property
    def l_void(self) -> float:
        """[log-odds] below this a cell is void for good (the ``dual`` policy)."""
        return logit(self.void_threshold)


@dataclass(frozen=True)
class DecayParams:
    """Freshness decay of the ``decay`` policy.

    Evidence fades toward the prior with the time since the cell was last observed:
    ``L(t) = L0 + (L - L0) * 2 ** (-(t - last_observed) / half_life)``. Each field's
    description below is also its ``--name`` flag's help (as ``SensorModel``'s).

    half_life_occupied: [s] fade half life of evidence above the prior (the ``decay``
        policy, and a new cell's under ``dual``).
    half_life_free: [s] fade half life of evidence below the prior (as above).
    fade_bound: [log-odds] a cell whose faded evidence (its distance from the prior) is
        below this is unknown again, as if never observed; below the thresholds'
        distance from the prior.
    """

    half_life_occupied: float = 30.0
    half_life_free: float = 120.0
    fade_bound: float = 0.05

    def __post_init__(self) -> None:
        for name in ("half_life_occupied", "half_life_free", "fade_bound"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise FieldError(name, value, "must be a positive finite number")


# ---------------------------------------------------------------------------- old records
class Recorded(str):
    """In ``LEGACY_SENSOR_MODEL``: the value the old record itself holds under this name."""

    __slots__ = ()


_DEFAULTS: dict[str, Any] = {f.name: f.default for f in fields(SensorModel)}

LEGACY_SENSOR_MODEL: tuple[dict[str, Any], ...] = (
    # Before no-return beams had evidence of their own (docs/no-return.md) a journal was
    # fused with no-return beams as strong as returns (p_miss) out to range_max (None).
    {"p_miss_no_return": Recorded("p_miss"), "no_return_range": None},
    # Before the fill between beams and the guard of glancing faces (docs/clearing.md):
    # beams only.
    {"fill_between_beams": False, "guard_glancing_faces": False},
    # Before the ``dual`` policy (docs/dual.md), which alone reads these: today's defaults.
    {name: _DEFAULTS[name] for name in ("void_threshold", "confirm_hits", "confirm_after")},
    # Before ``dual`` bounded the confirm-after gap and released structure seen clear
    # through (docs/dual.md): today's defaults
    # (dual's history rules changed with it; such a dir replays under today's).
    {name: _DEFAULTS[name] for name in ("confirm_within", "release_margin")},
    # Before ``dual``'s transients faded with a half life of their own and void cells'
    # hits faded too (docs/dual.md): today's default (such a dir replays under it).
    {"transient_half_life": _DEFAULTS["transient_half_life"]},
)
"""The values a sensor model recorded before a field existed was fused under, one
mapping per change that added fields, oldest first (``fill_legacy_sensor_model``)."""


def fill_legacy_sensor_model(model: dict[str, Any]) -> dict[str, Any]:
    """Fill in, in place, the fields an old record of a sensor model (a data dir's map
    settings) lacks, with the values its journal was fused under (``LEGACY_SENSOR_MODEL``),
    so that the dir opens under those settings, not today's defaults; returns ``model``.

    A field the record holds is kept. A change whose values refer to a field the record
    does not hold (``Recorded``) fills nothing: such a record was not written by a server.
    """
    for added in LEGACY_SENSOR_MODEL:
        sources = [value for value in added.values() if isinstance(value, Recorded)]
        if all(source in model for source in sources):
            for name, value in added.items():
                model.setdefault(name, model[value] if isinstance(value, Recorded) else value)
    return model
