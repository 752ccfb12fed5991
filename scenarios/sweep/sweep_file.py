"""A sweep file and the runs it expands to (``fleetmap sweep``, docs/commands.md).

A sweep file is YAML::

    scenarios: [moved_pod.yaml, ../scenarios/tiny.yaml]   # relative to the sweep file
    policies: [decay, binary, sticky]      # optional; default: all three
    seeds: [0, 1]                          # or {count: 3, start: 0}; default: [0]
    parameters:                            # optional grid: every combination is run
      map_server.decay.half_life_occupied: [10, 30, 120]
    duration: 60                           # optional [s]: overrides every scenario's

It expands (``expand``) to one ``SweepRun`` per scenario x policy x parameter
combination x seed, in that nesting order (file order within each), so the same file
always gives the same runs in the same order. Every run has its own output folder
``<scenario>/<policy>/<key=value__...>/seed<k>`` (no parameter part when the grid is
empty). Errors are ``ScenarioError`` naming the sweep file, the line and the field
(``sweep.yaml:4: seeds.count: must be an integer >= 1, got 0``).
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from pydantic import Discriminator, Field

from mapserver.core.sensor_model import DEFAULT_POLICY, Policy
from mapserver.service.validation import Section, number, reworded, text, variant, variant_tag
from scenarios.spec.scenario import load_scenario
from scenarios.spec.server import PolicyName
from scenarios.spec.yaml_lines import Document, ScenarioError, parse_yaml

__all__ = ["ScenarioError", "Sweep", "SweepRun", "expand", "load_sweep", "parse_sweep"]

DEFAULT_POLICIES = (DEFAULT_POLICY.value, *(p.value for p in Policy if p is not DEFAULT_POLICY))
"""The policies a sweep or a compare runs unless told: the default and the three
baselines the README's tables measure."""
MAX_RUNS = 100_000
_PARAM_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")
_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]")

Scalar = bool | int | float | str


# ---------------------------------------------------------------------------- the file
class SeedRange(Section):
    """``seeds: {count, start}``: seeds start, start + 1, ..., count of them."""

    count: number(integer=True, ge=1, le=MAX_RUNS)
    start: number(integer=True, ge=0) = 0


Seeds = Annotated[
    variant(SeedRange, "range") | variant(list[number(integer=True, ge=0)], "list"),
    Discriminator(
        lambda v: variant_tag({dict: "range", list: "list"}.get(type(v))),
        custom_error_type="seeds",
        custom_error_message="must be a list of integers or {count, start}",
    ),
]
ParameterValue = Annotated[
    bool | int | Annotated[float, Field(allow_inf_nan=False)] | str,
    reworded("must be a number, string or boolean"),
]


class SweepFile(Section):
    """A sweep file as written (module docstring); ``parse_sweep`` checks the rest."""

    scenarios: list[text("a scenario file path")]
    policies: list[PolicyName] | None = None
    seeds: Seeds | None = None
    parameters: dict[str, list[ParameterValue]] | None = None
    duration: number("seconds", gt=0) | None = None


@dataclass(frozen=True)
class SweepRun:
    """One run of a sweep.

    scenario: the scenario file (resolved against the sweep file's folder); name: its
    stem (the first folder of the run's outputs); policy: ``decay``/``binary``/``sticky``;
    seed: the run's seed; parameters: (dotted scenario key, value) in file order;
    duration: [s] sim time override, None for the scenario's own.
    """

    scenario: Path
    name: str
    policy: str
    seed: int
    parameters: tuple[tuple[str, Scalar], ...] = ()
    duration: float | None = None

    def overrides(self) -> dict[str, Any]:
        """The dotted-key overrides for ``load_scenario``: the parameters and duration."""
        out: dict[str, Any] = dict(self.parameters)
        if self.duration is not None:
            out["duration"] = self.duration
        return out

    def folder(self) -> Path:
        """The run's output folder, relative to the sweep's ``--out``."""
        parts = [self.name, self.policy]
        if self.parameters:
            parts.append("__".join(f"{k}={_safe(v)}" for k, v in self.parameters))
        parts.append(f"seed{self.seed}")
        return Path(*parts)

    def label(self) -> str:
        """A short name for progress lines: the folder as a posix path."""
        return self.folder().as_posix()


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file (see the module docstring); ``source``: the file."""

    scenarios: tuple[Path, ...]
    policies: tuple[str, ...]
    seeds: tuple[int, ...]
    parameters: tuple[tuple[str, tuple[Scalar, ...]], ...] = ()
    duration: float | None = None
    source: str = ""

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The swept dotted keys, in file order."""
        return tuple(k for k, _ in self.parameters)

    def combinations(self) -> list[tuple[tuple[str, Scalar], ...]]:
        """Every combination of the parameter grid (one empty one when there is none)."""
        keys = self.parameter_names
        values = [v for _, v in self.parameters]
        return [tuple(zip(keys, combo, strict=True)) for combo in itertools.product(*values)]


def expand(sweep: Sweep) -> list[SweepRun]:
    """The runs of ``sweep``: scenario x policy x parameter combination x seed, in that
    nesting order (deterministic)."""
    return [
        SweepRun(path, path.stem, policy, seed, combo, sweep.duration)
        for path in sweep.scenarios
        for policy in sweep.policies
        for combo in sweep.combinations()
        for seed in sweep.seeds
    ]


def load_sweep(path: str | Path, check_scenarios: bool = True) -> Sweep:
    """The sweep in YAML file ``path``. With ``check_scenarios``, every scenario is also
    loaded with every parameter combination (and the duration), so a bad parameter key
    or value fails here, before any run, naming the sweep field."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        fix = (
            " (give a sweep YAML: docs/scenarios.md)"
            if isinstance(exc, FileNotFoundError)
            else f" ({exc})"
        )
        raise ScenarioError(source, None, "sweep", f"cannot read the file{fix}") from None
    sweep = parse_sweep(text, source, base=Path(path).resolve().parent)
    if check_scenarios:
        check_sweep(sweep)
    return sweep


def parse_sweep(text: str, source: str = "<sweep>", base: Path | None = None) -> Sweep:
    """The sweep in YAML ``text``; scenario paths are resolved against ``base`` (default:
    the current folder). ``source`` names the file in errors."""
    doc = parse_yaml(text, source, root="sweep")
    if not isinstance(doc.data, dict):
        raise doc.error((), "must be a mapping of sweep fields", doc.data)
    top = doc.validate(SweepFile)
    scenarios = _scenarios(doc, top.scenarios, base or Path.cwd())
    policies = _unique(doc, ("policies",), top.policies, DEFAULT_POLICIES, "policy")
    if isinstance(top.seeds, SeedRange):
        seeds = tuple(range(top.seeds.start, top.seeds.start + top.seeds.count))
    else:
        seeds = _unique(doc, ("seeds",), top.seeds, (0,), "seed")
    parameters = _parameters(doc, top.parameters or {})
    sweep = Sweep(scenarios, policies, seeds, parameters, top.duration, source)
    runs = len(scenarios) * len(policies) * len(seeds) * len(sweep.combinations())
    if runs > MAX_RUNS:
        raise doc.error((), f"expands to {runs} runs, more than {MAX_RUNS}")
    return sweep


def check_sweep(sweep: Sweep) -> None:
    """Load every scenario with every parameter combination; a ScenarioError names the
    sweep file, the scenario and the problem (the first one found)."""
    for path in sweep.scenarios:
        for combo in sweep.combinations():
            run = SweepRun(
                path, path.stem, sweep.policies[0], sweep.seeds[0], combo, sweep.duration
            )
            overrides = run.overrides()
            try:
                load_scenario(path, overrides)
            except ScenarioError as exc:
                where = ", ".join(f"{k}={v!r}" for k, v in overrides.items()) or "no overrides"
                raise ScenarioError(
                    sweep.source, None, "parameters" if combo else "scenarios",
                    f"scenario {path.name} with {where} is invalid: {exc}",
                ) from None  # fmt: skip


# ---------------------------------------------------------------------------- fields
def _scenarios(doc: Document, names: list[str], base: Path) -> tuple[Path, ...]:
    if not names:
        raise doc.error(("scenarios",), "must list at least one scenario file")
    paths: list[Path] = []
    stems: dict[str, int] = {}
    for i, name in enumerate(names):
        where = ("scenarios", i)
        path = (base / name).resolve()
        if not path.is_file():
            raise doc.error(where, f"is not a file (looked for {path})", name)
        if path.stem in stems:
            raise doc.error(where, f"has the same file name as scenarios[{stems[path.stem]}]", name)
        stems[path.stem] = len(paths)
        paths.append(path)
    return tuple(paths)


def _unique(
    doc: Document, where: tuple[str], items: list[Any] | None, default: tuple[Any, ...], what: str
) -> tuple[Any, ...]:
    """``items`` (``default`` when not given): at least one, none twice."""
    if items is None:
        return default
    for i, item in enumerate(items):
        if item in items[:i]:
            raise doc.error((*where, i), "is listed twice", item)
    if not items:
        raise doc.error(where, f"must list at least one {what}")
    return tuple(items)


def _parameters(
    doc: Document, grid: dict[str, list[Scalar]]
) -> tuple[tuple[str, tuple[Scalar, ...]], ...]:
    out: list[tuple[str, tuple[Scalar, ...]]] = []
    for key, values in grid.items():
        where = ("parameters", key)
        if not _PARAM_KEY.match(key):
            raise doc.error(where, "must be a dotted scenario key (map_server.policy)", key)
        if key in ("duration", "seed", "map_server.policy"):
            raise doc.error(where, "is set by the sweep's own field; use it instead", key)
        if not values:
            raise doc.error(where, "must be a non-empty list of values", values)
        seen: list[Scalar] = []
        for i, item in enumerate(values):
            if any(type(item) is type(s) and item == s for s in seen):
                raise doc.error((*where, i), "is listed twice", item)
            seen.append(item)
        out.append((key, tuple(seen)))
    return tuple(out)


def _safe(value: Scalar) -> str:
    """``value`` as a file-name-safe string (``10``, ``0.5``, ``true``)."""
    text = str(value).lower() if isinstance(value, bool) else str(value)
    return _UNSAFE.sub("_", text) or "_"
