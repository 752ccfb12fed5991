"""Scenarios: compose the fleet, the map server and the planners; score runs; the CLI."""
