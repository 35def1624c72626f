"""HDF5 scans of any layout: Diamond's scan NeXus (the real K11 file), a Diamond NXtomo subentry, and a
layout given by dataset paths, with external links and virtual datasets."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.io.h5tree import H5Tree
from nanoct.io.hdf5_layouts import detect_layout
from nanoct.io.scanio import ReaderOptions, detect_format, line_integrals, read_scan

K11 = Path(__file__).resolve().parents[1] / "data" / "realdata" / "k11-18014-nexus" / "k11-18014.nxs"
K, R, L = 10, 4, 9


def test_the_real_diamond_k11_file_is_read_as_its_beamline_laid_it_out():
    assert detect_format(K11) == "diamond"
    scan = read_scan(K11)
    # independently: the frames file and the key as h5py reads them, without the NeXus file's links
    with h5py.File(K11.parent / "k11-18014" / "k11-18014-imaging.h5", "r") as f:
        frames = f["entry/detector/detector"][()]
    with h5py.File(K11, "r") as f:
        keys = f["entry/instrument/imaging/image_key"][()]
    with h5py.File(K11.parent / "k11-18014" / "k11-18014-pcompPanda.h5", "r") as f:
        theta = f["entry/gts_theta.value/gts_theta.value"][()]
    assert frames.shape == (3201, 22, 26) and (keys == 0).sum() == 3001
    assert scan.projections.shape == (3001, 22, 26)
    assert scan.flats.shape == (100, 22, 26) and scan.darks.shape == (100, 22, 26)
    np.testing.assert_array_equal(scan.projections, frames[keys == 0])
    np.testing.assert_array_equal(scan.flats, frames[keys == 1])
    np.testing.assert_allclose(scan.angles, np.deg2rad(theta[keys == 0]))
    assert 89.9 < np.rad2deg(scan.angles).min() < 90.1 and 269.9 < np.rad2deg(scan.angles).max() < 270.1
    li = line_integrals(scan)
    assert np.isfinite(li).all() and 0 < np.median(li) < 1  # a sample seen through (interior scan)


def test_the_k11_file_rows_and_columns_are_read_from_disk_only_where_asked():
    part = read_scan(K11, rows=slice(5, 8), crop=(2, 20))
    whole = read_scan(K11)
    np.testing.assert_array_equal(part.projections, whole.projections[:, 5:8, 2:20])
    assert part.source["detector_shape"] == [22, 26]


def _frames():
    rng = np.random.default_rng(3)
    proj = rng.uniform(100, 900, (K, R, L)).astype(np.float32)
    flat, dark = np.full((2, R, L), 1000, np.float32), np.full((1, R, L), 10, np.float32)
    return proj, flat, dark


def test_a_diamond_nxtomo_subentry_is_found_by_its_paths(tmp_path):
    proj, flat, dark = _frames()
    path = tmp_path / "i13.nxs"
    with h5py.File(path, "w") as f:
        f["entry1/tomo_entry/data/data"] = np.concatenate([dark, flat, proj])
        f["entry1/tomo_entry/instrument/detector/image_key"] = np.r_[2, 1, 1, np.zeros(K, int)]
        f["entry1/tomo_entry/data/rotation_angle"] = np.r_[0, 0, 0, np.linspace(0, 180, K, endpoint=False)]
    assert detect_format(path) == "diamond-nxtomo"
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.projections, proj)
    np.testing.assert_allclose(np.rad2deg(scan.angles), np.linspace(0, 180, K, endpoint=False))


def _linked(tmp_path: Path) -> tuple[Path, np.ndarray]:
    """A file of no known layout whose frames sit behind an external link and whose angles are a VDS."""
    proj, flat, dark = _frames()
    frames = np.concatenate([flat, proj, dark])
    (tmp_path / "raw").mkdir()
    with h5py.File(tmp_path / "raw" / "det.h5", "w") as f:
        f["frames"] = frames
        f["rot"] = np.r_[0, 0, np.linspace(0, np.pi, K, endpoint=False), 0]
    path = tmp_path / "scan.h5"
    with h5py.File(path, "w") as f:
        f["scan/frames"] = h5py.ExternalLink("raw/det.h5", "/frames")
        f["scan/keys"] = np.r_[1, 1, np.zeros(K, int), 2]
        layout = h5py.VirtualLayout(shape=(K + 3,), dtype=np.float64)
        layout[:] = h5py.VirtualSource("raw/det.h5", "rot", shape=(K + 3,))
        f.create_virtual_dataset("scan/theta", layout)
        f["scan/theta_alias"] = h5py.SoftLink("/scan/theta")
    return path, proj


def test_a_layout_given_by_paths_follows_external_links_and_virtual_datasets(tmp_path):
    path, proj = _linked(tmp_path)
    with pytest.raises(NanoctError, match="no known layout.*--data-path"):
        read_scan(path)
    options = ReaderOptions(data_path="/scan/frames", image_key_path="/scan/keys", angles_path="/scan/theta_alias")
    with pytest.raises(NanoctError, match="look like radians"):  # no units attribute: degrees
        read_scan(path, options=options)
    scan = read_scan(path, options=ReaderOptions(**{**options.__dict__, "angle_units": "rad"}))
    np.testing.assert_array_equal(scan.projections, proj)
    np.testing.assert_allclose(scan.angles, np.linspace(0, np.pi, K, endpoint=False))
    assert scan.flats.shape == (2, R, L) and scan.darks.shape == (1, R, L)
    assert scan.source["format"] == "hdf5" and scan.source["data"] == "/scan/frames"


def test_a_units_attribute_is_honoured_and_the_user_overrides_it(tmp_path):
    path, proj = _linked(tmp_path)
    with h5py.File(path, "a") as f:
        f["scan/deg"] = np.r_[0, 0, np.linspace(0, 180, K, endpoint=False), 0]
        f["scan/deg"].attrs["units"] = "degree"
    options = ReaderOptions(data_path="/scan/frames", image_key_path="/scan/keys", angles_path="/scan/deg")
    np.testing.assert_allclose(read_scan(path, options=options).angles, np.linspace(0, np.pi, K, endpoint=False))
    stated = ReaderOptions(**{**options.__dict__, "angle_units": "rad"})
    np.testing.assert_allclose(read_scan(path, options=stated).angles, np.linspace(0, 180, K, endpoint=False))


def test_a_known_layout_takes_a_path_the_user_overrides(tmp_path):
    proj, flat, dark = _frames()
    path = tmp_path / "k11like.nxs"
    with h5py.File(path, "w") as f:
        f["entry/imaging/data"] = np.concatenate([flat, proj])
        f["entry/instrument/imaging/image_key"] = np.r_[1, 1, np.zeros(K, int)]
        f["entry/imaging_sum/gts_theta_value"] = np.r_[0, 0, np.linspace(0, 180, K, endpoint=False)]
        f["entry/imaging/gts_theta_value_set"] = np.r_[0, 0, np.linspace(0, 90, K, endpoint=False)]
    with H5Tree(path) as tree:
        assert detect_layout(tree) == "diamond"
    other = read_scan(path, options=ReaderOptions(angles_path="/entry/imaging/gts_theta_value_set"))
    np.testing.assert_allclose(np.rad2deg(other.angles), np.linspace(0, 90, K, endpoint=False))
    np.testing.assert_array_equal(other.projections, proj)


def test_angles_from_an_hdf5_dataset_for_a_npy_scan(tmp_path):
    proj, _, _ = _frames()
    np.save(tmp_path / "p.npy", proj)
    with h5py.File(tmp_path / "angles.h5", "w") as f:
        f["entry/rot"] = np.linspace(0, np.pi, K, endpoint=False)
        f["entry/rot"].attrs["units"] = "rad"
    scan = read_scan(tmp_path / "p.npy", angles_file=f"{tmp_path / 'angles.h5'}:/entry/rot")
    np.testing.assert_allclose(scan.angles, np.linspace(0, np.pi, K, endpoint=False))
    with pytest.raises(NanoctError, match="missing"):
        read_scan(tmp_path / "p.npy", angles_file=f"{tmp_path / 'angles.h5'}:/entry/nothing")


def test_nxtomo_angles_in_the_unit_the_user_states(tmp_path):
    proj, flat, _ = _frames()
    path = tmp_path / "scan.nx"
    with h5py.File(path, "w") as f:
        f["entry/instrument/detector/data"] = np.concatenate([flat, proj])
        f["entry/instrument/detector/image_key"] = np.r_[1, 1, np.zeros(K, int)]
        f["entry/sample/rotation_angle"] = np.r_[0, 0, np.linspace(0, np.pi, K, endpoint=False)]  # radians, no units
    with pytest.raises(NanoctError, match="look like radians"):
        read_scan(path)
    scan = read_scan(path, options=ReaderOptions(angle_units="rad"))
    assert scan.source["format"] == "nxtomo"
    np.testing.assert_allclose(scan.angles, np.linspace(0, np.pi, K, endpoint=False))
