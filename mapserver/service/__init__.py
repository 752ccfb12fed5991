"""The map service: one data dir's shared map (ingest, reads, plans' costmaps), its
settings, the scan gate and the map's clock, and journal replay."""
