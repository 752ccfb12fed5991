"""The JSON Schema files for editors are the generated ones, and the shipped files pass
them (when ``jsonschema`` is installed)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from scenarios.schemas import FOLDER, SCHEMAS, render

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_the_committed_schema_files_are_the_generated_ones(name: str) -> None:
    committed = (FOLDER / f"{name}.schema.json").read_text(encoding="utf-8")
    assert committed == render(name), "run: python -m scenarios.schemas"


def _validator(name: str):
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads((FOLDER / f"{name}.schema.json").read_text(encoding="utf-8"))
    return jsonschema.Draft202012Validator(schema)


@pytest.mark.parametrize(
    ("name", "path"),
    [("scenario", p) for p in sorted((ROOT / "scenarios").glob("*.yaml"))]
    + [("settings", ROOT / "docker" / "server.example.yaml")],
    ids=lambda value: value.name if isinstance(value, Path) else value,
)
def test_shipped_files_pass_their_schema(name: str, path: Path) -> None:
    errors = list(_validator(name).iter_errors(yaml.safe_load(path.read_text())))
    assert errors == []


def test_the_schema_rejects_a_string_for_a_number_and_an_unknown_key() -> None:
    data = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
    data["duration"] = "30"
    data["units"]["cont"] = 2
    errors = {tuple(e.path): e.validator for e in _validator("scenario").iter_errors(data)}
    assert errors == {("duration",): "type", ("units",): "additionalProperties"}


def test_the_schema_command_writes_where_told_and_help_writes_nothing(tmp_path, capsys) -> None:
    from scenarios.schemas import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0 and not Path("--help").exists()
    assert main([str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"{n}.schema.json" for n in SCHEMAS)
