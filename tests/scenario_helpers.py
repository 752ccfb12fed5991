"""Helpers for tests that run the tiny scenario: a shorter copy of scenarios/tiny.yaml."""

from __future__ import annotations

from pathlib import Path

TINY = Path(__file__).resolve().parents[1] / "scenarios" / "tiny.yaml"


def tiny5(folder: Path, duration: float | None = None) -> Path:
    """tiny.yaml with its drop and removal moved inside a 5 s run (at 1 s and 3 s), as
    ``folder/tiny5.yaml``; ``duration`` [s] replaces its 20 s when given (> 3 s)."""
    text = TINY.read_text().replace("at: 4.0", "at: 1.0").replace("at: 12.0", "at: 3.0")
    if duration is not None:
        text = text.replace("duration: 20.0", f"duration: {duration}")
    path = folder / "tiny5.yaml"
    path.write_text(text)
    return path
