"""The ``fleetmap`` command: ``scenarios.cli.main:main`` and its subcommands."""
