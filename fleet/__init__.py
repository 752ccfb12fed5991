"""The simulated fleet: PyBullet warehouse, drive units and their LiDARs.

- ``boxworld``: the analytic planar box world and warehouse generator (no physics).
- ``shapes``, ``layout``: footprints, and the warehouse layout a world is built from.
- ``bullet``: PyBullet (the ``sim`` extra), imported quietly, or a clear error without it.
- ``world``: the PyBullet world (obstacles by id, unit bodies, contacts, ray casts).
- ``lidar``, ``localization``, ``unit``: a unit's sensor, pose estimate and drive.
- ``sim``, ``poster``: the sim clock and step loop; posting scans to the map server.
- ``ground_truth``: the true geometry on the map's grid, inflated as the server does.

It knows nothing of planning: units follow the paths they are given.
"""
