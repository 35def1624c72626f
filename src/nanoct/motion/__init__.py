"""Motion and rotation-axis estimation for measured scans.

The layer above :mod:`nanoct.recon` (whose solvers and projectors it uses to reconstruct and
reproject) and below :mod:`nanoct.workflows`.
"""
