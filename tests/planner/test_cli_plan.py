"""``fleetmap plan`` on a saved ROS map."""

import json

import numpy as np

from mapserver.core.geometry import GridGeometry
from mapserver.store.mapfiles import write_ros_map
from scenarios.cli.main import main


def saved_map(tmp_path):
    occupancy = np.zeros((20, 40), np.int8)  # 4 m x 2 m at 0.1 m, all free ...
    occupancy[:15, 20] = 100  # ... with a wall from the bottom, open at the top
    return write_ros_map(tmp_path, occupancy, GridGeometry(40, 20, 0.1))


def test_plan_on_a_saved_map_goes_around_the_wall(tmp_path, capsys):
    code = main(["plan", str(saved_map(tmp_path)), "--start", "0.5,0.5", "--goal", "3.5,0.5",
                 "--json"])  # fmt: skip
    assert code == 0
    plan = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert plan["found"] and plan["map_version"] == 0
    assert max(y for _, y in plan["path"]) > 1.5  # over the top of the wall
    assert plan["min_clearance"] >= 0.3  # never within the inscribed radius


def test_plan_reports_no_path_and_bad_points(tmp_path, capsys):
    path = str(saved_map(tmp_path))
    assert main(["plan", path, "--start", "0.5,0.5", "--goal", "9,9"]) == 2
    assert "goal: must be on the map" in capsys.readouterr().err
    assert main(["plan", str(tmp_path / "missing.yaml"), "--start", "0,0", "--goal", "1,1"]) == 2
