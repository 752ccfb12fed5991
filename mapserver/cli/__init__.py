"""The map server's commands (``fleetmap serve``, ``replay``, ``map build``,
``journal``), registered by ``scenarios.cli.main``."""
