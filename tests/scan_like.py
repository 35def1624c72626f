"""A constructed measured scan with a known noise level, axis and motion, for the matched-set tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nanoct.core.geometry import Geometry
from nanoct.io.store import DataStore, create_scan
from nanoct.sim.analytic import Ellipse, ellipse_sinogram

#: Views (degrees, not starting at 0: the scan keeps its own angles), detector, slices, axis offset, noise, air.
ANGLES_DEG = np.arange(48) * 3.75 - 88.0
N_DET, SLICES, OFFSET, SIGMA, AIR = 64, 6, 1.5, 0.02, 0.35


def scan_store(path: Path, *, shifts: np.ndarray | None = None, seed: int = 0) -> DataStore:
    """An imported-looking scan: ellipses inside the field of view, an open-beam level with a slope, white noise.

    ``shifts`` (K,) in detector pixels are recorded as the motion of a stack result ``fbp_stack``
    (with an axis 0.5 px from the import's), as ``nanoct stack`` records it.
    """
    rng = np.random.default_rng(seed)
    angles = np.deg2rad(ANGLES_DEG)
    sinos = []
    for i in range(SLICES):
        body = [Ellipse(0.0, 0.0, 11.0, 8.0, 0.3 * i, 0.05), Ellipse(3.0, -2.0, 3.0, 2.0, 0.0, 0.1)]
        clean = ellipse_sinogram(body, angles, N_DET, center_offset=OFFSET)
        level = AIR + 0.01 * np.linspace(-1, 1, N_DET)[None, :] + 0.005 * np.sin(angles)[:, None]
        sinos.append(clean + level + rng.normal(0.0, SIGMA, clean.shape))
    geometry = Geometry.from_angles(angles, N_DET, N_DET, center_offset=OFFSET)
    store = create_scan(path, geometry, np.stack(sinos), {"file": "constructed", "format": "npy"})
    if shifts is not None:
        store.prepare_reconstruction("fbp_stack", {"method": "fbp"}, shifts=True)
        store.recons.set_shared_shifts("fbp_stack", shifts)
        store.recons.set_motion_info("fbp_stack", {"center_offset": OFFSET + 0.5})
    return store
