"""Running a sweep's runs in parallel: a local process pool (default) or Ray tasks.

``run_sweep(runs, out_dir, workers=N)`` runs each ``SweepRun`` with
``scenarios.run.execute.execute`` in a ``ProcessPoolExecutor`` (spawned workers, so no
forked threads); ``run_sweep(..., ray_address=ADDRESS)`` runs the same function as Ray
remote tasks on the cluster at ADDRESS (``local`` starts a local Ray; ``auto`` joins the
one on this machine). Ray is the optional extra ``fleetmap[ray]``, imported only then;
its workers must have fleetmap installed and write to ``out_dir``, so on a multi-node
cluster it must be a shared filesystem.

A run that fails (an exception in ``execute``, or a worker that dies) becomes a
``RunResult`` with status ``error`` and the message; the sweep goes on. ``on_result``
sees each result as it finishes (in finishing order), ``on_wait`` is called every
``WAIT_S`` while none does (``progress.RunProgress`` prints from both); the returned list
is in run order.
"""

from __future__ import annotations

import multiprocessing
import os
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mapserver.core.errors import FleetmapError
from scenarios.sweep.sweep_file import SweepRun

__all__ = [
    "MissingExtraError",
    "RunResult",
    "execute_run",
    "import_ray",
    "run_sweep",
]

RAY_EXTRA = "ray"
WAIT_S = 1.0
"""[s] how often ``run_sweep`` calls ``on_wait`` while no run finishes."""


class MissingExtraError(FleetmapError, RuntimeError):
    """An optional dependency is not installed; the message names the extra to install."""


@dataclass(frozen=True)
class RunResult:
    """The outcome of one run: ``status`` ``ok`` (with ``metrics``, metrics.json's keys)
    or ``error`` (with ``error``, one line); ``wall_seconds`` [s] of the whole run
    including its outputs; ``out_dir``: where its outputs are."""

    run: SweepRun
    status: str
    out_dir: Path
    metrics: dict[str, Any] = field(default_factory=dict)
    error: str = ""
    wall_seconds: float = 0.0


def execute_run(run: SweepRun, out_dir: Path) -> RunResult:
    """Run ``run`` with ``execute`` into ``out_dir / run.folder()``; never raises for a
    failed run (the error is in the result). Runs in a worker process or Ray task."""
    from scenarios.run.execute import execute

    folder = Path(out_dir) / run.folder()
    start = time.perf_counter()
    try:
        metrics = execute(
            run.scenario, run.policy, run.seed, None, folder, overrides=run.overrides()
        )
    except Exception as exc:  # noqa: BLE001 - a failed run is recorded, not fatal
        return RunResult(run, "error", folder, error=_one_line(exc),
                         wall_seconds=time.perf_counter() - start)  # fmt: skip
    return RunResult(run, "ok", folder, dict(metrics), wall_seconds=time.perf_counter() - start)


def run_sweep(
    runs: Sequence[SweepRun],
    out_dir: Path,
    workers: int | None = None,
    ray_address: str | None = None,
    on_result: Callable[[RunResult], None] | None = None,
    on_wait: Callable[[], None] | None = None,
) -> list[RunResult]:
    """Run every run (see the module docstring); ``workers``: processes of the local
    pool (default ``os.cpu_count()``; ignored with Ray). Returns results in run order."""
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    out_dir = Path(out_dir).resolve()
    if ray_address is not None:
        return _run_ray(runs, out_dir, ray_address, on_result, on_wait)
    return _run_pool(runs, out_dir, workers or os.cpu_count() or 1, on_result, on_wait)


def _run_pool(
    runs: Sequence[SweepRun],
    out_dir: Path,
    workers: int,
    on_result: Callable[[RunResult], None] | None,
    on_wait: Callable[[], None] | None,
) -> list[RunResult]:
    results: list[RunResult | None] = [None] * len(runs)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        max_workers=min(workers, max(1, len(runs))), mp_context=context
    ) as pool:
        pending: dict[Future[RunResult], int] = {
            pool.submit(execute_run, run, out_dir): i for i, run in enumerate(runs)
        }
        while pending:
            done, _ = wait(pending, timeout=WAIT_S, return_when=FIRST_COMPLETED)
            if not done and on_wait is not None:
                on_wait()
            for future in done:
                i = pending.pop(future)
                try:
                    result = future.result()
                except Exception as exc:  # noqa: BLE001 - e.g. a worker process died
                    result = RunResult(runs[i], "error", out_dir / runs[i].folder(),
                                       error=_one_line(exc))  # fmt: skip
                results[i] = result
                if on_result is not None:
                    on_result(result)
    return [r for r in results if r is not None]


def import_ray() -> Any:
    """The ``ray`` module; MissingExtraError naming the extra when it is not installed."""
    try:
        import ray
    except ImportError as exc:
        raise MissingExtraError(
            f"--ray needs Ray, the optional extra {RAY_EXTRA!r}: "
            f"pip install 'fleetmap[{RAY_EXTRA}]' ({exc})"
        ) from None
    return ray


def _run_ray(
    runs: Sequence[SweepRun],
    out_dir: Path,
    address: str,
    on_result: Callable[[RunResult], None] | None,
    on_wait: Callable[[], None] | None,
) -> list[RunResult]:
    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        ray.init(address=None if address == "local" else address, log_to_driver=False)
    try:
        task = ray.remote(execute_run)
        pending = {task.remote(run, out_dir): i for i, run in enumerate(runs)}
        results: list[RunResult | None] = [None] * len(runs)
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_S)
            if not done and on_wait is not None:
                on_wait()
            for ref in done:
                i = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - a task or its worker failed
                    result = RunResult(runs[i], "error", out_dir / runs[i].folder(),
                                       error=_one_line(exc))  # fmt: skip
                results[i] = result
                if on_result is not None:
                    on_result(result)
    finally:
        if started:
            ray.shutdown()
    return [r for r in results if r is not None]


def _one_line(exc: BaseException) -> str:
    """``Type: message`` on one line (the last line of the exception's text)."""
    text = "".join(traceback.format_exception_only(type(exc), exc)).strip()
    return " ".join(text.split())
