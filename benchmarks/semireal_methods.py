"""The paper's methods on a real scan with a known added motion (semi-real benchmark).

Usage::

    PYTHONPATH=src python benchmarks/semireal_methods.py [--slices 20,30,...,120] [--pictures docs/img]

Data: Diamond I13-2 scan 24737 (``tests/data/realdata/i13-24737-tiff``, 91 views x 135 rows x
160 columns), flat/dark corrected with :func:`nanoct.io.scanio.read_scan` and
:func:`~nanoct.io.scanio.line_integrals`, angles from lines 11-101 of ``angles.txt`` (degrees),
rotation axis given at +6.2 px (the data's README: +6.4 from opposite views, +6.0 from
algotom's ``find_center_vo``).

A known motion is added to every 2-D projection by a cubic-spline sub-pixel shift
(``scipy.ndimage.shift``): horizontally a drift (3 px over the scan) plus two harmonics
(1.2 and 0.6 px) plus jitter (0.3 px rms), vertically a cubic (+-2 px) plus jitter (0.3 px
rms). The vertical motion is not modelled by any per-slice method; it is undone with its
known value before the slices are cut (a stack-level estimate of it is not part of this
benchmark), so every slice still carries the horizontal motion and the interpolation of two
shifts.

Reference: FBP of the unmoved scan. The open beam of this scan reads about 0.38 absorbance;
every FBP here (reference and rows) is computed after removing the same per-view air level
(:func:`nanoct.recon.measured.air_level`), the estimator the row-action methods use by
default on measured data, so that air is at zero in all images (the FBP of the raw data,
``FBP raw``, is listed too). Scores: PSNR in dB inside the field-of-view disc (radius
``(L-1)/2 - |axis offset|``, data range of the reference there), after the best sub-pixel
translation of the image onto the reference (:func:`nanoct.evaluation.metrics.register`,
the gauge no data fix); ``--unregistered`` prints the plain scores too.

Rows per slice: FBP of the moved data without correction, FBP with the known motion, FBP with
the stack's motion (:func:`nanoct.motion.stack.estimate_stack_motion` on all chosen slices,
axis given), Dremel with the defaults (``nanoct.dremel``), Dremel with the data as given
(``dremel_off``: ``measured="off"``), RESESOP after Dremel (``resesop``: the model carries Dremel's
motion, ``shifts=``, and eta is estimated from Dremel's image after that motion with
:func:`nanoct.recon.eta.eta_from_residual`, its default on measured data: half the largest
residual per view; ``resesop_eta1``: the whole; ``resesop_unmoved_model``: the paper's
unperturbed model with eta from Dremel's residual before its motion), the stack paths (``dremel_joint``,
``dremel_stack``, ``resesop_stack``: see :func:`stack_rows`), Dremel on the unmoved scan
(``dremel_unmoved``: what a perfect motion estimate would give Dremel against this reference),
and for each iterative method its sweeps and seconds.

The object wider than the field of view: the same slices with the (moved) sinogram cut to its
central half width (80 columns) and scored on the central 80 x 80 of the full-width reference.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

import nanoct
from nanoct.core.geometry import Geometry, remove_translation
from nanoct.evaluation.metrics import register
from nanoct.io.scanio import line_integrals, read_scan
from nanoct.motion.stack import estimate_stack_motion
from nanoct.recon.dremel import DremelParams, dremel
from nanoct.recon.eta import eta_from_residual
from nanoct.recon.fbp import fbp
from nanoct.recon.measured import air_level
from nanoct.recon.resesop import resesop
from nanoct.recon.shared import joint_shifts
from nanoct.workflows.stack import _dremel_slice, _resesop_slice

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "realdata" / "i13-24737-tiff"
AXIS = 6.2
ROWS = (
    "fbp_raw", "fbp", "fbp_known", "fbp_stack", "dremel", "dremel_off", "resesop", "resesop_eta1",
    "resesop_unmoved_model", "dremel_joint", "resesop_joint", "dremel_joint_refined", "resesop_joint_refined",
    "dremel_stack", "resesop_stack", "dremel_unmoved",
)  # fmt: skip
#: The rows with sweeps and seconds, and the rows the targets compare with uncorrected FBP.
ITERATIVE = (
    "dremel", "dremel_off", "resesop", "resesop_eta1", "resesop_unmoved_model", "dremel_joint", "resesop_joint",
    "dremel_joint_refined", "resesop_joint_refined", "dremel_stack", "resesop_stack", "dremel_unmoved",
)  # fmt: skip


def load_scan() -> tuple[np.ndarray, np.ndarray]:
    """Line integrals (K, R, L) and angles (degrees) of the I13 scan."""
    lines = (DATA / "angles.txt").read_text().split()[10:101]
    with tempfile.TemporaryDirectory() as tmp:
        angles_file = Path(tmp) / "angles.txt"
        angles_file.write_text("\n".join(lines) + "\n")
        scan = read_scan(
            DATA / "tiffs", angles_file=angles_file, flats=DATA / "flat_00001.tiff", darks=DATA / "dark_00001.tiff"
        )
    return line_integrals(scan).astype(np.float64), np.array(lines, dtype=np.float64)


def known_motion(n_views: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal and vertical object shifts per view (detector pixels)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n_views)
    h = 3.0 * t - 1.5 + 1.2 * np.sin(4 * np.pi * t) + 0.6 * np.cos(10 * np.pi * t + 0.3)
    v = 2.0 * (2 * t - 1) ** 3
    return h + 0.3 * rng.standard_normal(n_views), v + 0.3 * rng.standard_normal(n_views)


def move(proj: np.ndarray, h: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The projections of the moving object (``p_k(v, u) = P_k(v + v_k, u + h_k)``), vertical motion then undone."""
    moved = [ndimage.shift(p, (-vk, -hk), order=3, mode="nearest") for p, hk, vk in zip(proj, h, v)]
    return np.stack([ndimage.shift(p, (vk, 0.0), order=3, mode="nearest") for p, vk in zip(moved, v)])


def disc(n: int) -> np.ndarray:
    """The field-of-view disc of an n x n image (axis offset taken off the radius)."""
    yy, xx = np.mgrid[:n, :n] - (n - 1) / 2
    return np.hypot(yy, xx) <= (n - 1) / 2 - abs(AXIS)


def scores(image: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """PSNR inside ``mask``: plain and after the best sub-pixel translation onto ``ref``.

    The translation is found over the whole image (:func:`~nanoct.evaluation.metrics.register`);
    where it lowers the score inside the mask the image is scored as it is.
    """
    span = float(ref[mask].max() - ref[mask].min())

    def db(x: np.ndarray) -> float:
        return float(10 * np.log10(span**2 / np.mean((x[mask] - ref[mask]) ** 2)))

    plain = db(image)
    return plain, max(plain, db(register(image, ref)[0]))  # no translation is one of the translations


def air_removed(sino: np.ndarray) -> np.ndarray:
    return sino - air_level(sino)[:, None]


def timed(run, *args, **kwargs) -> tuple[np.ndarray, tuple[int, float]]:
    """The image of ``run(*args, **kwargs)`` with (sweeps, seconds)."""
    t0 = time.perf_counter()
    result = run(*args, **kwargs)
    return result.image, (result.iterations, time.perf_counter() - t0)


def stack_rows(g: Geometry, sino: np.ndarray, stack: np.ndarray, joint: np.ndarray) -> dict[str, tuple]:
    """The slice with a motion shared by the stack, as ``nanoct reconstruct`` and ``nanoct stack`` run it.

    ``dremel_joint``: Dremel with the joint motion held fixed (:func:`nanoct.recon.shared.joint_shifts`
    over the chosen slices; what ``nanoct reconstruct --method dremel`` does on a simulated stack);
    ``dremel_joint_refined``: Dremel started from the joint motion and refining it per slice
    (``nanoct reconstruct --method dremel`` on an imported measured stack); ``resesop_joint`` /
    ``resesop_joint_refined``: RESESOP after the motion of these two (its model carries it, eta
    from the residual of their image after it: ``nanoct reconstruct --method resesop --eta
    estimate:residual`` after them; their seconds include Dremel's);
    ``dremel_stack`` / ``resesop_stack``: the per-slice functions of ``nanoct stack --method
    dremel|resesop`` with the motion of :func:`nanoct.motion.stack.estimate_stack_motion` (on
    measured data Dremel starts from it and refines it; RESESOP's model carries Dremel's refined
    motion, eta half the largest residual per view after it: the ``auto`` level). The sweeps of
    ``resesop_stack`` are not reported (0); its seconds include its Dremel.
    """
    y = sino.astype(np.float32)
    out = {"dremel_stack": timed(_dremel_slice, g, y, stack)}
    for row, fixed in (("dremel_joint", True), ("dremel_joint_refined", False)):
        t0 = time.perf_counter()
        first = dremel(g, y, shifts0=joint, fix_shifts=fixed)
        t1 = time.perf_counter()
        out[row] = (first.image, (first.iterations, t1 - t0))
        eta = eta_from_residual(g, y, first.image, shifts=first.motion)
        image, (sweeps, seconds) = timed(resesop, g, y, eta, shifts=first.motion)
        out[row.replace("dremel", "resesop")] = (image, (sweeps, seconds + t1 - t0))
    t0 = time.perf_counter()
    image, _ = _resesop_slice(g, y, stack, "auto")
    out["resesop_stack"] = (image, (0, time.perf_counter() - t0))
    return out


def reconstruct(
    sino: np.ndarray, unmoved: np.ndarray, angles: np.ndarray, motions: dict[str, np.ndarray], h: np.ndarray
) -> dict:
    """Every row's image for one sinogram, with (sweeps, seconds) for the iterative methods.

    ``dremel_unmoved``: Dremel's view steps on the unmoved sinogram with the shifts held at zero,
    the score a perfect motion estimate would give Dremel against the FBP reference.
    """
    n = sino.shape[1]
    g = Geometry.from_angles(angles, n, n, degrees=True, center_offset=AXIS)
    clean = air_removed(sino)
    stack = motions["stack"]
    out = {
        "fbp_raw": (fbp(g, sino).image, None),
        "fbp": (fbp(g, clean).image, None),
        "fbp_known": (fbp(g, clean, shifts=h).image, None),
        "fbp_stack": (fbp(g, clean, shifts=stack).image, None),
    }
    y = sino.astype(np.float32)
    t0 = time.perf_counter()
    d = nanoct.dremel(y, angles=angles, degrees=True, center_offset=AXIS)
    t1 = time.perf_counter()
    out["dremel"] = (d.image, (d.iterations, t1 - t0))
    off = nanoct.dremel(y, angles=angles, degrees=True, center_offset=AXIS, measured="off")
    t2 = time.perf_counter()
    out["dremel_off"] = (off.image, (off.iterations, t2 - t1))
    # RESESOP after Dremel: the model carries Dremel's motion, eta the residual left after it
    image, (sweeps, seconds) = timed(resesop, g, y, eta_from_residual(g, y, d.image, shifts=d.motion), shifts=d.motion)
    out["resesop"] = (image, (sweeps, seconds + (t1 - t0)))  # Dremel's time counted
    eta1 = eta_from_residual(g, y, d.image, scale=1.0, shifts=d.motion)
    out["resesop_eta1"] = timed(resesop, g, y, eta1, shifts=d.motion)
    # the unperturbed model (the paper's), eta from Dremel's residual before its motion
    eta0 = eta_from_residual(g, y, d.image)
    out["resesop_unmoved_model"] = timed(nanoct.resesop, y, angles=angles, degrees=True, center_offset=AXIS, eta=eta0)
    out["dremel_unmoved"] = timed(dremel, g, unmoved.astype(np.float32), fix_shifts=True)
    return out | stack_rows(g, sino, stack, motions["joint"])


def run_case(proj: np.ndarray, moved: np.ndarray, refs: dict, angles: np.ndarray, h: np.ndarray, cut: bool, args):
    """Scores of every row on every slice of one case (full width or cut to half)."""
    n_det = moved.shape[2]
    cols = slice(n_det // 4, n_det // 4 + n_det // 2) if cut else slice(0, n_det)
    n = cols.stop - cols.start
    sinos = {s: moved[:, s, cols] for s in args.slices}
    g = Geometry.from_angles(angles, n, n, degrees=True, center_offset=AXIS)
    t0 = time.perf_counter()
    stack = estimate_stack_motion(g, np.stack([air_removed(s) for s in sinos.values()]), center=AXIS)
    t1 = time.perf_counter()
    joint, _ = joint_shifts(g, np.stack(list(sinos.values())).astype(np.float32), DremelParams.check(g))
    t2 = time.perf_counter()
    motions = {"stack": stack.shifts, "joint": joint}
    for name, m in motions.items():
        err = remove_translation(m - h, g.angles)
        rms = np.sqrt(np.mean(err**2))
        print(f"{'cut' if cut else 'full'}: {name} motion rms error {rms:.2f} px (translation removed)")
    print(f"stack motion {t1 - t0:.1f} s, joint Dremel motion {t2 - t1:.1f} s")
    mask = disc(n)
    table, images = {}, {}
    for s, sino in sinos.items():
        ref = refs[s][cols, cols]
        out = reconstruct(sino, proj[:, s, cols], angles, motions, h)
        table[s] = {row: (*scores(img, ref, mask), info) for row, (img, info) in out.items()}
        images[s] = {row: img for row, (img, _) in out.items()} | {"reference": ref}
        print(f"  slice {s:3d} done", flush=True)
    return table, images


def print_table(title: str, table: dict, unregistered: bool) -> None:
    """One line per slice, the mean, and the worst margin of each method against uncorrected FBP."""
    print(f"\n{title}: PSNR (dB, registered) inside the field of view; [sweeps, seconds] of the iterative methods")
    print("slice | " + " | ".join(ROWS))
    for s, rows in table.items():
        cells = []
        for row in ROWS:
            plain, reg, info = rows[row]
            cell = f"{reg:.2f}" + (f" ({plain:.2f})" if unregistered else "")
            if row in ITERATIVE:
                cell += f" [{info[0]}, {info[1]:.1f}s]"
            cells.append(cell)
        print(f"{s} | " + " | ".join(cells))
    mean = {row: np.mean([rows[row][1] for rows in table.values()]) for row in ROWS}
    print("mean | " + " | ".join(f"{mean[row]:.2f}" for row in ROWS))
    for row in ITERATIVE:
        margin = [rows[row][1] - rows["fbp"][1] for rows in table.values()]
        stack = mean[row] - mean["fbp_stack"]
        print(f"{row}: worst slice vs uncorrected FBP {min(margin):+.2f} dB, mean {np.mean(margin):+.2f} dB; "
              f"mean vs FBP with the stack's motion {stack:+.2f} dB, vs FBP with the known motion "
              f"{mean[row] - mean['fbp_known']:+.2f} dB")  # fmt: skip


def save_pictures(folder: Path, cases: dict[str, tuple[dict, dict]], slices: list[int]) -> None:
    """One picture per method: the chosen slices of both cases, PSNR in the titles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    for row in ("reference", *ROWS):
        fig, axes = plt.subplots(2, len(slices), figsize=(2.6 * len(slices), 5.6), squeeze=False)
        for i, (case, (table, images)) in enumerate(cases.items()):
            for j, s in enumerate(slices):
                ref = images[s]["reference"]
                lo, hi = float(np.percentile(ref, 1)), float(np.percentile(ref, 99.8))
                ax = axes[i, j]
                ax.imshow(images[s][row], cmap="gray", vmin=lo, vmax=hi)
                score = "" if row == "reference" else f": {table[s][row][1]:.1f} dB"
                ax.set_title(f"{case} {s}{score}", fontsize=9)
                ax.axis("off")
        fig.suptitle(f"I13 24737 with added motion: {row}", fontsize=10)
        fig.tight_layout()
        fig.savefig(folder / f"semireal_{row}.png", dpi=80)
        plt.close(fig)


#: Dremel's measured-data options, shift-estimate refinements and a restart (``--variants``).
VARIANTS = {
    "defaults": {},
    "pad=0 (no extension)": {"pad": 0},
    "pad=L/2": {"pad": "half"},
    "subpixel=False (the simulations' default)": {"subpixel": False},
    "f_sr=4": {"f_sr": 4},
    "restarted from its own motion (twice the time)": {"restart": True},
}


def variant_image(g: Geometry, y: np.ndarray, kw: dict) -> np.ndarray:
    """Dremel's image with one of :data:`VARIANTS` (``restart``: a second run from the first run's motion)."""
    kw = dict(kw)
    if kw.pop("restart", False):
        kw["shifts0"] = dremel(g, y, **kw).motion
    return dremel(g, y, **kw).image


def variants(proj: np.ndarray, moved: np.ndarray, refs: dict, angles: np.ndarray, slices: list[int]) -> None:
    """Mean PSNR (registered) of Dremel with each of :data:`VARIANTS`, both cases."""
    n_det = proj.shape[2]
    for cut in (False, True):
        cols = slice(n_det // 4, n_det // 4 + n_det // 2) if cut else slice(0, n_det)
        n = cols.stop - cols.start
        g = Geometry.from_angles(angles, n, n, degrees=True, center_offset=AXIS)
        means = {}
        for name, kw in VARIANTS.items():
            kw = {**kw, "pad": n // 2} if kw.get("pad") == "half" else kw
            values = [scores(variant_image(g, moved[:, s, cols].astype(np.float32), kw), refs[s][cols, cols],
                             disc(n))[1] for s in slices]  # fmt: skip
            means[name] = np.mean(values)
        print(f"Dremel variants ({'cut' if cut else 'full'}), mean PSNR: "
              + ", ".join(f"{k} {v:.2f}" for k, v in means.items()))  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--slices", default=",".join(str(s) for s in range(20, 121, 10)))
    parser.add_argument("--pictures", default=None, help="folder for one picture per method (e.g. docs/img)")
    parser.add_argument("--picture-slices", default="40,70,100")
    parser.add_argument("--unregistered", action="store_true", help="print the plain scores too")
    parser.add_argument("--variants", action="store_true", help="only Dremel's option variants (mean PSNR)")
    args = parser.parse_args()
    args.slices = [int(s) for s in args.slices.split(",")]
    start = time.perf_counter()
    proj, angles = load_scan()
    h, v = known_motion(proj.shape[0])
    moved = move(proj, h, v)
    n_det = proj.shape[2]
    g = Geometry.from_angles(angles, n_det, n_det, degrees=True, center_offset=AXIS)
    refs = {s: fbp(g, air_removed(proj[:, s])).image for s in args.slices}
    if args.variants:
        variants(proj, moved, refs, angles, args.slices)
        return
    cases = {}
    for name, cut in (("full", False), ("cut", True)):
        cases[name] = run_case(proj, moved, refs, angles, h, cut, args)
        title = "object inside the field of view" if not cut else "object wider than the field of view (half width)"
        print_table(title, cases[name][0], args.unregistered)
    if args.pictures:
        chosen = [s for s in (int(s) for s in args.picture_slices.split(",")) if s in args.slices]
        save_pictures(Path(args.pictures), cases, chosen)
    print(f"\ntotal {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
