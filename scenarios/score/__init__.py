"""Scoring a run: freezes and their evidence, clearing, collisions, map against truth,
throughput, trips, and report.png."""
