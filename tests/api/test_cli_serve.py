"""``fleetmap serve``: refusals, and the line it prints once it listens; ``fleetmap replay``
from a server's journal."""

import json
import queue
import re
import subprocess
import sys
import threading

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from server_helpers import scan_body, small_settings

from mapserver.api.app import create_app
from scenarios.cli.main import main


def test_an_open_server_refuses_to_bind_beyond_loopback(tmp_path, capsys):
    code = main(["serve", "--host", "0.0.0.0", "--data-dir", str(tmp_path / "d")])
    assert code == 2
    err = capsys.readouterr().err
    assert "host" in err and "loopback" in err
    assert not (tmp_path / "d").exists()


def test_a_bad_config_value_names_the_field(tmp_path, capsys):
    config = tmp_path / "server.yaml"
    config.write_text("sensor_model:\n  p_hit: 0.4\n")
    assert main(["serve", "--config", str(config), "--data-dir", str(tmp_path / "d")]) == 2
    assert "sensor_model.p_hit" in capsys.readouterr().err


def test_a_data_dir_made_with_other_map_settings_is_refused(tmp_path, capsys):
    data = tmp_path / "d"
    create_app(small_settings(data)).state.service.close()
    config = tmp_path / "server.yaml"
    config.write_text("grid:\n  width: 300\n  height: 100\n  resolution: 0.1\n")
    assert main(["serve", "--config", str(config), "--data-dir", str(data)]) == 2
    assert "other map settings" in capsys.readouterr().err


def test_replay_rebuilds_the_servers_map_from_its_journal(tmp_path, capsys):
    data = tmp_path / "d"
    app = create_app(small_settings(data, policy="sticky"))
    with TestClient(app) as client:
        for i in range(5):
            client.post("/v1/scans", json=scan_body(stamp=float(i), x=4.0 + i))
        served = np.frombuffer(client.get("/v1/map?format=raw").content, np.int8)
    assert main(["replay", str(data), "--out", str(tmp_path / "all"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["scans"] == 5
    logodds = np.load(tmp_path / "all" / "logodds.npy")
    probability = 1 / (1 + np.exp(-logodds.astype(np.float64)))
    observed = served >= 0
    assert np.array_equal(np.floor(probability[observed.reshape(100, 200)] * 100 + 0.5),
                          served[observed])  # fmt: skip
    assert main(["replay", str(data / "journal.sqlite3"), "--until", "1.5",
                 "--out", str(tmp_path / "early"), "--json"]) == 0  # fmt: skip
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["scans"] == 2
    here = set(tmp_path.iterdir())
    assert main(["replay", str(data / "journal.sqlite3")]) == 0  # no --out: beside it
    said = capsys.readouterr().out.splitlines()[-1]
    assert (
        said == f"replayed 5 scans of {data / 'journal.sqlite3'}; wrote {data}/replay-map/map.yaml"
    )
    assert np.array_equal(np.load(data / "replay-map" / "logodds.npy"), logodds)
    assert set(tmp_path.iterdir()) == here  # nothing in the working folder's place


def test_replay_of_something_else_is_a_clear_error(tmp_path, capsys):
    assert main(["replay", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "holds neither a server's journal.sqlite3 nor a run's replay.mcap" in err


def serve_until_listening(tmp_path, *flags: str) -> tuple[subprocess.Popen, str]:
    """``fleetmap serve --port 0`` in a subprocess; it and its first stderr line that says
    where it listens (after any warnings)."""
    command = [sys.executable, "-m", "scenarios.cli.main", "serve", "--port", "0",
               "--data-dir", str(tmp_path / "data"), *flags]  # fmt: skip
    server = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(
        target=lambda: [lines.put(line) for line in server.stderr], daemon=True
    ).start()
    try:
        while True:
            line = lines.get(timeout=60)
            if "listening on" in line:
                return server, line.rstrip("\n")
    except BaseException:
        server.kill()
        raise


@pytest.mark.parametrize(
    ("tokens", "said"),
    [
        (None, "tokens: off - open to every client, loopback only"),
        ([{"token": "u", "role": "unit", "units": ["*"]}, {"token": "r", "role": "reader"},
          {"token": "a", "role": "admin"}], "tokens: on (3)"),
    ],
)  # fmt: skip
def test_serve_says_where_it_listens_and_whether_tokens_are_on(tmp_path, tokens, said):
    flags = []
    if tokens is not None:
        (tmp_path / "server.yaml").write_text(json.dumps({"tokens": tokens}))
        flags = ["--config", str(tmp_path / "server.yaml")]
    server, line = serve_until_listening(tmp_path, *flags)
    try:
        match = re.fullmatch(
            r"fleetmap serve: listening on (http://127\.0\.0\.1:(\d+)/) \(viewer; API docs at "
            r"\1docs\); (.*)",
            line,
        )
        assert match, line
        url, port, tokens_said = match.groups()
        assert int(port) > 0 and tokens_said == said  # --port 0: the port it got
        assert httpx.get(url + "healthz").json()["status"] == "ok"
        assert httpx.get(url + "docs").status_code == 200
    finally:
        server.terminate()
        server.wait(timeout=20)
