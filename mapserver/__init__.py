"""The shared map: the belief grid (pure numpy/numba core) and, later, its HTTP service."""
