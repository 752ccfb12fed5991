"""The ``sim`` extra and ``--version`` (issue 16): everything but the simulator works
without PyBullet, the simulator's commands say in one line how to get it, no command
prints PyBullet's banner, and ``fleetmap --version`` prints the package's version.

Without PyBullet is simulated where it is installed (Python 3.11) by ``sys.modules
["pybullet"] = None``, which makes ``import pybullet`` raise ``ModuleNotFoundError`` as
a missing package does; on Python 3.12+ it is missing for real.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest

from fleet.bullet import SimulatorMissing, import_silently, install_hint, load_pybullet
from mapserver import version as version_module
from mapserver.version import UNKNOWN, package_version, source_version

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT_VERSION = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
NO_PYBULLET = "import sys; sys.modules['pybullet'] = None\n"
MAIN = "from scenarios.cli.main import main\nsys.exit(main(sys.argv[1:]))\n"
SIM_ERROR_311 = (
    "the simulator needs pybullet, which is not installed: pip install 'fleetmap[sim]' "
    "(pybullet has wheels for Python 3.11)"
)
SIM_ERROR_312 = (
    "the simulator needs pybullet, which is not installed: pip install 'fleetmap[sim]' "
    "(pybullet has wheels for Python 3.11; on Python 3.12 pip builds it from source, which "
    "needs a C++ compiler)"
)
SIM_ERROR = (
    SIM_ERROR_311
    if sys.version_info < (3, 12)
    else SIM_ERROR_312.replace("Python 3.12", f"Python {sys.version_info[0]}.{sys.version_info[1]}")
)


def test_the_install_hint_mentions_a_source_build_only_where_no_wheel_exists():
    assert install_hint((3, 11)) == SIM_ERROR_311
    assert install_hint((3, 12)) == SIM_ERROR_312
    assert install_hint((3, 13)) == SIM_ERROR_312.replace("Python 3.12", "Python 3.13")


def python(code: str, *args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def test_fleetmap_version_prints_the_package_version():
    proc = subprocess.run(
        [sys.executable, "-m", "scenarios.cli.main", "--version"], capture_output=True, text=True
    )
    assert (proc.returncode, proc.stdout, proc.stderr) == (0, f"fleetmap {PYPROJECT_VERSION}\n", "")
    assert PYPROJECT_VERSION == "0.1.0"


def test_the_version_comes_from_the_metadata_else_the_source_tree(tmp_path, monkeypatch):
    assert package_version() == metadata.version("fleetmap") == PYPROJECT_VERSION

    def not_installed(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(version_module.metadata, "version", not_installed)
    assert package_version() == PYPROJECT_VERSION  # the checkout's pyproject.toml
    ours = tmp_path / "pyproject.toml"
    ours.write_text('[project]\nname = "fleetmap"\nversion = "2.3.4"\n')
    assert package_version(ours) == "2.3.4"
    other = tmp_path / "other.toml"
    other.write_text('[project]\nname = "otherpkg"\nversion = "9.9"\n')
    broken = tmp_path / "broken.toml"
    broken.write_text("[project\n")
    for path in (other, broken, tmp_path / "absent.toml"):
        assert source_version(path) == UNKNOWN


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "scenarios/tiny.yaml"],
        ["run", "no-such-scenario.yaml"],
        ["compare", "scenarios/tiny.yaml", "--seeds", "1"],
        ["sweep", "no-such-sweep.yaml"],
    ],
)
def test_the_simulator_commands_without_pybullet_say_how_to_install_it(argv, tmp_path):
    proc = python(NO_PYBULLET + MAIN, *argv, "--out", str(tmp_path / "out"))
    assert proc.returncode == 2
    assert proc.stderr == f"fleetmap {argv[0]}: error: {SIM_ERROR}\n"
    assert proc.stdout == ""
    assert not (tmp_path / "out").exists()


def test_without_pybullet_the_server_side_commands_work_and_never_load_it(tmp_path):
    """Every module of mapserver and planner and every command's ``--help`` load neither
    PyBullet nor the PyBullet world (with PyBullet installed this catches an import that
    would break the server on Python 3.12+); ``map build`` and ``plan`` run, and a scenario
    file loads (its grid and map settings configure a server)."""
    code = NO_PYBULLET + (
        "import contextlib, importlib, io, pkgutil, mapserver, planner\n"
        "for package in (mapserver, planner):\n"
        "    for info in pkgutil.walk_packages(package.__path__, package.__name__ + '.'):\n"
        "        importlib.import_module(info.name)\n"
        "from scenarios.cli.main import build_parser, main\n"
        "for command in build_parser()._subparsers._group_actions[0].choices:\n"
        "    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "        main([command, '--help'])\n"
        "out = sys.argv[1]\n"
        "assert main(['map', 'build', 'scenarios/data/sample_scans.jsonl', '--width', '400',\n"
        "             '--height', '200', '--resolution', '0.05', '--out', out]) == 0\n"
        "assert main(['plan', out + '/map.yaml', '--start', '1,1', '--goal', '2,1']) == 0\n"
        "from scenarios.spec.scenario import load_scenario\n"  # a scenario's grid, for a server
        "assert load_scenario('scenarios/moved_pod.yaml').geometry().width == 400\n"
        "print(sorted(m for m in ('fleet.world',) if m in sys.modules))\n"
    )
    proc = python(code, str(tmp_path / "map"))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == "[]"
    assert "pybullet" not in proc.stderr


def test_load_pybullet_without_it_raises_simulator_missing_and_restores_the_output():
    code = NO_PYBULLET + (
        "import os\n"
        "from fleet.bullet import SimulatorMissing, load_pybullet\n"
        "try:\n"
        "    load_pybullet()\n"
        "except SimulatorMissing as exc:\n"
        "    assert isinstance(exc, ModuleNotFoundError) and exc.name == 'pybullet'\n"
        "    print(exc, flush=True)\n"
        "os.write(1, b'fd 1 back\\n'); os.write(2, b'fd 2 back\\n')\n"
    )
    proc = python(code)
    assert (proc.returncode, proc.stdout, proc.stderr) == (
        0,
        f"{SIM_ERROR}\nfd 1 back\n",
        "fd 2 back\n",
    )
    assert issubclass(SimulatorMissing, ModuleNotFoundError)


def test_import_silently_swallows_what_a_module_prints_from_c_at_import(tmp_path):
    """A module that prints from C (buffered: stdout is a pipe) and writes to both file
    descriptors while it is imported: none of it shows; what is printed after does."""
    (tmp_path / "noisy.py").write_text(
        "import ctypes, os\n"
        "ctypes.CDLL(None).printf(b'banner from C\\n')\n"
        "os.write(1, b'banner on fd 1\\n'); os.write(2, b'banner on fd 2\\n')\n"
    )
    (tmp_path / "broken.py").write_text("import os\nos.write(2, b'dying words\\n')\n1 / 0\n")
    code = (
        "import os, sys\n"
        f"sys.path.insert(0, {str(tmp_path)!r})\n"
        "from fleet.bullet import import_silently\n"
        "print('before', flush=True)\n"
        "assert import_silently('noisy').__name__ == 'noisy'\n"
        "try:\n"
        "    import_silently('broken')\n"
        "except ZeroDivisionError:\n"
        "    print('raised', flush=True)\n"
        "print('after', flush=True); print('err after', file=sys.stderr, flush=True)\n"
    )
    proc = python(code)
    assert (proc.returncode, proc.stdout, proc.stderr) == (
        0,
        "before\nraised\nafter\n",
        "err after\n",
    )


@pytest.mark.sim
def test_loading_pybullet_prints_no_banner():
    code = (
        "from fleet.bullet import load_pybullet\n"
        "p = load_pybullet()\n"
        "print(p.MAX_RAY_INTERSECTION_BATCH_SIZE)\n"
        "import fleet.world\n"
    )
    proc = python(code)
    assert (proc.returncode, proc.stdout, proc.stderr) == (0, "16384\n", "")
    assert load_pybullet() is sys.modules["pybullet"] is import_silently("pybullet")
