"""The vendored real scan and constructed 3-D scans shared by the motion tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nanoct.io.scanio import line_integrals, read_scan

I13 = Path(__file__).resolve().parents[1] / "data" / "realdata" / "i13-24737-tiff"


@pytest.fixture(scope="session")
def i13(tmp_path_factory):
    """Diamond I13-2 scan 24737: line integrals (91, 135, 160) and angles (rad); open beam at ~0.4 absorbance."""
    angles = np.loadtxt(I13 / "angles.txt")[10:101]  # lines 11-101: the projections (README.md there)
    path = tmp_path_factory.mktemp("i13") / "angles.txt"
    np.savetxt(path, angles)
    scan = read_scan(I13 / "tiffs", angles_file=path, flats=I13 / "flat_00001.tiff", darks=I13 / "dark_00001.tiff")
    return line_integrals(scan).astype(np.float64), np.deg2rad(angles)
