"""The corrections on the real scans of tests/data/realdata: ring metric and air level, before and after.

Neutron 360-degree sinogram (459 views x 503 columns, raw counts): each view is divided by its
open beam (the median of columns 0-29) and ``-log`` is taken (the "before" sinogram; its 214 zero
counts, a dead pixel, become ``-log(1e-6)``, as in nanoct's import); the rotation axis is found by
algotom's ``find_center_vo`` on the first 180 degrees of the outlier-cleaned sinogram and checked
against mirrored opposite views; each stripe removal then runs on the same sinogram and the
slice is reconstructed with nanoct's FBP (all 459 views over 360 degrees). The ring metric
(:func:`nanoct.preprocess.ring_metric`) of each slice is printed with its reduction
factor; nanoct's default (``Corrections(stripes="all")``) is compared with algotom's
``remove_all_stripe`` called directly.

Diamond I13-2 scan 24737 (91 views of 135 x 160, flat/dark-corrected transmission): the air
absorbance ``-log(t)`` is averaged over two strips that see only air in every view (rows 5-129,
columns 2-27 and 137-157), before and after the open-beam normalisation of each degree, with the
air found automatically and from given columns.

Saves ``corrections_neutron.png`` and ``corrections_i13.png`` into ``--png-dir``. Usage::

    PYTHONPATH=src python benchmarks/real_corrections.py --png-dir docs/img
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

from nanoct.core.geometry import Geometry
from nanoct.preprocess import Corrections, apply_corrections, remove_stripes, ring_metric
from nanoct.recon.fbp import fbp

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "realdata"
AIR_STRIPS = ((slice(5, 130), slice(2, 28)), (slice(5, 130), slice(137, 158)))


def neutron_sinogram(*, fill_dead: bool = False) -> np.ndarray:
    """The raw neutron sinogram as (459, 1, 503) float32 counts.

    ``fill_dead``: the 214 zero counts (detector columns 314 and 346, views 31 to 202) replaced by
    the mean of the two neighbouring columns, so that a slice shows the rings of the other pixels
    rather than those of the zeros.
    """
    raw = tifffile.imread(DATA / "neutron-360-sinogram" / "sinogram_360_neutron_image.tif").astype(np.float32)
    if fill_dead:
        views, cols = np.nonzero(raw == 0)
        left, right = np.maximum(cols - 1, 0), np.minimum(cols + 1, raw.shape[1] - 1)
        raw[views, cols] = 0.5 * (raw[views, left] + raw[views, right])
    return raw[:, None, :]


def mirror_center(sino: np.ndarray) -> float:
    """The axis column from each view against the mirrored view 180 degrees later (interpolated)."""
    k, n_cols = sino.shape
    half = k / 2  # 229.5 views: the opposite view lies between two measured ones
    lo = int(np.floor(half))
    first = sino[: k - lo - 1]
    opposite = (1 - (half - lo)) * sino[lo : k - 1] + (half - lo) * sino[lo + 1 : k]
    flipped = opposite[:, ::-1]
    margin = n_cols // 10
    centers = np.arange(n_cols / 2 - n_cols / 8, n_cols / 2 + n_cols / 8, 0.25)
    errors = [
        np.mean(
            (first - ndimage.shift(flipped, (0, 2 * c - (n_cols - 1)), order=1, mode="nearest"))[:, margin:-margin] ** 2
        )
        for c in centers
    ]
    return float(centers[int(np.argmin(errors))])


def reconstruct(sino: np.ndarray, angles: np.ndarray, axis_column: float) -> np.ndarray:
    """nanoct's FBP of one (K, L) sinogram on an L x L grid centred on the axis."""
    n_cols = sino.shape[1]
    geometry = Geometry.from_angles(angles, n_cols, n_cols, center_offset=axis_column - (n_cols - 1) / 2)
    return fbp(geometry, sino).image


def neutron_rings(png: Path | None) -> dict[str, float]:
    """Ring metric of the neutron slice for no stripe removal, nanoct's default and algotom's methods."""
    from algotom.prep.calculation import find_center_vo
    from algotom.prep.removal import remove_all_stripe

    base = Corrections(open_beam=True, air_columns=((0, 30),))
    before = apply_corrections(neutron_sinogram(), base).line_integrals[:, 0]
    cleaned = apply_corrections(neutron_sinogram(), replace(base, outliers=5.0)).line_integrals[:, 0]
    k = before.shape[0]
    angles = np.arange(k) * 2 * np.pi / k
    vo = float(find_center_vo(cleaned[: k // 2 + 1]))
    mirror = mirror_center(cleaned)
    print(f"neutron axis column: algotom find_center_vo {vo:.2f}, mirrored opposite views {mirror:.2f} (used: vo)")
    default = apply_corrections(neutron_sinogram(), replace(base, stripes="all"))
    sinos = {
        "none": before,
        "nanoct default (all)": default.line_integrals[:, 0],
        "algotom remove_all_stripe": remove_all_stripe(before, 3.0, 51, 21),
    }
    for method in ("sorting", "filtering", "fitting"):
        sinos[f"nanoct {method}"] = remove_stripes(before, method)
    filled = apply_corrections(neutron_sinogram(fill_dead=True), base).line_integrals[:, 0]
    sinos["filled"] = filled
    sinos["filled + nanoct default (all)"] = apply_corrections(
        neutron_sinogram(fill_dead=True), replace(base, stripes="all")
    ).line_integrals[:, 0]
    sinos["filled + algotom remove_all_stripe"] = remove_all_stripe(filled, 3.0, 51, 21)
    sinos["outliers 5 (no stripes)"] = cleaned
    sinos["outliers 5 + default"] = remove_stripes(cleaned, "all")
    slices = {name: reconstruct(sino, angles, vo) for name, sino in sinos.items()}
    metrics = {name: ring_metric(image) for name, image in slices.items()}
    offsets = ((8, 0), (0, 8), (-8, 0), (0, -8))
    print(f"{'sinogram':34s} {'ring metric':>11s} {'vs none':>9s} {'vs filled':>9s} {'off-axis floor':>14s}")
    for name, image in slices.items():
        value, floor = metrics[name], np.mean([ring_metric(image, offset=o) for o in offsets])
        gains = f"{metrics['none'] / value:8.1f}x {metrics['filled'] / value:8.1f}x"
        print(f"{name:34s} {value:11.4g} {gains} {floor:14.4g}")
    for case in ("", "filled + "):
        ratio = metrics[f"{case}nanoct default (all)"] / metrics[f"{case}algotom remove_all_stripe"]
        print(f"{case}nanoct default / {case}algotom remove_all_stripe: {ratio:.3f}")
    if png is not None:
        names = ["none", "filled", "filled + nanoct default (all)", "filled + algotom remove_all_stripe"]
        titles = ["open beam, -log", "dead pixel filled", "+ nanoct stripes=all", "+ algotom remove_all_stripe"]
        _figure(png, [slices[n] for n in names], titles, [metrics[n] for n in names])
    return metrics


def _figure(png: Path, images: list[np.ndarray], titles: list[str], values: list[float]) -> None:
    """The central 320 x 320 pixels of each slice, one grey scale (the second slice's 1-99 %)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = images[0].shape[0]
    crop = slice(n // 2 - 160, n // 2 + 160)
    lo, hi = np.percentile(images[1], [1, 99])
    fig, axes = plt.subplots(1, len(images), figsize=(3.4 * len(images), 4.0))
    for ax, image, title, value in zip(axes, images, titles, values):
        ax.imshow(image[crop, crop], cmap="gray", vmin=lo, vmax=hi)
        ax.set_title(f"{title}\nring metric {value:.3g}", fontsize=9)
        ax.axis("off")
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(png, dpi=60)
    plt.close(fig)


def i13_transmission() -> tuple[np.ndarray, np.ndarray]:
    """Flat/dark-corrected transmissions (91, 135, 160) and the projection angles in degrees."""
    folder = DATA / "i13-24737-tiff"
    flat = tifffile.imread(folder / "flat_00001.tiff").astype(np.float64)
    dark = tifffile.imread(folder / "dark_00001.tiff").astype(np.float64)
    raw = np.stack([tifffile.imread(p) for p in sorted((folder / "tiffs").glob("raw_*.tiff"))]).astype(np.float64)
    gain = flat - dark
    good = gain > 0  # one dead pixel: transmission 1 there, as nanoct's import does
    trans = np.where(good, (raw - dark) / np.where(good, gain, 1.0), 1.0).astype(np.float32)
    angles = np.loadtxt(folder / "angles.txt")[10:101]
    return trans, angles


def air_level(lines: np.ndarray) -> tuple[float, float]:
    """Mean absorbance over the air strips, and the largest |mean| of one view over them."""
    per_view = np.mean([lines[:, rows, cols].mean(axis=(1, 2)) for rows, cols in AIR_STRIPS], axis=0)
    return float(per_view.mean()), float(np.abs(per_view).max())


def i13_air(png: Path | None) -> dict[str, tuple[float, float]]:
    """Air absorbance on I13 24737 before and after each open-beam normalisation."""
    trans, angles = i13_transmission()
    runs = {"before (flat/dark only)": Corrections(), "open beam, automatic air (default)": Corrections(open_beam=True)}
    for degree in (0, 1, 2):
        runs[f"open beam, automatic air, degree {degree}"] = Corrections(open_beam=True, open_beam_degree=degree)
    runs["open beam, columns 0:30,130:160"] = Corrections(open_beam=True, air_columns=((0, 30), (130, 160)))
    results, lines = {}, {}
    print(f"{'I13 24737':44s} {'air mean':>9s} {'worst view':>10s} {'seconds':>8s}")
    for name, corr in runs.items():
        start = time.perf_counter()
        lines[name] = apply_corrections(trans, corr).line_integrals
        results[name] = air_level(lines[name])
        print(f"{name:44s} {results[name][0]:9.4f} {results[name][1]:10.4f} {time.perf_counter() - start:8.2f}")
    if png is not None:
        after = "open beam, automatic air (default)"
        row = 67
        images = [lines[name][:, row] for name in (next(iter(runs)), after)]
        slices = [reconstruct(image, np.deg2rad(angles), 85.5) for image in images]
        _i13_figure(png, images, slices, row)
    return results


def _i13_figure(png: Path, sinos: list[np.ndarray], slices: list[np.ndarray], row: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(15, 4))
    for i, (sino, image, label) in enumerate(zip(sinos, slices, ("before", "after open beam"))):
        shown = axes[i].imshow(sino, cmap="gray", vmin=-0.05, vmax=1.6, aspect="auto")
        axes[i].set_title(f"sinogram row {row}, {label}\nair absorbance {np.median(sino[:, :25]):.3f}", fontsize=9)
        fig.colorbar(shown, ax=axes[i], fraction=0.04)
        shown = axes[2 + i].imshow(image, cmap="gray", vmin=-0.01, vmax=0.04)
        axes[2 + i].set_title(f"FBP slice {row}, {label}", fontsize=9)
        axes[2 + i].axis("off")
        fig.colorbar(shown, ax=axes[2 + i], fraction=0.04)
    fig.tight_layout()
    fig.savefig(png, dpi=60)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--png-dir", type=Path, default=None, help="save the before/after images here")
    args = parser.parse_args()
    if args.png_dir is not None:
        args.png_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    neutron_rings(None if args.png_dir is None else args.png_dir / "corrections_neutron.png")
    i13_air(None if args.png_dir is None else args.png_dir / "corrections_i13.png")
    print(f"total {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
