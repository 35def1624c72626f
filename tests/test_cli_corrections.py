"""`nanoct import` with the corrections on real scans: the open beam of I13 and the rings of the neutron scan."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nanoct.cli import run
from nanoct.io.store import DataStore
from nanoct.preprocess import Corrections
from nanoct.preprocess.rings import ring_metric
from nanoct.recon.stack import corrected_fbp

REAL = Path(__file__).resolve().parent / "data" / "realdata"


def test_open_beam_normalisation_takes_i13_air_to_zero(tmp_path):
    i13 = REAL / "i13-24737-tiff"
    flats, darks = str(i13 / "flat_00001.tiff"), str(i13 / "dark_00001.tiff")
    argv = ["import", str(i13 / "tiffs"), "--angles", str(i13 / "angles.txt"), "--angles-select", "10:101",
            "--flats", flats, "--darks", darks, "--rows", "60:70"]  # fmt: skip
    assert run([*argv, "--out", str(tmp_path / "raw"), "-q"]) == 0
    assert run([*argv, "--out", str(tmp_path / "norm"), "--open-beam", "-q"]) == 0
    raw, norm = DataStore.open(tmp_path / "raw"), DataStore.open(tmp_path / "norm")
    air = (slice(None), slice(None), slice(2, 27))  # columns that see only air in every view
    assert np.median(raw.read_array("sinograms", list(range(10)))[air]) > 0.3
    assert abs(np.median(norm.read_array("sinograms", list(range(10)))[air])) < 0.02
    assert Corrections.from_dict(norm.meta["scan"]["corrections"]) == Corrections(open_beam=True)
    assert "corrections" not in raw.meta["scan"]


@pytest.mark.slow
def test_stripe_removal_lowers_the_ring_metric_of_the_neutron_slice(tmp_path):
    neutron = REAL / "neutron-360-sinogram" / "sinogram_360_neutron_image.tif"
    argv = ["import", str(neutron), "--angles", "0:360", "--open-beam", "--center-offset", "auto", "-q"]
    assert run([*argv, "--out", str(tmp_path / "rings")]) == 0
    assert run([*argv, "--stripes", "all", "--out", str(tmp_path / "clean")]) == 0
    metric = {}
    for name in ("rings", "clean"):
        store = DataStore.open(tmp_path / name)
        image = corrected_fbp(store.geometry, store.read_array("sinograms", [0])[0])
        metric[name] = ring_metric(image, offset=(0.0, store.geometry.center_offset))
    # the import fills the dead pixels' zero counts from their rows; the rings left are the other pixels'
    assert metric["clean"] < metric["rings"] / 3, metric  # measured 3.8x
