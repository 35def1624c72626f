"""Storage and files: the Zarr store, its chunks and reconstruction arrays, measured scans, atomic writes,
provenance."""
