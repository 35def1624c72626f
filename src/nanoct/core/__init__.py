"""Foundations: errors, input checks, scan geometry, ray transforms, Dask fan-out."""
