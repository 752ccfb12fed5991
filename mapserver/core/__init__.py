"""The pure core of the map: grid geometry, cost values, the sensor model, scans, the
belief grid and its numba kernels (fusion, obstacle marking, inflation, queries).

Imports only the standard library, numpy and numba (``tests/test_import_directions.py``).
"""
