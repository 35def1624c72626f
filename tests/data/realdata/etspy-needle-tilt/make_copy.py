"""Rebuild this folder from the ETSpy 1.3.0 wheel (NIST): the needle tilt series binned 2 x 2.

Usage (the wheel from ``pip download etspy==1.3.0 --no-deps``; h5py, mrcfile, scipy and
scikit-image from nanoct's environment)::

    python tests/data/realdata/etspy-needle-tilt/make_copy.py etspy-1.3.0-py3-none-any.whl

Reads ``etspy/tests/test_data/HAADF.mrc`` (77 tilts x 256 x 256, int16 stored with an offset),
``HAADF.rawtlt`` and ``HAADF_Aligned.hspy`` (the acquiring group's aligned series) from the
wheel, and writes next to this script:

* ``needle_bin2.mrc``: the raw frames less their stack minimum (as ETSpy's aligned series has
  them), averaged over 2 x 2 pixels, rounded to uint16 (MRC mode 6); voxel size 67.2 angstrom;
* ``needle_bin2.rawtlt``: the tilt angles as in the wheel (degrees);
* ``reference.npz``: ETSpy's alignment of the full-size frames, unchanged (full-size pixels).

Before writing, it checks the convention of the reference: applying the stored shifts to the
raw frames (``scipy.ndimage.shift``, cubic) and then ETSpy's rotation and shift of the whole
stack (``skimage.transform.warp``, as ETSpy's ``trans_stack``) must give the aligned series.
"""

from __future__ import annotations

import sys
import tempfile
import warnings
import zipfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
MEMBERS = ("HAADF.mrc", "HAADF.rawtlt", "HAADF_Aligned.hspy")
GROUP = "Experiments/__unnamed__"


def etspy_transform(image: np.ndarray, yshift: float, angle_deg: float) -> np.ndarray:
    """ETSpy's ``trans_stack`` on one image: a rotation by ``angle_deg`` about ``shape / 2``, then ``y - yshift``."""
    from skimage import transform

    theta = np.deg2rad(angle_deg)
    cy, cx = np.asarray(image.shape, dtype=np.float64) / 2
    rotation = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    to_centre = np.array([[1, 0, cx], [0, 1, cy], [0, 0, 1]])
    from_centre = np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1]])
    shift = np.array([[1, 0, 0], [0, 1, -yshift], [0, 0, 1]])
    form = transform.AffineTransform(shift @ to_centre @ rotation @ from_centre)
    return transform.warp(image, inverse_map=form.inverse, order=1, preserve_range=True)


def check_reference(raw: np.ndarray, aligned: np.ndarray, shifts: np.ndarray, yshift: float, angle: float) -> float:
    """Relative RMS difference between ETSpy's aligned frames and the raw frames moved by the reference."""
    from scipy import ndimage

    worst = 0.0
    for k in range(0, raw.shape[0], 8):
        moved = etspy_transform(ndimage.shift(raw[k], shifts[k], order=3), yshift, angle)
        inner = (slice(20, -20), slice(20, -20))
        worst = max(worst, float(np.sqrt(np.mean((moved - aligned[k])[inner] ** 2)) / np.std(aligned[k][inner])))
    return worst


def main(wheel: str) -> None:
    import h5py
    import mrcfile

    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(wheel) as archive:
        for name in MEMBERS:
            archive.extract(f"etspy/tests/test_data/{name}", tmp)
        data = Path(tmp) / "etspy/tests/test_data"
        with warnings.catch_warnings(), mrcfile.open(data / "HAADF.mrc", permissive=True) as mrc:
            warnings.simplefilter("ignore")  # the header lacks the map ID and machine stamp
            raw = np.asarray(mrc.data, dtype=np.float64)
        raw -= raw.min()
        with h5py.File(data / "HAADF_Aligned.hspy", "r") as f:
            aligned = f[f"{GROUP}/data"][()].astype(np.float64)
            shifts = f[f"{GROUP}/metadata/Tomography/_sig_shifts/data"][()]
            tilts = f[f"{GROUP}/metadata/Tomography/_sig_tilts/data"][()][:, 0]
            attrs = dict(f[f"{GROUP}/metadata/Tomography"].attrs)
        angles_text = (data / "HAADF.rawtlt").read_text()
    angle, yshift = float(attrs["tiltaxis"]), float(attrs["yshift"])
    misfit = check_reference(raw, aligned, shifts, yshift, angle)
    print(f"reference applied to the raw frames vs ETSpy's aligned series: relative RMS {misfit:.1e}")
    if misfit > 1e-2:
        raise SystemExit("the reference's convention does not reproduce the aligned series")
    k, n, m = raw.shape
    binned = raw.reshape(k, n // 2, 2, m // 2, 2).mean(axis=(2, 4))
    with mrcfile.new(HERE / "needle_bin2.mrc", overwrite=True) as mrc:
        mrc.set_data(np.round(binned).astype(np.uint16))
        mrc.voxel_size = 2 * 33.6  # angstrom: 3.36 nm per full-size pixel (HAADF.txt)
    (HERE / "needle_bin2.rawtlt").write_text(angles_text)
    np.savez(
        HERE / "reference.npz",
        shifts_yx=shifts,
        tilts_deg=tilts,
        tiltaxis_deg=angle,
        yshift=yshift,
        binning=2,
        full_size=np.array([n, m]),
    )
    print(f"wrote {HERE}: {k} tilts x {n // 2} x {m // 2}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: make_copy.py etspy-1.3.0-py3-none-any.whl")
    main(sys.argv[1])
