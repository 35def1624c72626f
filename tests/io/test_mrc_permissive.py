"""Non-standard MRC headers read permissively, with one warning naming what is non-standard.

The real case: ETSpy's FEI/STEM HAADF tilt series (``tests/data/realdata/etspy-haadf/``, its
original header kept byte for byte but its frames cropped) has no map ID and no machine stamp,
so mrcfile's standard read refuses it. A truncated copy stays refused with one error line.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import mrcfile
import numpy as np
import pytest

from nanoct.cli import run
from nanoct.core.errors import NanoctError
from nanoct.io.mrcio import MrcHeaderWarning, find_tilt_file
from nanoct.io.scanio import ReaderOptions, read_scan
from nanoct.io.store import DataStore

HAADF = Path(__file__).resolve().parents[1] / "data" / "realdata" / "etspy-haadf" / "HAADF_crop.mrc"
FEI_DATA = 1024 + 131072  # the data follow the 1024-byte header and FEI's 131072-byte extended header
K, NY, NX = 77, 64, 96  # tilts, image rows, image columns of the cropped copy
MAP_ID = "map ID b'\\x00\\x00\\x00\\x00' instead of b'MAP '"
STAMP = "machine stamp 0x00 0x00 0x00 0x00 instead of 0x44 0x44 (little-endian) or 0x11 0x11 (big-endian)"
ROWS = ReaderOptions(tilt_axis="rows")  # the series' tilt axis runs along its image rows


def _read(path: Path, **kwargs):
    """``read_scan`` and every warning it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scan = read_scan(path, **kwargs)
    return scan, caught


def _standard(path: Path) -> np.ndarray:
    """A standard MRC2014 stack of 4 images (3 rows x 5 columns) with its angle file."""
    stack = np.arange(4 * 3 * 5, dtype=np.float32).reshape(4, 3, 5)
    with mrcfile.new(path, overwrite=True) as mrc:
        mrc.set_data(stack)
    np.savetxt(path.with_suffix(".rawtlt"), [-30.0, -10.0, 10.0, 30.0])
    return stack


def test_the_fei_series_reads_with_one_warning_naming_its_header():
    raw = np.frombuffer(HAADF.read_bytes()[FEI_DATA:], dtype="<i2").reshape(K, NY, NX)
    with pytest.raises(ValueError, match="Map ID"):  # what made nanoct refuse it: mrcfile's standard read
        mrcfile.open(HAADF).close()
    scan, caught = _read(HAADF, options=ROWS)
    assert len(caught) == 1 and caught[0].category is MrcHeaderWarning
    message = str(caught[0].message)
    assert MAP_ID in message and STAMP in message and str(HAADF) in message
    assert scan.source["mrc_nonstandard"] == [MAP_ID, f"{STAMP}, taken as little-endian"]
    np.testing.assert_array_equal(scan.projections, raw.transpose(0, 2, 1))  # the int16 values, little-endian
    # the angles are the .rawtlt's, one per frame (-76 to +76 degrees)
    assert find_tilt_file(HAADF) == HAADF.with_suffix(".rawtlt") and scan.source["angles_from"].endswith(".rawtlt")
    tilts = np.loadtxt(HAADF.with_suffix(".rawtlt"))
    assert tilts.size == K and tilts[0] == -76 and tilts[-1] == 76
    np.testing.assert_allclose(np.rad2deg(scan.angles), tilts, atol=1e-9)


def test_the_fei_series_imports_on_the_command_line(tmp_path, capsys):
    out = tmp_path / "haadf"
    args = ["import", str(HAADF), "--out", str(out), "--line-integrals", "--tilt-axis", "rows"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert run(args) == 0
    assert [w.category for w in caught] == [MrcHeaderWarning] and MAP_ID in str(caught[0].message)
    assert f"{NX} slice(s), {K} views x {NY} detector pixels" in capsys.readouterr().out
    data = DataStore.open(out)
    np.testing.assert_allclose(np.rad2deg(data.geometry.angles), np.loadtxt(HAADF.with_suffix(".rawtlt")), atol=1e-9)
    assert data.meta["scan"]["angles_from"] == str(HAADF.with_suffix(".rawtlt"))
    assert data.meta["scan"]["mrc_nonstandard"][0] == MAP_ID  # kept with the data set


@pytest.mark.parametrize("keep", [600, 100_000, FEI_DATA + 5000, HAADF.stat().st_size - 1])
def test_a_truncated_fei_copy_is_refused_with_one_line(tmp_path, capsys, keep):
    """Cut in the header, in the extended header, in the first frame, one byte short."""
    cut = tmp_path / "cut.mrc"
    cut.write_bytes(HAADF.read_bytes()[:keep])
    cut.with_suffix(".rawtlt").write_bytes(HAADF.with_suffix(".rawtlt").read_bytes())
    with pytest.raises(NanoctError, match="cannot read .* as MRC") as refused:
        read_scan(cut, options=ROWS)
    if keep > 1024:  # the header read: it says how much data it promised
        expected = f"the header asks for {HAADF.stat().st_size} bytes"
        assert expected in str(refused.value) and f"the file has {keep}" in str(refused.value)
        assert MAP_ID in str(refused.value)
    out = tmp_path / "o"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert run(["import", str(cut), "--out", str(out), "--line-integrals", "--tilt-axis", "rows"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot read") and len(err.strip().splitlines()) == 1
    assert not caught and not out.exists()  # refused: no warning of a permissive read, nothing written


def test_a_standard_mrc_gives_no_warning(tmp_path):
    path = tmp_path / "tomo.mrc"
    stack = _standard(path)
    scan, caught = _read(path)
    assert not caught and "mrc_nonstandard" not in scan.source
    np.testing.assert_array_equal(scan.projections, stack)


def test_bytes_after_the_data_are_named_once(tmp_path):
    path = tmp_path / "tomo.mrc"
    stack = _standard(path)
    path.write_bytes(path.read_bytes() + bytes(100))
    scan, caught = _read(path)
    assert [w.category for w in caught] == [MrcHeaderWarning]  # not mrcfile's own RuntimeWarning besides
    assert "100 bytes after the data that the header (1024 header + 0 extended header + 4 x 3 x 5 values of mode 2" in (
        str(caught[0].message)
    )
    np.testing.assert_array_equal(scan.projections, stack)


def test_a_machine_stamp_of_the_wrong_byte_order_is_named(tmp_path):
    path = tmp_path / "tomo.mrc"
    stack = _standard(path)
    raw = bytearray(path.read_bytes())
    raw[212:216] = b"\x11\x11\x00\x00"  # says big-endian; the file is little-endian
    path.write_bytes(bytes(raw))
    scan, caught = _read(path)
    assert [w.category for w in caught] == [MrcHeaderWarning]
    assert "machine stamp 0x11 0x11 0x00 0x00 names the other byte order than its mode, taken as little-endian" in (
        str(caught[0].message)
    )
    np.testing.assert_array_equal(scan.projections, stack)


def test_an_unknown_mode_is_refused_naming_it(tmp_path, capsys):
    path = tmp_path / "tomo.mrc"
    _standard(path)
    raw = bytearray(path.read_bytes())
    raw[12:16] = np.int32(999).tobytes()  # no MRC mode, in either byte order
    path.write_bytes(bytes(raw))
    with pytest.raises(NanoctError, match="cannot read .* as MRC: mode 999 is not an MRC mode"):
        read_scan(path)
    assert run(["import", str(path), "--out", str(tmp_path / "o"), "--line-integrals"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and len(err.strip().splitlines()) == 1 and not (tmp_path / "o").exists()
