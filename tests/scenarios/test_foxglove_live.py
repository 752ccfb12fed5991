"""``fleetmap run --foxglove``: the replay's channels live over the Foxglove WebSocket
protocol, from a real run in a subprocess read by a real ``websockets`` client; and the
errors of the flag (no SDK, a bad or busy port)."""

from __future__ import annotations

import json
import queue
import re
import socket
import struct
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from scenarios.cli.main import build_parser, main
from scenarios.cli.run import FOXGLOVE_PORT, _foxglove_port
from scenarios.replay.live import FIXED_CHANNELS
from scenarios.replay.metrics_channel import VERDICTS

ROOT = Path(__file__).resolve().parents[2]
TINY = "scenarios/tiny.yaml"
SUBPROTOCOL = "foxglove.sdk.v1"  # the Foxglove SDK 0.30 server's (it refuses others)
MESSAGE_DATA = 0x01  # server binary opcode: op, uint32 subscription id, uint64 ns, payload
LISTENING = re.compile(r"^Foxglove: (ws://127\.0\.0\.1:\d+) \(open in Foxglove: Open connection\)$")
WATCHED = ("/scene", "/metrics", "/tf")


def _stderr_lines(proc: subprocess.Popen) -> queue.Queue:
    lines: queue.Queue = queue.Queue()

    def pump() -> None:
        for line in proc.stderr:
            lines.put(line.rstrip("\n"))
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return lines


def _address(lines: queue.Queue) -> str:
    while (line := lines.get(timeout=120)) is not None:
        if match := LISTENING.match(line):
            return match.group(1)
    raise AssertionError("the run never said where Foxglove can connect")


def _listen(url: str):
    """(serverInfo, advertised channels by id, [(topic, ns, payload)]) until the run's
    server closes the connection; subscribes to the WATCHED topics once advertised."""
    advertised: dict[int, dict] = {}
    subscribed: dict[int, str] = {}  # subscription id -> topic
    received = []
    with connect(url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=30) as ws:
        info = json.loads(ws.recv(timeout=30))
        try:
            while True:
                frame = ws.recv(timeout=120)
                if isinstance(frame, str):
                    message = json.loads(frame)
                    if message["op"] != "advertise":
                        continue
                    new = []
                    for channel in message["channels"]:
                        advertised[channel["id"]] = channel
                        if channel["topic"] in WATCHED:
                            subscribed[len(subscribed) + 1] = channel["topic"]
                            new.append({"id": len(subscribed), "channelId": channel["id"]})
                    if new:
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                    continue
                op, subscription, ns = struct.unpack_from("<BIQ", frame)
                assert op == MESSAGE_DATA
                received.append((subscribed[subscription], ns, bytes(frame[13:])))
        except ConnectionClosed:
            pass
    return info, advertised, received


def _replay(path: Path):
    """({topic: (schema name, schema text)}, {topic: {(log time, payload)}})."""
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {
            ch.topic: (summary.schemas[ch.schema_id].name, summary.schemas[ch.schema_id].data)
            for ch in summary.channels.values()
        }
        f.seek(0)
        messages: dict[str, set] = {}
        for _, channel, message in make_reader(f).iter_messages(topics=list(WATCHED)):
            messages.setdefault(channel.topic, set()).add((message.log_time, message.data))
    return schemas, messages


@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("live")
    proc = subprocess.Popen(
        [sys.executable, "-m", "scenarios.cli.main", "run", TINY, "--out", str(out),
         "--foxglove-port=0"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        url = _address(_stderr_lines(proc))
        heard = _listen(url)
        assert proc.wait(timeout=300) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return (*heard, *_replay(out / "replay.mcap"))


def test_the_live_server_advertises_the_replays_topics_with_their_schemas(live_run):
    info, advertised, _, schemas, _ = live_run
    assert info["op"] == "serverInfo" and info["name"] == "fleetmap"
    topics = {c["topic"] for c in advertised.values()}
    assert {c.topic for c in FIXED_CHANNELS} <= topics
    assert {"/units/u1/scan", "/units/u2/scan", "/units/u1/plan", "/units/u2/plan"} <= topics
    assert topics <= set(schemas)  # nothing live that the replay lacks
    for channel in advertised.values():
        name, text = schemas[channel["topic"]]
        assert (channel["encoding"], channel["schemaEncoding"]) == ("json", "jsonschema")
        assert channel["schemaName"] == name
        assert json.loads(channel["schema"]) == json.loads(text)


def test_live_scene_and_frames_are_the_replays_messages_byte_for_byte(live_run):
    _, _, received, _, replay = live_run
    for topic in ("/scene", "/tf"):
        live = [(ns, payload) for t, ns, payload in received if t == topic]
        assert len(live) >= 10, topic
        assert set(live) <= replay[topic], topic
    scene = [json.loads(p) for t, _, p in received if t == "/scene"]
    objects = {e["id"] for u in scene for e in u["entities"] if e["id"].startswith("object/")}
    assert {"object/rack-1", "object/tote-1", "object/wall-n"} <= objects


def test_live_metrics_are_the_replays_without_the_freeze_verdicts(live_run):
    _, _, received, _, replay = live_run
    recorded = {ns: json.loads(data) for ns, data in replay["/metrics"]}
    live = [(ns, json.loads(p)) for t, ns, p in received if t == "/metrics"]
    assert len(live) >= 10
    for ns, message in live:
        verdicts = set(VERDICTS)
        assert not verdicts & set(message)
        assert message == {k: v for k, v in recorded[ns].items() if k not in verdicts}
    assert live[-1][0] == max(recorded)  # the last sample, at the run's end, went out too


# ------------------------------------------------------------------------------ errors
def _error_line(capsys) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1, err
    return err[0]


def test_without_the_sdk_foxglove_fails_at_once_saying_how_to_install(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove: ImportError
    assert main(["run", TINY, "--out", str(tmp_path), "--foxglove"]) == 2
    assert _error_line(capsys) == (
        "fleetmap run: error: --foxglove needs the Foxglove SDK (foxglove-sdk): "
        "pip install 'fleetmap[foxglove]'"
    )
    assert list(tmp_path.iterdir()) == []  # nothing ran


def test_a_busy_port_fails_at_once_naming_it(tmp_path, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["run", TINY, "--out", str(tmp_path), f"--foxglove-port={port}"]) == 2
    line = _error_line(capsys)
    assert line.startswith(f"fleetmap run: error: --foxglove: cannot listen on 127.0.0.1:{port} (")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("port", ["70000", "-1", "http"])
def test_a_bad_port_is_refused_naming_the_value(port, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["run", TINY, f"--foxglove-port={port}"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "argument --foxglove-port: PORT must be an integer 0-65535, got " in err
    assert port in err.splitlines()[-1]


def test_foxglove_is_a_flag_so_the_scenario_may_follow_it():
    parser = build_parser()
    args = parser.parse_args(["run", "--foxglove", TINY])
    assert (args.scenario, args.foxglove, args.foxglove_port) == (Path(TINY), True, None)
    assert _foxglove_port(args) == FOXGLOVE_PORT
    args = parser.parse_args(["run", TINY, "--foxglove-port", "9001"])
    assert _foxglove_port(args) == 9001  # the port alone turns the stream on
    assert _foxglove_port(parser.parse_args(["run", TINY])) is None
