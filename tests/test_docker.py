"""The container files, tested without Docker (it cannot run here).

- ``docker/Dockerfile``: base image, non-root user, ``/data`` volume, port, healthcheck,
  and its CMD, which is run here as is (host, data dir and config pointed at loopback and
  a temporary folder) against a real server, with the healthcheck's own command.
- ``docker/compose.yaml``: parsed with PyYAML; its services, volumes, ports, tokens; and
  its two services' commands run together on loopback as compose would run them (each
  read from the files: the server's from the Dockerfile's CMD, the scenario's from its
  ``command``), volumes as temporary folders, the service name as 127.0.0.1.
- ``docker/server.example.yaml``: valid settings, refused on 0.0.0.0 without tokens, and
  the map settings of the scenario compose runs against it.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
import yaml

from mapserver.core.sensor_model import DEFAULT_POLICY
from mapserver.service.settings import SettingsError, load_settings
from scenarios.cli.main import build_parser
from scenarios.run.embedded_server import free_port
from scenarios.spec.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
DOCKER = ROOT / "docker"
SERVE = ["fleetmap", "serve", "--host", "0.0.0.0", "--data-dir", "/data",
         "--config", "/config/server.yaml"]  # fmt: skip
TEST_TOKENS = {
    "FLEETMAP_UNIT_TOKEN": "unit-t",
    "FLEETMAP_READER_TOKEN": "reader-t",
    "FLEETMAP_ADMIN_TOKEN": "admin-t",
}


def dockerfile() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) per instruction, continuation lines joined."""
    text = re.sub(r"\\\n", " ", (DOCKER / "Dockerfile").read_text())
    lines = [line.strip() for line in text.splitlines()]
    return [
        (line.split(None, 1)[0].upper(), line.split(None, 1)[1])
        for line in lines
        if line and not line.startswith("#")
    ]


def instruction(name: str) -> list[str]:
    return [args for op, args in dockerfile() if op == name]


def cmd_argv() -> list[str]:
    (cmd,) = instruction("CMD")
    return json.loads(cmd)


def healthcheck_argv() -> list[str]:
    (check,) = instruction("HEALTHCHECK")
    return json.loads(check.split(" CMD ", 1)[1])


def compose() -> dict:
    return yaml.safe_load((DOCKER / "compose.yaml").read_text())


def substitute(text: str) -> str:
    """Compose's ``${NAME:?message}`` interpolation with the test tokens."""
    return re.sub(r"\$\{(\w+):\?[^}]*\}", lambda m: TEST_TOKENS[m.group(1)], text)


def tokens_env() -> str:
    return substitute(compose()["services"]["mapserver"]["environment"]["FLEETMAP_TOKENS"])


def test_the_image_is_slim_python_run_by_a_non_root_user_with_data_in_a_volume():
    ops = dockerfile()
    assert ops[0] == ("FROM", "python:3.11-slim")
    users = instruction("USER")
    assert users and users[-1] not in ("root", "0")
    assert [op for op, _ in ops].index("USER") < [op for op, _ in ops].index("CMD")
    assert "/data" in instruction("VOLUME")[0].split()
    assert instruction("EXPOSE") == ["8700"]
    # the image also runs `fleetmap run` (compose.yaml's scenario service): the sim extra
    assert any("pip install '.[sim]'" in run for run in instruction("RUN"))
    for copy in instruction("COPY"):
        *sources, _ = copy.split()
        assert all((ROOT / source).exists() for source in sources), copy


def test_the_image_command_is_fleetmap_serve_on_all_interfaces_with_data_and_config():
    argv = cmd_argv()
    assert argv == SERVE
    args = build_parser().parse_args(argv[1:])
    assert (args.command, args.host) == ("serve", "0.0.0.0")
    assert (args.data_dir, args.config) == (Path("/data"), Path("/config/server.yaml"))
    check = healthcheck_argv()
    assert check[0] == "python" and "/healthz" in check[-1]


def test_the_example_config_is_valid_with_tokens_and_refused_on_all_interfaces_without(
    tmp_path, monkeypatch
):
    config = DOCKER / "server.example.yaml"
    monkeypatch.setenv("FLEETMAP_TOKENS", tokens_env())
    settings = load_settings(config, {"host": "0.0.0.0", "data_dir": tmp_path})
    roles = {t.token.get_secret_value(): t.role.value for t in settings.tokens}
    assert roles == {"unit-t": "unit", "reader-t": "reader", "admin-t": "admin"}
    monkeypatch.delenv("FLEETMAP_TOKENS")
    with pytest.raises(SettingsError, match="host: .*loopback"):
        load_settings(config, {"host": "0.0.0.0", "data_dir": tmp_path})


def test_the_image_command_serves_and_passes_its_own_healthcheck(tmp_path):
    """The CMD's argv with its three paths pointed here: the server the image runs."""
    config = tmp_path / "server.yaml"
    shutil.copy(DOCKER / "server.example.yaml", config)
    here = {"--host": "127.0.0.1", "--data-dir": str(tmp_path / "data"), "--config": str(config)}
    argv = cmd_argv()
    local = [here.get(argv[i - 1], arg) if i else arg for i, arg in enumerate(argv)]
    assert [a for a in local if a.startswith("--")] == [a for a in argv if a.startswith("--")]
    port = str(free_port())
    env = dict(os.environ, FLEETMAP_PORT=port, FLEETMAP_TOKENS=tokens_env())
    command = [sys.executable, "-m", "scenarios.cli.main", *local[1:]]
    server = subprocess.Popen(command, env=env, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    try:
        healthy = _wait_healthy(env, server)
        assert healthy, server.stderr.read() if server.poll() is not None else "not healthy"
        url = f"http://127.0.0.1:{port}/v1/map/meta"
        assert httpx.get(url).status_code == 401  # tokens from the environment are in force
        meta = httpx.get(url, headers={"Authorization": "Bearer reader-t"}).json()
        assert (meta["width"], meta["height"], meta["resolution"]) == (400, 300, 0.1)
        assert meta["policy"] == DEFAULT_POLICY.value
    finally:
        server.terminate()
        server.wait(timeout=20)
    assert _healthcheck(env) != 0  # and it fails once the server is gone


def _healthcheck(env: dict[str, str]) -> int:
    check = healthcheck_argv()
    return subprocess.run([sys.executable, *check[1:]], env=env, timeout=10).returncode


def _wait_healthy(env: dict[str, str], server: subprocess.Popen, timeout: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if server.poll() is not None:
            return False
        if _healthcheck(env) == 0:
            return True
        time.sleep(0.1)
    return False


def test_compose_runs_the_server_with_its_volume_port_config_and_tokens():
    spec = compose()
    assert set(spec["services"]) == {"mapserver", "scenario"}
    server = spec["services"]["mapserver"]
    build = server["build"]
    assert (DOCKER / build["context"] / build["dockerfile"]).resolve() == DOCKER / "Dockerfile"
    assert "fleetmap-data:/data" in server["volumes"]
    assert set(spec["volumes"]) >= {"fleetmap-data"}
    (config_mount,) = [v for v in server["volumes"] if ":/config/server.yaml" in v]
    assert (DOCKER / config_mount.split(":")[0]).resolve() == DOCKER / "server.example.yaml"
    assert [p.rsplit(":", 1)[1] for p in server["ports"]] == ["8700"]
    tokens = json.loads(tokens_env())
    assert sorted(t["role"] for t in tokens) == ["admin", "reader", "unit"]


def test_compose_runs_a_scenario_against_the_server_once_it_is_healthy():
    spec = compose()
    scenario = spec["services"]["scenario"]
    assert scenario["image"] == spec["services"]["mapserver"]["image"]
    assert scenario["depends_on"]["mapserver"]["condition"] == "service_healthy"
    argv = scenario["command"]
    assert argv[:3] == ["fleetmap", "run", "scenarios/moved_pod.yaml"]
    assert argv[argv.index("--server") + 1] == "http://mapserver:8700"
    out = argv[argv.index("--out") + 1]
    assert any(out.startswith(v.split(":")[1] + "/") for v in scenario["volumes"])
    args = build_parser().parse_args(argv[1:])
    assert args.server == "http://mapserver:8700"
    assert (ROOT / argv[2]).is_file()


def test_the_example_config_has_the_map_settings_of_the_scenario_compose_runs(tmp_path):
    """``fleetmap run --server`` refuses a server whose grid is not the scenario's; the
    scenario pins its sensor model, decay and inflation too: the example has them all."""
    argv = compose()["services"]["scenario"]["command"]
    pinned = load_scenario(ROOT / argv[2]).map_server.overrides()
    served = load_settings(DOCKER / "server.example.yaml", {"data_dir": tmp_path})
    assert {key: _dumped(getattr(served, key)) for key in pinned} == pinned


def _dumped(value: object) -> object:
    return value.model_dump() if hasattr(value, "model_dump") else getattr(value, "value", value)


@pytest.mark.sim  # the scenario service runs the simulator
def test_compose_up_runs_the_scenario_to_the_end_against_the_server(tmp_path):
    """Both services as compose runs them, on loopback: the server's command (the image's
    CMD; its config and data from the service's volumes), healthy by the image's own
    healthcheck, then the scenario's command (its ``--server`` the server's address here)
    to exit 0 with its outputs in its volume and its scans in the server's map."""
    spec = compose()
    server, scenario = spec["services"]["mapserver"], spec["services"]["scenario"]
    volumes = {name: tmp_path / name for name in spec["volumes"]}
    port = free_port()
    env = dict(os.environ, FLEETMAP_PORT=str(port), **_environment(server))
    server_argv = _on_host(cmd_argv(), server["volumes"], volumes)
    server_argv[server_argv.index("--host") + 1] = "127.0.0.1"
    (tmp_path / "fleetmap-data").mkdir()
    process = subprocess.Popen(_python(server_argv), env=env, cwd=tmp_path,
                               stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        healthy = _wait_healthy(env, process)
        assert healthy, process.stderr.read() if process.poll() is not None else "not healthy"
        _check_the_repository_is_the_workdir()
        argv = _on_host(scenario["command"], scenario["volumes"], volumes)
        url = argv[argv.index("--server") + 1]
        assert url == f"http://mapserver:{_container_port(server)}"
        argv[argv.index("--server") + 1] = f"http://127.0.0.1:{port}"
        done = subprocess.run(_python(argv), env=dict(os.environ, **_environment(scenario)),
                              cwd=ROOT, capture_output=True, text=True,
                              timeout=600)  # fmt: skip
        assert done.returncode == 0, done.stderr[-3000:]
        metrics = json.loads(done.stdout.splitlines()[-1])  # --json: the metrics, last
        out = Path(argv[argv.index("--out") + 1])
        assert json.loads((out / "metrics.json").read_text()) == metrics
        names = {"metrics.json", "freezes.json", "trips.json", "collisions.json",
                 "report.png", "replay.mcap"}  # fmt: skip
        assert names <= {p.name for p in out.iterdir()}
        assert metrics["tasks_completed"] > 0
        reader = {"Authorization": f"Bearer {TEST_TOKENS['FLEETMAP_READER_TOKEN']}"}
        meta = httpx.get(f"http://127.0.0.1:{port}/v1/map/meta", headers=reader).json()
        assert meta["version"] > 0 and meta["stamp"] > 0  # the run's scans are in its map
    finally:
        process.terminate()
        process.wait(timeout=20)


def _environment(service: dict) -> dict[str, str]:
    """A service's ``environment`` block, interpolated with the test tokens."""
    return {name: substitute(str(value)) for name, value in service["environment"].items()}


def _on_host(argv: list[str], mounts: list[str], volumes: dict[str, Path]) -> list[str]:
    """``argv`` with each container path under a mount rewritten to its host folder: a
    named volume's folder in ``volumes``, a bind mount's source beside compose.yaml."""
    targets = {}
    for mount in mounts:
        source, target = mount.split(":")[:2]
        targets[target] = volumes[source] if source in volumes else (DOCKER / source).resolve()
    out = []
    for arg in argv:
        for target, host in targets.items():
            if arg == target or arg.startswith(target + "/"):
                arg = str(host) + arg[len(target) :]
        out.append(arg)
    return out


def _python(argv: list[str]) -> list[str]:
    assert argv[0] == "fleetmap"
    return [sys.executable, "-m", "scenarios.cli.main", *argv[1:]]


def _container_port(service: dict) -> str:
    (port,) = [p.rsplit(":", 1)[1] for p in service["ports"]]
    return port


def _check_the_repository_is_the_workdir() -> None:
    """The image's COPY lines fill its WORKDIR from the repository's root, path for path,
    so a relative path in a service's command means the same from ``ROOT``."""
    assert len(instruction("WORKDIR")) == 1
    for copy in instruction("COPY"):
        *sources, dest = copy.split()
        assert all(dest in ("./", f"./{source}") for source in sources), copy
