"""``fleetmap evaluate``: a verdict on a recording without ground truth (docs/evaluate.md).

``sight`` (what the scans saw, map-independent), ``maps`` (the maps under test: a
fleetmap grid per policy) and ``octomap_peer`` (OctoMap beside them), ``measures`` (the
verdict's figures), ``run`` (one pass over the recording, every map in lockstep),
``report`` (Markdown and CSV) and ``picture`` (evaluate.png)."""
