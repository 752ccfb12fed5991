"""Running a scenario: the episode (simulator, map server, coordinator, units), its
observers and record, and writing a run's outputs."""
