"""Every ``fleetmap`` command's ``--help`` is plain text: no reStructuredText or Markdown
markup (``code``, `quotes`, :roles:, directives, **bold**) from the docstrings."""

import argparse
import re
import subprocess
import sys

from scenarios.cli.main import build_parser

MARKUP = re.compile(r"`|:[a-z]+:`|^\s*\.\. |\*\*|\|\w+\|", re.MULTILINE)


def commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    """(words, parser) for ``parser`` and every subcommand under it, depth first."""
    yield prefix, parser
    for action in parser._actions:  # argparse keeps subcommands in its _SubParsersAction
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from commands(sub, (*prefix, name))


def test_every_commands_help_is_plain_text():
    seen = []
    for words, parser in commands(build_parser()):
        text = parser.format_help()
        assert not MARKUP.search(text), (words, MARKUP.search(text).group(0), text)
        seen.append(" ".join(words))
    assert {"", "plan", "run", "compare", "serve", "map build", "journal check"} <= set(seen)


def test_plan_help_as_printed_describes_the_command_plainly():
    done = subprocess.run([sys.executable, "-m", "scenarios.cli.main", "plan", "--help"],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 0  # (stderr may hold pybullet's build banner: another change)
    assert done.stdout.startswith("usage: fleetmap plan [-h] --start X,Y --goal X,Y")
    assert "Plan a path on a saved map (a ROS map YAML)" in done.stdout
    assert "`" not in done.stdout


def test_every_option_with_a_default_shows_it_in_help():
    """An option that has a default (not None, not an off switch's False) says it: the
    formatter's ``(default: X)`` or the help's own words (``default: sized from the data``)."""
    checked = 0
    for words, parser in commands(build_parser()):
        formatter = parser._get_formatter()
        for action in parser._actions:
            default = action.default
            if not action.option_strings or action.help == argparse.SUPPRESS:
                continue
            if default is None or default is argparse.SUPPRESS or default is False:
                continue
            shown = formatter._expand_help(action) if action.help else ""
            assert "default" in shown, (words, action.option_strings, shown)
            checked += 1
    assert checked > 60  # map build alone has 30 such flags
    build = dict(commands(build_parser()))[("map", "build")].format_help()
    assert "(default: 0.05)" in " ".join(build.split())  # --resolution
    assert "(default: None)" not in " ".join(build.split())
