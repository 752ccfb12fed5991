"""The simulated fleet: PyBullet warehouse, drive units and their LiDARs."""
