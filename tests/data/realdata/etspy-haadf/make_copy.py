"""Rebuild this folder from the ETSpy 1.3.0 wheel (NIST): the FEI HAADF tilt series, cropped, its header kept.

Usage (the wheel from ``pip download etspy==1.3.0 --no-deps``; numpy and mrcfile from nanoct's
environment)::

    python tests/data/realdata/etspy-haadf/make_copy.py etspy-1.3.0-py3-none-any.whl

Reads ``etspy/tests/test_data/HAADF.mrc`` (77 tilts x 256 x 256, MRC mode 1, int16
little-endian, written by FEI software: no map ID, no machine stamp, a 131072-byte FEI extended
header) and ``HAADF.rawtlt`` from the wheel, and writes next to this script:

* ``HAADF_crop.mrc``: the original 1024-byte header and extended header byte for byte, except
  the six fields that give the image size (``nx``, ``ny``, ``mx``, ``my``, ``cella.x``,
  ``cella.y``: 256 -> 96 columns and 256 -> 64 rows, the voxel size staying 1 angstrom as in the
  original), followed by image rows 96-159 and columns 64-159 of every frame, values unchanged;
* ``HAADF_crop.rawtlt``: the tilt angles as in the wheel (degrees).

It checks that mrcfile still rejects the copy as the original (map ID, machine stamp), that the
permissive read gives exactly the cropped frames, and that only those six header fields differ.
"""

from __future__ import annotations

import hashlib
import struct
import sys
import tempfile
import warnings
import zipfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
WHEEL_SHA256 = "23b07379a1e973a4f69445b0a634687d4af4bb6a806d24bdce49be57afbd36f8"
ROWS, COLS = slice(96, 160), slice(64, 160)  # of the 256 x 256 frames: the needle's tip region
HEADER = 1024


def crop(original: bytes) -> bytes:
    """The cropped file: the original headers with the new image size, then the cropped frames."""
    nx, ny, nz, mode = struct.unpack_from("<4i", original, 0)
    extended = struct.unpack_from("<i", original, 92)[0]
    if (nx, ny, nz, mode, extended) != (256, 256, 77, 1, 131072):
        raise SystemExit(f"unexpected HAADF.mrc header: {nx} x {ny} x {nz}, mode {mode}, extended {extended}")
    start = HEADER + extended
    frames = np.frombuffer(original[start:], dtype="<i2").reshape(nz, ny, nx)
    cut = np.ascontiguousarray(frames[:, ROWS, COLS])
    header = bytearray(original[:start])
    n_rows, n_cols = cut.shape[1:]
    struct.pack_into("<2i", header, 0, n_cols, n_rows)  # nx, ny
    struct.pack_into("<2i", header, 28, n_cols, n_rows)  # mx, my
    struct.pack_into("<2f", header, 40, float(n_cols), float(n_rows))  # cella x, y (angstrom): 1 A voxels as before
    return bytes(header) + cut.tobytes()


def check(original: bytes, copy: bytes) -> None:
    """mrcfile rejects the copy as it rejects the original; permissively it reads the cropped frames."""
    import mrcfile

    changed = {i // 4 for i in range(HEADER) if original[i] != copy[i]}
    if not changed <= {0, 1, 7, 8, 10, 11} or original[HEADER : HEADER + 131072] != copy[HEADER : HEADER + 131072]:
        raise SystemExit(f"header words {sorted(changed)} changed; only nx, ny, mx, my, cella x, y may")
    with tempfile.TemporaryDirectory() as tmp:
        a, b = Path(tmp) / "a.mrc", Path(tmp) / "b.mrc"
        a.write_bytes(original)
        b.write_bytes(copy)
        for path in (a, b):
            try:
                mrcfile.open(path).close()
            except ValueError:
                pass
            else:
                raise SystemExit(f"mrcfile reads {path.name} as standard MRC")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the map ID and machine stamp warnings, expected here
            with mrcfile.open(a, permissive=True) as full, mrcfile.open(b, permissive=True) as cut:
                if not np.array_equal(full.data[:, ROWS, COLS], cut.data):
                    raise SystemExit("the permissive read of the copy is not the cropped frames")


def main(wheel: str) -> None:
    digest = hashlib.sha256(Path(wheel).read_bytes()).hexdigest()
    if digest != WHEEL_SHA256:
        raise SystemExit(f"{wheel}: sha256 {digest}, not the ETSpy 1.3.0 wheel's {WHEEL_SHA256}")
    with zipfile.ZipFile(wheel) as archive:
        original = archive.read("etspy/tests/test_data/HAADF.mrc")
        angles = archive.read("etspy/tests/test_data/HAADF.rawtlt")
    copy = crop(original)
    check(original, copy)
    (HERE / "HAADF_crop.mrc").write_bytes(copy)
    (HERE / "HAADF_crop.rawtlt").write_bytes(angles)
    print(f"wrote {HERE / 'HAADF_crop.mrc'}: {len(copy)} bytes (the original {len(original)})")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: make_copy.py etspy-1.3.0-py3-none-any.whl")
    main(sys.argv[1])
