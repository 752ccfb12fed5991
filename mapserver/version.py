"""fleetmap's version: the installed distribution's, else the source tree's.

``fleetmap --version`` prints it. An installed ``fleetmap`` (editable or not) has it in
its metadata; code run from a source checkout that was never installed reads it from the
checkout's ``pyproject.toml``; anything else is ``unknown``.
"""

from __future__ import annotations

import tomllib
from importlib import metadata
from pathlib import Path

DISTRIBUTION = "fleetmap"
PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
"""The source tree's ``pyproject.toml`` (absent in an installed wheel)."""
UNKNOWN = "unknown"


def package_version(pyproject: Path = PYPROJECT) -> str:
    """The version string, e.g. ``0.1.0``."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return source_version(pyproject)


def source_version(pyproject: Path) -> str:
    """``project.version`` of ``pyproject`` when it is fleetmap's, else ``unknown``."""
    try:
        project = tomllib.loads(pyproject.read_text(encoding="utf-8")).get("project", {})
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return UNKNOWN
    if project.get("name") != DISTRIBUTION or not isinstance(project.get("version"), str):
        return UNKNOWN
    return project["version"]
