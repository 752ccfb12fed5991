"""Helpers for tests that run shipped scenarios: shorter copies of their files."""

from __future__ import annotations

from pathlib import Path

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
TINY = SCENARIOS / "tiny.yaml"


def tiny5(folder: Path, duration: float | None = None) -> Path:
    """tiny.yaml with its drop and removal moved inside a 5 s run (at 1 s and 3 s), as
    ``folder/tiny5.yaml``; ``duration`` [s] replaces its 20 s when given (> 3 s)."""
    text = TINY.read_text().replace("at: 4.0", "at: 1.0").replace("at: 12.0", "at: 3.0")
    if duration is not None:
        text = text.replace("duration: 20.0", f"duration: {duration}")
    path = folder / "tiny5.yaml"
    path.write_text(text)
    return path


def shortened(folder: Path, name: str, duration: float) -> Path:
    """A copy of shipped scenario ``name`` whose run ends at ``duration`` [s] (its events
    before then kept), as ``folder/<name>.yaml``: the whole runs take minutes."""
    lines = [
        f"duration: {duration}" if ln.startswith("duration:") else ln
        for ln in (SCENARIOS / f"{name}.yaml").read_text(encoding="utf-8").splitlines()
    ]
    assert f"duration: {duration}" in lines
    path = folder / f"{name}.yaml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
