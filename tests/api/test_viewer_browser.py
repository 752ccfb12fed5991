"""The live viewer in headless Chromium against a real ``fleetmap serve`` on loopback.

Chromium is driven over the DevTools protocol (``browser_helpers``). The server runs with
tokens, so the page gets its reader token from the URL fragment (or a prompt). Pixels are
read from the page's canvas at a cell's centre (``fleetmapViewer.pixelAt``) and compared
with the palette the server's PNG replies use.
"""

import json
import re

import httpx
import numpy as np
import pytest
from browser_helpers import Browser, chromium_or_skip
from server_helpers import ServerProcess, scan_body

from mapserver.api.render import cost_palette, occupancy_palette
from mapserver.client import MapClient, UnitState
from mapserver.core.costvalues import FREE, LETHAL, UNKNOWN
from mapserver.core.scan import Pose2D

UNIT, READER = "unit-token", "reader-token"
LETHAL_CELL = (80, 50)  # (col, row): where scan_body's beams from (5, 5) end, at x = 8.05
FREE_CELL = (60, 50)  # crossed by three scans' beams, two metres from any return
UNKNOWN_CELL = (250, 20)  # never observed
NEW_CELL = (230, 150)  # the return, at x = 23.05, of a scan posted from (20, 15) later


def rgba(palette: np.ndarray, value: int) -> list[int]:
    return [*palette[value].tolist(), 255]


@pytest.fixture(scope="module")
def chromium():
    return chromium_or_skip()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    folder = tmp_path_factory.mktemp("viewer-server")
    config = folder / "server.yaml"
    tokens = [{"token": UNIT, "role": "unit", "units": ["*"]}, {"token": READER, "role": "reader"}]
    config.write_text(json.dumps({"tokens": tokens}))
    process = ServerProcess(folder / "data", config=config)
    with httpx.Client(base_url=process.url) as http:
        writer = MapClient(http, token=UNIT)
        for stamp in (1.0, 2.0, 3.0):
            writer.post_scan(scan_body(stamp=stamp))
        yield process, http
    process.stop()


@pytest.fixture(scope="module")
def page(chromium, server, tmp_path_factory):
    process, _ = server
    browser = Browser(chromium, tmp_path_factory.mktemp("chromium-profile"))
    try:
        browser.open(f"{process.url}/#token={READER}")
        browser.evaluate("fleetmapViewer.ready.then(() => true)")
        yield browser
    finally:
        browser.close()


def server_grid(http, path, dtype):
    reply = http.get(path, params={"format": "raw"}, headers={"Authorization": f"Bearer {READER}"})
    return np.frombuffer(reply.content, dtype=dtype).reshape(200, 300)


def pixel(page, cell) -> list[int]:
    return page.evaluate(f"fleetmapViewer.pixelAt({cell[0]}, {cell[1]})")


def near(drawn: list[int], colour: list[int], tolerance: int = 3) -> bool:
    """A shape's pixel is its colour up to the canvas's rounding (map cells are exact)."""
    rgb = drawn[:3]
    return drawn[3] == 255 and all(
        abs(a - b) <= tolerance for a, b in zip(rgb, colour, strict=True)
    )


def test_the_page_loads_without_console_errors_and_hides_the_token(page):
    assert page.wait_for("fleetmapViewer.version === 3")
    assert page.console_errors() == []
    assert page.evaluate("location.hash") == ""  # the token left the address bar
    assert page.evaluate("document.querySelector('.meta-resolution').textContent") == "0.1 m/cell"
    assert page.evaluate("document.querySelector('.meta-policy').textContent") == "dual"


def test_the_costmap_shows_lethal_free_and_unknown_cells_in_their_colours(page, server):
    costs = server_grid(server[1], "/v1/costmap", np.uint8)
    palette = cost_palette()
    for (col, row), value in ((LETHAL_CELL, LETHAL), (FREE_CELL, FREE), (UNKNOWN_CELL, UNKNOWN)):
        assert costs[row, col] == value
        assert pixel(page, (col, row)) == rgba(palette, value)


def test_a_new_scan_appears_without_a_reload(page, server):
    process, http = server
    page.evaluate("window.sameDocument = true")
    full_reads = page.requested("/v1/costmap?format=raw")
    updates = page.requested("/v1/costmap/updates")
    navigations = len(page.named("Page.frameNavigated"))
    assert pixel(page, NEW_CELL) == rgba(cost_palette(), UNKNOWN)
    MapClient(http, token=UNIT).post_scan(scan_body(stamp=4.0, unit="u2", x=20.0, y=15.0))
    lethal = rgba(cost_palette(), LETHAL)
    drawn = f"fleetmapViewer.pixelAt({NEW_CELL[0]}, {NEW_CELL[1]}).join()"
    page.wait_for(f"{drawn} === '{','.join(map(str, lethal))}'")
    assert page.requested("/v1/costmap?format=raw") == full_reads == 1
    assert page.requested("/v1/costmap/updates") > updates
    assert page.evaluate("window.sameDocument === true && fleetmapViewer.stats.patchesApplied > 0")
    assert len(page.named("Page.frameNavigated")) == navigations
    assert page.console_errors() == []


PATH_UNITS = [  # u1 moving along a path, u7 frozen
    UnitState.of(
        "u1", 4.0, Pose2D(3.05, 15.05, 0.0), ((3.05, 15.05), (10.05, 15.05)), activity="moving"
    ),
    UnitState.of("u7", 4.0, Pose2D(25.05, 5.05, 1.0), frozen=True, reason="no path: aisle blocked"),
]


def test_units_are_drawn_with_their_paths_and_frozen_units_are_marked(page, server):
    MapClient(server[1], token=UNIT).publish_units(PATH_UNITS)
    page.wait_for("document.querySelector('#units li[data-unit=\"u7\"].frozen') !== null")
    reason = "document.querySelector('#units li[data-unit=\"u7\"] .reason').textContent"
    assert page.evaluate(reason) == "no path: aisle blocked"
    colours = page.evaluate("fleetmapViewer.colours")
    assert near(pixel(page, (250, 50)), colours["frozen"])  # u7's centre
    assert near(pixel(page, (30, 150)), colours["unit"])  # u1's centre
    on_path = [pixel(page, (col, 150)) for col in range(60, 90)]  # along u1's dashed path
    assert any(near(p, colours["path"]) for p in on_path)


STATE_UNITS = [  # (unit, activity, where [m]): a column at x = 15.05, 3 m apart
    ("u10", "broken_down", (15.05, 2.05)),
    ("u2", "waiting", (15.05, 5.05)),
    ("u11", "idle", (15.05, 8.05)),
    ("u3", "dwelling", (15.05, 11.05)),
    ("u20", None, (15.05, 17.05)),  # a fleet that posts no activity
]
STATE_WORDS = {
    "moving": "moving",
    "waiting": "waiting for traffic",
    "frozen": "frozen",
    "broken_down": "broken down",
    "dwelling": "dwelling at a stop",
    "idle": "idle (no task)",
}
LIST_UNITS = """[...document.querySelectorAll('#units li')]
    .map(li => [li.dataset.unit, li.querySelector('.state').textContent])"""
LEGEND_STATES = """[...document.querySelectorAll('#legend li.state')]
    .map(li => [li.dataset.state, li.textContent])"""


def publish(server, stamp, placed) -> None:
    """Post the states of ``placed`` units, (unit, activity, (x, y) [m]), at ``stamp``."""
    states = [UnitState.of(u, stamp, Pose2D(x, y, 0.0), activity=a) for u, a, (x, y) in placed]
    MapClient(server[1], token=UNIT).publish_units(states)


def test_units_are_listed_in_natural_order_with_their_state_in_words_look_and_legend(page, server):
    # u1 and u7 as the test before posts them (xdist may run this one without it)
    MapClient(server[1], token=UNIT).publish_units(PATH_UNITS)
    publish(server, 5.0, STATE_UNITS)
    page.wait_for("document.querySelectorAll('#units li').length === 7")
    assert page.evaluate(LIST_UNITS) == [
        ["u1", "moving"],  # PATH_UNITS, at (3.05, 15.05)
        ["u2", "waiting for traffic"],
        ["u3", "dwelling at a stop"],
        ["u7", "frozen"],  # frozen: true, no activity
        ["u10", "broken down"],
        ["u11", "idle (no task)"],
        ["u20", "state not posted"],
    ]
    assert page.evaluate(LEGEND_STATES) == [
        *([key, words] for key, words in STATE_WORDS.items()),
        ["unreported", "state not posted"],
    ]
    looks = page.evaluate("fleetmapViewer.states")
    assert {key: look["words"] for key, look in looks.items()} == STATE_WORDS
    assert looks["frozen"]["colour"] == [229, 72, 77]  # frozen stays red
    assert len({tuple(look["colour"]) for look in looks.values()}) == 6
    assert len({look["shape"] for look in looks.values()}) == 5  # idle: a grey disc
    drawn = {  # one cell above each centre: inside every marker, off the broken-down cross
        "moving": pixel(page, (30, 151)),
        "frozen": pixel(page, (250, 51)),
        **{
            activity or "unreported": pixel(page, (150, round(y * 10) + 1))
            for _, activity, (_, y) in STATE_UNITS
        },
    }
    for key, colour in drawn.items():
        expected = looks[key]["colour"] if key in looks else [100, 116, 139]
        assert near(colour, expected), (key, colour)
    # the comparator itself: digit runs as numbers, then code units for a total order
    ids = ["u10", "u2", "u1", "a", "u02", "U1", "u1b", "u100"]
    ordered = page.evaluate(
        f"{json.dumps(ids)}.map(id => ({{unit_id: id}})).sort(fleetmapViewer.byUnitId)"
        ".map(u => u.unit_id)"
    )
    assert ordered == ["a", "u1", "U1", "u1b", "u02", "u2", "u10", "u100"]
    assert page.console_errors() == []


def test_the_occupancy_and_age_views_show_the_servers_values(page, server):
    http = server[1]
    try:
        page.evaluate("fleetmapViewer.setView('occupancy')")
        occupancy = server_grid(http, "/v1/map", np.int8)
        for col, row in (LETHAL_CELL, FREE_CELL, UNKNOWN_CELL):
            value = int(occupancy[row, col])
            assert page.evaluate(f"fleetmapViewer.valueAt({col}, {row})") == value
            assert pixel(page, (col, row)) == rgba(occupancy_palette(), value & 255)
        page.evaluate("fleetmapViewer.setView('age')")
        ages = server_grid(http, "/v1/map/age", "<f4")
        col, row = LETHAL_CELL
        assert page.evaluate(f"fleetmapViewer.valueAt({col}, {row})") == float(ages[row, col])
        assert page.evaluate("fleetmapViewer.valueAt(250, 20)") is None  # never observed
        assert pixel(page, UNKNOWN_CELL) == rgba(cost_palette(), UNKNOWN)
        assert page.requested("/v1/map/age?format=raw") >= 1
    finally:
        page.evaluate("fleetmapViewer.setView('costmap')")
    assert page.console_errors() == []


def test_without_a_token_the_page_asks_for_one_and_sends_it(page, server):
    process, _ = server
    page.evaluate("sessionStorage.clear()")
    page.call("Page.navigate", url=f"{process.url}/")
    dialog = page.wait_event("Page.javascriptDialogOpening")
    assert dialog["params"]["type"] == "prompt"
    page.call("Page.handleJavaScriptDialog", accept=True, promptText=READER)
    page.evaluate("fleetmapViewer.ready.then(() => true)")
    assert page.evaluate("sessionStorage.getItem('fleetmap.token')") == READER
    assert pixel(page, LETHAL_CELL) == rgba(cost_palette(), LETHAL)


GONE = re.compile(
    r"The map server at (http://127\.0\.0\.1:\d+/) is not answering since "
    r"\d\d:\d\d:\d\d; retrying"
)
BANNER = "document.querySelector('#banner')"


def test_the_page_says_when_its_server_is_gone_and_resumes_when_it_is_back(page, server, tmp_path):
    """Its own open server, stopped and started again on the same port and data dir."""
    first = ServerProcess(tmp_path / "data")
    second = None
    try:
        with httpx.Client(base_url=first.url) as http:
            MapClient(http).post_scan(scan_body(stamp=1.0))
        page.open(f"{first.url}/")
        page.evaluate("fleetmapViewer.ready.then(() => true)")
        assert page.wait_for("fleetmapViewer.version === 1")
        assert page.evaluate(f"{BANNER}.hidden") is True
        first.stop()
        text = page.wait_for(f"!{BANNER}.hidden && {BANNER}.textContent", timeout=20)
        assert GONE.fullmatch(text) and GONE.fullmatch(text).group(1) == f"{first.url}/"
        assert page.evaluate("fleetmapViewer.serverGone") is True
        assert page.evaluate("document.querySelector('#stage').classList.contains('stale')")
        note = page.evaluate("document.querySelector('#stale-note').textContent")
        assert note.startswith("stale: the last map received at ") and "(version 1," in note
        assert pixel(page, LETHAL_CELL) == rgba(cost_palette(), LETHAL)  # the map stays
        second = ServerProcess(tmp_path / "data", port=first.port)
        with httpx.Client(base_url=second.url) as http:
            MapClient(http).post_scan(scan_body(stamp=2.0))
        assert page.wait_for(f"{BANNER}.hidden && fleetmapViewer.version === 2", timeout=20)
        assert page.evaluate("fleetmapViewer.serverGone") is False
        assert not page.evaluate("document.querySelector('#stage').classList.contains('stale')")
        assert page.evaluate("document.querySelector('#stale-note').hidden") is True
    finally:
        for process in (first, second):
            if process is not None:
                process.stop()
        page.open(f"{server[0].url}/#token={READER}")
        page.evaluate("fleetmapViewer.ready.then(() => true)")


CLUSTER = [  # (unit, activity, where [m]): five units 0.5 m apart, long labels among them
    ("p1", "moving", (22.05, 12.05)),
    ("p10", "broken_down", (22.55, 12.05)),  # its label used to cover p1
    ("p2", "waiting", (22.05, 12.55)),
    ("p11", "idle", (22.55, 12.55)),
    ("p3", None, (23.05, 12.05)),
]
WHITE_IN_BOX = """(box => {
    const c = document.querySelector('#map');
    const w = Math.floor(box.right - box.left), h = Math.floor(box.bottom - box.top);
    const img = c.getContext('2d').getImageData(Math.ceil(box.left), Math.ceil(box.top), w, h);
    const d = img.data;
    let white = 0;
    for (let i = 0; i < d.length; i += 4) white += d[i] > 200 && d[i + 1] > 200 && d[i + 2] > 200;
    return white;
})"""


def test_labels_of_units_half_a_metre_apart_do_not_overlap_labels_or_markers(page, server):
    publish(server, 6.0, CLUSTER)
    page.wait_for("fleetmapViewer.labels.some(l => l.unit_id === 'p3')")
    labels = {label["unit_id"]: label for label in page.evaluate("fleetmapViewer.labels")}
    reach = page.evaluate("fleetmapViewer.markerReach")
    width, height = page.evaluate("[document.querySelector('#map').width, "
                                  "document.querySelector('#map').height]")  # fmt: skip
    cluster = [labels[uid] for uid, _, _ in CLUSTER]
    spacing = abs(cluster[1]["x"] - cluster[0]["x"])  # 0.5 m on the canvas [px]
    assert spacing < 2 * reach  # close enough that their markers' surroundings overlap
    for a in labels.values():
        assert 0 <= a["left"] and a["right"] <= width and 0 <= a["top"] and a["bottom"] <= height
        for b in labels.values():
            if a is not b:
                assert not boxes_overlap(a, b), (a, b)
                marker = {"left": b["x"] - reach, "right": b["x"] + reach,
                          "top": b["y"] - reach, "bottom": b["y"] + reach}  # fmt: skip
                assert not boxes_overlap(a, marker), (a["unit_id"], "covers", b["unit_id"])
        page.wait_for(f"{WHITE_IN_BOX}({json.dumps(a)}) >= 8")  # its text is painted there
    assert any(label["leader"] for label in cluster)  # the crowded ones moved, tied by a line
    assert not labels["p1"]["leader"]  # the first in natural order sits beside its marker
    assert page.console_errors() == []


def boxes_overlap(a, b) -> bool:
    return (
        a["left"] < b["right"]
        and b["left"] < a["right"]
        and a["top"] < b["bottom"]
        and b["top"] < a["bottom"]
    )
