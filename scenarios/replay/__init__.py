"""A run's replay: replay.mcap (Foxglove schemas and messages, scene objects, fused scans,
metrics channels) and ``fleetmap replay``."""
