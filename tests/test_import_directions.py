"""Import directions (the architecture, enforced): read every module's imports, module
level and inside functions alike, and check them against the rules.

- ``mapserver/core/`` imports only the standard library, numpy, numba and itself;
- ``planner/`` imports nothing of ``mapserver`` but ``mapserver.core``;
- nothing in ``mapserver/`` but its API (``mapserver/api/``) imports ``planner``;
- nothing in ``mapserver/`` or ``planner/`` imports the simulator or the scenarios
  (``fleet``, ``scenarios``), except for type checking;
- importing ``mapserver.client`` loads neither numba, PIL, sqlite3 nor fastapi;
- only ``fleet/bullet.py`` imports ``pybullet`` (the ``sim`` extra, quietly).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STDLIB = sys.stdlib_module_names


def imports(path: Path) -> list[tuple[int, str, bool]]:
    """(line, imported module, under ``if TYPE_CHECKING``) for each import in ``path``."""
    tree = ast.parse(path.read_text(), str(path))
    typing_only: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            typing_only.update(id(n) for child in node.body for n in ast.walk(child))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name, id(node) in typing_only) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module, id(node) in typing_only))
    return found


def within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def broken_rule(where: str, module: str, typing_only: bool) -> str | None:
    """The rule that ``where`` (a path relative to the root) importing ``module`` breaks."""
    top = module.split(".")[0]
    if where.startswith("mapserver/core/"):
        if not (top in STDLIB or top in ("numpy", "numba") or within(module, "mapserver.core")):
            return "mapserver/core imports only the standard library, numpy, numba and itself"
    if where.startswith("planner/") and within(module, "mapserver"):
        if not within(module, "mapserver.core"):
            return "planner imports nothing of mapserver but mapserver.core"
    if where.startswith("mapserver/") and not where.startswith("mapserver/api/"):
        if within(module, "planner"):
            return "nothing in mapserver but its API imports planner"
    if where.startswith(("mapserver/", "planner/")) and top in ("fleet", "scenarios"):
        if not typing_only:
            return "mapserver and planner do not import the simulator or the scenarios"
    return None


def violations(root: Path) -> list[str]:
    """``FILE:LINE: imports MODULE: RULE`` for every import below ``root`` that breaks one."""
    found = []
    for package in ("mapserver", "planner"):
        for path in sorted((root / package).rglob("*.py")):
            where = path.relative_to(root).as_posix()
            for line, module, typing_only in imports(path):
                rule = broken_rule(where, module, typing_only)
                if rule:
                    found.append(f"{where}:{line}: imports {module}: {rule}")
    return found


def test_every_import_goes_the_allowed_way():
    assert violations(ROOT) == []


def test_a_forbidden_import_is_caught(tmp_path):
    for package in ("mapserver/core", "mapserver/store", "planner"):
        (tmp_path / package).mkdir(parents=True)
    (tmp_path / "mapserver/core/belief.py").write_text("import numpy\nfrom scipy import ndimage\n")
    (tmp_path / "mapserver/store/journal.py").write_text(
        "def f():\n    import planner.grid_search\n"
    )
    (tmp_path / "planner/lanes.py").write_text(
        "from mapserver.core.geometry import GridGeometry\nfrom mapserver.client import MapClient\n"
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from fleet.world import World\n"
        "import fleet.sim\n"
    )
    assert violations(tmp_path) == [
        "mapserver/core/belief.py:2: imports scipy: mapserver/core imports only the standard "
        "library, numpy, numba and itself",
        "mapserver/store/journal.py:2: imports planner.grid_search: nothing in mapserver but "
        "its API imports planner",
        "planner/lanes.py:2: imports mapserver.client: planner imports nothing of mapserver "
        "but mapserver.core",
        "planner/lanes.py:6: imports fleet.sim: mapserver and planner do not import the "
        "simulator or the scenarios",
    ]


def test_importing_the_client_loads_no_numba_pil_sqlite3_or_fastapi():
    code = (
        "import sys, mapserver.client\n"
        "print(sorted(m for m in ('numba', 'PIL', 'sqlite3', 'fastapi') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "[]"


def pybullet_imports(root: Path) -> list[str]:
    """``FILE:LINE`` of every import of ``pybullet`` below ``root`` but ``fleet/bullet.py``."""
    found = []
    for package in ("fleet", "mapserver", "planner", "scenarios"):
        for path in sorted((root / package).rglob("*.py")):
            where = path.relative_to(root).as_posix()
            for line, module, _ in imports(path):
                if within(module, "pybullet") and where != "fleet/bullet.py":
                    found.append(f"{where}:{line}")
    return found


def test_only_fleet_bullet_imports_pybullet(tmp_path):
    assert pybullet_imports(ROOT) == []
    for package in ("fleet", "mapserver", "planner", "scenarios"):
        (tmp_path / package).mkdir()
    (tmp_path / "fleet/bullet.py").write_text("import pybullet\n")
    (tmp_path / "fleet/world.py").write_text("import numpy\nimport pybullet as p\n")
    (tmp_path / "scenarios/run.py").write_text("def f():\n    from pybullet import connect\n")
    assert pybullet_imports(tmp_path) == ["fleet/world.py:2", "scenarios/run.py:2"]
