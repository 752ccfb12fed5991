"""Scenario files: the format, its YAML line map and validation, layouts, events, the map
server section and the task stream."""
