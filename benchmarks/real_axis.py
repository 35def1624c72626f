"""nanoct's automatic axis on every real scan at hand: each estimator's value, the one chosen, the time.

Runs :func:`nanoct.motion.axis.estimate_axis` on the rows ``nanoct import --center-offset auto``
uses (:func:`~nanoct.motion.axis.axis_rows`) of each real scan in ``tests/data/realdata`` and
``../shared/realdata`` (those present): Diamond I13-2 24737, Diamond K11 18014 (interior crop),
the 360-degree neutron sinogram, APS's tooth (Data Exchange), PSI's basalt beads (static), Diamond
I12's dendrite at full width and cut to its central 600 columns (wider than the field of view).
Prints one line per scan and, with ``--json FILE``, writes the records, so that two versions of
the code can be compared: run it with ``PYTHONPATH`` at each version's ``src``::

    PYTHONPATH=src python benchmarks/real_axis.py --json /tmp/axis_new.json
    PYTHONPATH=/tmp/old/src python benchmarks/real_axis.py --json /tmp/axis_old.json
    python benchmarks/real_axis.py --compare /tmp/axis_old.json /tmp/axis_new.json
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PLACES = (ROOT / "tests" / "data" / "realdata", ROOT.parent / "shared" / "realdata")


def _find(name: str) -> Path | None:
    return next((p / name for p in PLACES if (p / name).exists()), None)


def _raw_rows(path: Path, **options: object) -> tuple[np.ndarray, np.ndarray]:
    """``(S, K, L)`` line integrals of a scan file read as ``nanoct import`` reads it, and its angles."""
    from nanoct.io.scanio import line_integrals, read_scan, sinograms

    scan = read_scan(path, **options)
    return sinograms(line_integrals(scan)), np.asarray(scan.angles)


def _mat(path: Path, sino: str, angles: str, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A MATLAB sinogram stored (columns, views): ``(1, K, L)`` and unwrapped angles."""
    from scipy.io import loadmat

    data = loadmat(path)
    values = np.asarray(data[sino], dtype=np.float64).T / scale
    return values[None], np.unwrap(np.asarray(data[angles], dtype=np.float64).ravel())


def scans() -> dict[str, Callable[[], tuple[np.ndarray, np.ndarray]]]:
    """The loaders of the real scans present, by name: each gives ``(S, K, L)`` line integrals and angles."""
    from nanoct.io.scanio import ReaderOptions

    found: dict[str, Callable[[], tuple[np.ndarray, np.ndarray]]] = {}
    if (p := _find("i13-24737-tiff")) is not None:
        found["I13 24737"] = lambda p=p: _raw_rows(
            p / "tiffs",
            flats=p / "flat_00001.tiff",
            darks=p / "dark_00001.tiff",
            angles_file=str(p / "angles.txt"),
            options=ReaderOptions(angles_select=(10, 101)),
        )
    if (p := _find("k11-18014-nexus")) is not None:
        found["K11 18014 (interior)"] = lambda p=p: _raw_rows(p / "k11-18014.nxs")
    if (p := _find("neutron-360-sinogram")) is not None:
        found["neutron 360"] = lambda p=p: _neutron(p / "sinogram_360_neutron_image.tif")
    if (p := _find("aps-tooth-dxchange")) is not None:
        found["APS tooth"] = lambda p=p: _tooth(p / "tooth.h5")
    if (p := _find("psi-basalt-sinogram")) is not None:
        found["PSI basalt (static)"] = lambda p=p: _mat(p / "sino_basalt.mat", "sino_basalt", "angles")
    if (p := _find("i12-dendrite-sinogram")) is not None:
        found["I12 dendrite"] = lambda p=p: _mat(p / "RealDataDend.mat", "sinoRD", "anglesRad", 1000.0)
        found["I12 dendrite 330:930"] = lambda p=p: tuple(
            (s[..., 330:930], a) for s, a in [_mat(p / "RealDataDend.mat", "sinoRD", "anglesRad", 1000.0)]
        )[0]
    return found


def _neutron(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The 360-degree neutron sinogram normalised by its open-beam columns (2:28), 459 views over 360 degrees."""
    import tifffile

    raw = tifffile.imread(path).astype(np.float64)
    beam = np.median(raw[:, 2:28], axis=1)
    sino = -np.log(np.clip(raw / beam[:, None], 1e-6, None))
    return sino[None], np.arange(sino.shape[0]) * 2 * np.pi / sino.shape[0]


def _tooth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """APS's tooth with its views over 0..180 degrees inclusive (the file's own theta is one step short)."""
    rows, _ = _raw_rows(path)
    return rows, np.deg2rad(np.linspace(0.0, 180.0, rows.shape[1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", type=Path, default=None, help="Write the records here.")
    parser.add_argument("--compare", nargs=2, type=Path, default=None, metavar=("OLD", "NEW"))
    args = parser.parse_args()
    if args.compare is not None:
        old, new = (json.loads(p.read_text()) for p in args.compare)
        for name in new:
            was = old.get(name, {})
            a, b = was.get("offset", float("nan")), new[name]["offset"]
            print(f"{name}: {a:+.3f} -> {b:+.3f} px ({b - a:+.3f}); time {was.get('seconds', 0):.1f} "
                  f"-> {new[name]['seconds']:.1f} s; used {was.get('used')} -> {new[name]['used']}")  # fmt: skip
        return
    from nanoct.motion.axis import axis_rows, estimate_axis

    records = {}
    for name, load in scans().items():
        sinos, phi = load()
        sinos = sinos[axis_rows(sinos.shape[0])]
        start = time.perf_counter()
        estimate = estimate_axis(sinos, phi)
        seconds = time.perf_counter() - start
        records[name] = {**estimate.to_dict(), "seconds": seconds, "shape": list(sinos.shape)}
        values = ", ".join(f"{k} {v:+.2f}" for k, v in estimate.estimates.items())
        print(f"{name} {sinos.shape}: {values}; chosen {estimate.offset:+.3f} ({'+'.join(estimate.used)}), "
              f"{seconds:.1f} s", flush=True)  # fmt: skip
    if args.json is not None:
        args.json.write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
