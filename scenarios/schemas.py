"""JSON Schema files for editors, generated from the pydantic models that validate the
files: ``docs/schemas/scenario.schema.json`` (``ScenarioFile``), ``sweep.schema.json``
(``SweepFile``) and ``settings.schema.json`` (the server's ``Settings``).

``python -m scenarios.schemas [FOLDER]`` rewrites them (default: docs/schemas of the
repository); a test checks that the committed files are the generated ones. The schemas
give each field's type, bounds and default; the checks that join fields (ids, the floor,
lanes, the domain classes' rules) are the loaders' alone.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from mapserver.service.settings import Settings
from scenarios.spec.scenario import ScenarioFile
from scenarios.sweep.sweep_file import SweepFile

SCHEMAS: dict[str, type[BaseModel]] = {
    "scenario": ScenarioFile,
    "sweep": SweepFile,
    "settings": Settings,
}
FOLDER = Path(__file__).resolve().parents[1] / "docs" / "schemas"


def schema(name: str) -> dict[str, Any]:
    """The JSON Schema of file kind ``name`` (a key of SCHEMAS)."""
    out = {"$schema": "https://json-schema.org/draft/2020-12/schema"}
    out.update(SCHEMAS[name].model_json_schema())
    return out


def render(name: str) -> str:
    """``schema(name)`` as the text of its file."""
    return json.dumps(schema(name), indent=2) + "\n"


def write(folder: Path = FOLDER) -> list[Path]:
    """Write every schema to ``folder`` as ``<name>.schema.json``; the paths written."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in SCHEMAS:
        path = folder / f"{name}.schema.json"
        path.write_text(render(name), encoding="utf-8")
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    """``python -m scenarios.schemas [FOLDER]``: rewrite the schemas; prints each path."""
    parser = argparse.ArgumentParser(
        prog="python -m scenarios.schemas", description="Rewrite the JSON Schemas of the files."
    )
    parser.add_argument(
        "folder", nargs="?", type=Path, default=FOLDER, help=f"where to write (default: {FOLDER})"
    )
    args = parser.parse_args(argv)
    for written in write(args.folder):
        print(written)
    return 0


if __name__ == "__main__":
    sys.exit(main())
