"""Every X,Y option takes negative values as written (``--origin -12,-25``), in every
command: argparse alone reads ``-12,-25`` as an unknown option."""

import argparse

import pytest

from mapserver.cli.args import xy_pair
from scenarios.cli.main import build_parser


def xy_options(parser: argparse.ArgumentParser, path=()):
    """(command path, option) of every option typed X,Y or X,Y,YAW in the parser tree."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from xy_options(sub, (*path, name))
        elif action.option_strings and (
            action.type is xy_pair or getattr(action.type, "__name__", "") == "pose_triple"
        ):
            yield path, action.option_strings[-1], action.type


OPTIONS = list(xy_options(build_parser()))


def test_the_commands_have_xy_options():
    names = {(" ".join(path), option) for path, option, _ in OPTIONS}
    assert {("map build", "--origin"), ("evaluate", "--origin"), ("plan", "--start")} <= names
    assert ("plan", "--goal") in names
    assert {("map build", "--fixed-sensor"), ("import", "--fixed-sensor")} <= names
    assert ("evaluate", "--fixed-sensor") in names


@pytest.mark.parametrize(
    "path, option, kind",
    OPTIONS,
    ids=[f"{' '.join(path)} {option}" for path, option, _ in OPTIONS],
)
def test_negative_values_are_read_as_written(path, option, kind, tmp_path):
    value = "-12,-25" if kind is xy_pair else "-12,-25,-1.5"
    positional = {
        "map build": [str(tmp_path / "s.jsonl")],
        "evaluate": [str(tmp_path / "s.jsonl")],
        "plan": [str(tmp_path / "m.yaml")],
        "import": [str(tmp_path / "s.jsonl"), "--server", "http://127.0.0.1:8700"],
        "zones": ["--width", "10", "--height", "10", "--zones", "1"],
    }
    argv = [*path, *positional.get(" ".join(path), []), option, value]
    if path == ("plan",):
        other = "--goal" if option == "--start" else "--start"
        argv += [other, "-.5,-0.25"]
    args = build_parser().parse_args(argv)
    parsed = getattr(args, option.lstrip("-").replace("-", "_"))
    expected = (-12.0, -25.0) if kind is xy_pair else (-12.0, -25.0, -1.5)
    if hasattr(parsed, "yaw"):  # a Pose2D
        parsed = (parsed.x, parsed.y, parsed.yaw)
    assert parsed == expected


def test_a_malformed_pair_still_names_the_value(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["plan", "m.yaml", "--start", "-1", "--goal", "0,0"])
    assert "expected X,Y in metres, got '-1'" in capsys.readouterr().err
