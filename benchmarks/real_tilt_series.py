"""A real limited-angle tilt series aligned by nanoct, against the acquiring group's own alignment.

The data: ETSpy's needle (STEM HAADF, NIST; 77 tilts over -76..+76 degrees, tilt axis along the
image rows, jumps of about 20 pixels between frames), vendored binned 2 x 2 in
``tests/data/realdata/etspy-needle-tilt/`` with ETSpy's alignment of the full-size frames
(``reference.npz``: per-frame shifts ``(y, x)`` applied by ``scipy.ndimage.shift`` before one
rotation of the whole stack by ``tiltaxis_deg`` about the image centre and a shift of ``yshift``
rows; ``make_copy.py`` checks that this reproduces ETSpy's aligned series).

nanoct reads the images transposed (``--tilt-axis rows``): its slices are the image columns, its
vertical (along the axis) is the image x, its horizontal the image y. Both alignments move the raw
frames and then rotate, so the components compare directly, in full-size pixels (twice the
binned ones): horizontal ``2 d_k`` against the reference ``y`` shift, gauge-free (the difference
less its least-squares fit on ``(1, cos, sin)``: a constant goes with the axis, the rest is a
translation of the object); vertical ``2 v_k`` against the reference ``x`` shift, less the mean.
The axis: reconstructing with offset ``c`` and shifts ``d_k`` puts the axis of view ``k`` at row
``127.5 + 2 c - 2 d_k`` of the full-size frame; the reference puts it at ``r - s_k`` with ``r`` the
row that ETSpy's rotation and shift take to row 128 at the middle column; their difference less
its fit on ``(cos, sin)`` is constant, the axis difference. The tilt: nanoct's against
``-tiltaxis_deg`` (ETSpy rotates the frames by ``tiltaxis_deg`` to level the axis; nanoct's sign:
positive where the axis moves right going down its rows), and against an independent estimate
made here: the axis of every full-size image column from its centroids over the views (fitted on
``(1, cos, sin)``, frames moved by the reference shifts, background removed), a straight line
through them (columns 20-199, mass above 5 % of the largest). And the reference itself against a
plain registration chain (each binned frame against the one before it, skimage's
``phase_cross_correlation``), compared the same way.

Paths: the array API (:func:`~nanoct.motion.estimate.estimate_motion` on the projections as read
by ``nanoct.io``) and the command line (``nanoct import ... --line-integrals --tilt-axis rows``,
then ``nanoct stack``). Even/odd FRC of the central slices (image columns 100-155, where the
needle's structure is) before (no motion, the import's axis), after (``nanoct stack``'s motion)
and with ETSpy's alignment (the vendored frames moved as ETSpy moved the full-size ones), and a
picture of slice 64 from each (nanoct's: the slice ``nanoct stack`` wrote).

Usage::

    PYTHONPATH=src python benchmarks/real_tilt_series.py --png-dir docs/img
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from nanoct.core.geometry import Geometry
from nanoct.evaluation.frc import frc, frc_resolution
from nanoct.io.scanio import ReaderOptions, read_scan
from nanoct.motion.estimate import estimate_motion
from nanoct.motion.matching import apply_vertical
from nanoct.recon.stack import corrected_fbp

DATA = Path(__file__).resolve().parents[1] / "tests/data/realdata/etspy-needle-tilt"
MRC = DATA / "needle_bin2.mrc"
ROWS = np.arange(50, 78)  # binned image columns 100-155: the needle's bands


def load() -> tuple[np.ndarray, np.ndarray, dict]:
    """Projections ``(K, R, L)`` as nanoct reads them, angles (radians), the reference."""
    scan = read_scan(MRC, is_line_integral=True, options=ReaderOptions(tilt_axis="rows"))
    ref = dict(np.load(DATA / "reference.npz"))
    return np.asarray(scan.projections, dtype=np.float64), np.asarray(scan.angles), ref


def basis(phi: np.ndarray, constant: bool = True) -> np.ndarray:
    cols = [np.cos(phi), np.sin(phi)]
    return np.stack(([np.ones_like(phi)] if constant else []) + cols, axis=1)


def reference_axis_row(ref: dict) -> float:
    """The full-size row (middle column 127.5) that ETSpy's rotation and shift take to row 128."""
    theta = np.deg2rad(float(ref["tiltaxis_deg"]))
    return 128.0 + (float(ref["yshift"]) - np.sin(theta) * (127.5 - 128.0)) / np.cos(theta)


def compare(d: np.ndarray, v: np.ndarray, center: float, tilt: float, phi: np.ndarray, ref: dict) -> dict:
    """Per component against the reference, full-size pixels (``d``, ``v``, ``center`` binned)."""
    shifts = ref["shifts_yx"]
    diff = 2 * d - shifts[:, 0]
    fit = np.linalg.lstsq(basis(phi), diff, rcond=None)[0]
    horizontal = float(np.sqrt(np.mean((diff - basis(phi) @ fit) ** 2)))
    dv = 2 * v - shifts[:, 1]
    vertical = float(np.sqrt(np.mean((dv - dv.mean()) ** 2)))
    axis_diff = (127.5 + 2 * center - 2 * d) - (reference_axis_row(ref) - shifts[:, 0])
    axis = float(np.linalg.lstsq(basis(phi), axis_diff, rcond=None)[0][0])
    return {"horizontal": horizontal, "vertical": vertical, "axis": axis, "tilt": tilt + float(ref["tiltaxis_deg"])}


def centroid_tilt(ref: dict) -> float:
    """Independent axis tilt: centroid axis of every full-size column, a line through them (degrees)."""
    import mrcfile

    with mrcfile.open(MRC) as mrc:
        binned = np.asarray(mrc.data, dtype=np.float64)
    full = np.repeat(np.repeat(binned, 2, axis=1), 2, axis=2)  # the column line needs no finer sampling
    phi = np.deg2rad(ref["tilts_deg"])
    moved = np.stack([ndimage.shift(f, s, order=1) for f, s in zip(full, ref["shifts_yx"])])
    moved = np.clip(moved - np.median(moved[:, :20]), 0.0, None)
    mass = moved.sum(axis=1)  # (K, columns)
    rows = np.arange(moved.shape[1])
    centroid = (moved * rows[None, :, None]).sum(axis=1) / np.maximum(mass, 1e-12)
    cols = np.arange(20, 200)
    cols = cols[mass.mean(axis=0)[cols] > 0.05 * mass.mean(axis=0).max()]
    axes = np.linalg.lstsq(basis(phi), centroid[:, cols], rcond=None)[0][0]
    return float(np.degrees(np.arctan(np.polyfit(cols, axes, 1)[0])))


def chain_check(proj: np.ndarray, phi: np.ndarray, ref: dict) -> tuple[float, float]:
    """The reference against a plain registration chain (skimage, frame to frame, 20x upsampled), full-size px."""
    from skimage.registration import phase_cross_correlation

    frames = proj.transpose(0, 2, 1)  # image (y, x)
    steps = [phase_cross_correlation(a, b, upsample_factor=20)[0] for a, b in zip(frames[:-1], frames[1:])]
    chain = 2 * np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    dy, dx = chain[:, 0] - ref["shifts_yx"][:, 0], chain[:, 1] - ref["shifts_yx"][:, 1]
    dy = dy - basis(phi) @ np.linalg.lstsq(basis(phi), dy, rcond=None)[0]
    return float(np.sqrt(np.mean(dy**2))), float(np.std(dx))


def fbp_slices(proj: np.ndarray, phi: np.ndarray, center: float, d, views=slice(None)) -> np.ndarray:
    geometry = Geometry.from_angles(phi[views], proj.shape[2], proj.shape[2], center_offset=center)
    shifts = None if d is None else np.asarray(d)[views]
    return np.stack([corrected_fbp(geometry, proj[views, r], shifts) for r in ROWS])


def even_odd(proj: np.ndarray, phi: np.ndarray, center: float, d) -> str:
    even = fbp_slices(proj, phi, center, d, slice(0, None, 2))
    odd = fbp_slices(proj, phi, center, d, slice(1, None, 2))
    freq, curve = frc(even, odd)
    f7, p7 = frc_resolution(freq, curve, "1/7")
    return "above 1/7 to Nyquist" if f7 is None else f"1/7 crossing {f7:.3f} c/px ({p7:.2f} binned px)"


def reference_aligned(proj: np.ndarray, ref: dict) -> np.ndarray:
    """The vendored frames aligned as ETSpy aligned the full-size ones, in nanoct's orientation.

    Shifted by half the reference shifts, rotated by ``tiltaxis_deg`` about the binned image of
    full-size pixel 128 (63.75) and moved by half ``yshift``: ETSpy's axis, full-size row 128,
    is then binned row 63.75, an axis offset of +0.25 (binned) in nanoct's frame.
    """
    from skimage import transform

    theta, centre, half = np.deg2rad(float(ref["tiltaxis_deg"])), 63.75, 0.5 * float(ref["yshift"])
    rotation = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    move = np.array([[1, 0, centre], [0, 1, centre - half], [0, 0, 1]])
    form = transform.AffineTransform(move @ rotation @ np.array([[1, 0, -centre], [0, 1, -centre], [0, 0, 1]]))
    frames = proj.transpose(0, 2, 1)  # back to image (y, x)
    out = [
        transform.warp(ndimage.shift(f, s / 2, order=3), inverse_map=form.inverse, order=1, preserve_range=True)
        for f, s in zip(frames, ref["shifts_yx"])
    ]
    return np.stack(out).transpose(0, 2, 1)


def cli_path(tmp: Path) -> tuple[dict, np.ndarray, float, float, np.ndarray]:
    """``nanoct import`` then ``nanoct stack``: motion record, shifts, the import's axis, seconds, central slice."""
    from nanoct.cli import run
    from nanoct.io.store import DataStore

    store = tmp / "needle"
    start = time.perf_counter()
    args = ["import", str(MRC), "--out", str(store), "--line-integrals", "--tilt-axis", "rows"]
    if run([*args, "--center-offset", "auto", "-q"]) != 0:
        raise SystemExit("nanoct import failed")
    if run(["stack", str(store), "--workers", "0", "-q"]) != 0:
        raise SystemExit("nanoct stack failed")
    seconds = time.perf_counter() - start
    data = DataStore.open(store)
    info = data.recons.motion_info("fbp_stack")
    central = data.read_reconstruction("fbp_stack", [int(ROWS[ROWS.size // 2])])[0]
    return info, data.recons.shared_shifts("fbp_stack"), data.geometry.center_offset, seconds, central


def report(label: str, result: dict, seconds: float) -> None:
    print(f"{label:<34} horizontal {result['horizontal']:.2f} px  vertical {result['vertical']:.2f} px  "
          f"axis {result['axis']:+.2f} px  tilt {result['tilt']:+.2f} deg  ({seconds:.1f} s)")  # fmt: skip


def picture(path: Path, images: list[np.ndarray], titles: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(images), figsize=(3.2 * len(images), 3.4))
    for ax, image, title in zip(axes, images, titles):
        ax.imshow(image, cmap="gray", vmin=np.percentile(image, 1), vmax=np.percentile(image, 99.8))
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--png-dir", type=Path, default=None)
    args = parser.parse_args()
    proj, phi, ref = load()
    print(f"{MRC.name}: {proj.shape[0]} tilts x {proj.shape[1]} x {proj.shape[2]} (binned 2 x 2), "
          f"reference tilt {-float(ref['tiltaxis_deg']):+.2f} deg (nanoct's sign)")  # fmt: skip
    print(f"independent tilt (centroid axis of every column, a line): {centroid_tilt(ref):+.2f} deg")
    chain_y, chain_x = chain_check(proj, phi, ref)
    print(f"reference vs a phase-correlation chain: perpendicular {chain_y:.2f} px, along the axis {chain_x:.2f} px")
    start = time.perf_counter()
    motion = estimate_motion(proj, phi)
    api = compare(motion.horizontal, motion.vertical, motion.axis.offset, motion.tilt_deg, phi, ref)
    report("estimate_motion (array API)", api, time.perf_counter() - start)
    print(f"  {motion.horizontal_method}, axis by {', '.join(motion.axis.used)} {motion.axis.estimates}")
    with tempfile.TemporaryDirectory() as tmp:
        info, shifts, import_axis, seconds, central = cli_path(Path(tmp))
    tilt = info.get("tilt", {}).get("tilt_deg", 0.0)
    stack = compare(shifts, np.asarray(info["vertical"]), info["center_offset"], tilt, phi, ref)
    report("nanoct import + stack", stack, seconds)
    print(f"  {info['horizontal_method']}, axis {info['center_offset']:+.2f} by {info['center_method']}; "
          f"import's axis (no motion) {import_axis:+.2f}")  # fmt: skip
    straight = apply_vertical(proj, np.asarray(info["vertical"]))
    print(f"FRC even/odd, before (no motion, import's axis): {even_odd(proj, phi, import_axis, None)}")
    print(f"FRC even/odd, after (nanoct stack's motion):   {even_odd(straight, phi, info['center_offset'], shifts)}")
    aligned = reference_aligned(proj, ref)
    print(f"FRC even/odd, ETSpy's alignment (axis +0.25):  {even_odd(aligned, phi, 0.25, None)}")
    if args.png_dir is not None:
        row = ROWS.size // 2
        before = fbp_slices(proj, phi, import_axis, None)[row]
        etspy = fbp_slices(aligned, phi, 0.25, None)[row]
        path = args.png_dir / "real_tilt_needle.png"
        titles = ["no motion (import's axis)", "nanoct stack", "ETSpy's alignment"]
        picture(path, [before, central, etspy], [f"{t}, slice {ROWS[row]}" for t in titles])
        print(f"picture: {path}")


if __name__ == "__main__":
    main()
