"""Rotation axis, 3-D motion and even/odd FRC resolution on the real scans of tests/data/realdata.

1. **Axis.** On each scan (Diamond I13-2 scan 24737: TIFF, 91 views over 180 degrees with flat
   and dark; the raw neutron 360-degree sinogram, normalised by its open-beam columns 2-27 and
   ``-log``; Diamond K11 18014: NeXus, 3001 views over 180 degrees, a 22 x 26 crop inside the
   sample), nanoct's :func:`~nanoct.motion.axis.estimate_axis` on the rows of
   :func:`~nanoct.motion.axis.axis_rows` (every estimator's value and the chosen one) beside two
   references a user would compute: algotom's ``find_center_vo`` called with its defaults on the
   middle slice (the first 180 degrees of it), and the first view against the mirrored view
   180 degrees later (skimage's ``phase_cross_correlation``, upsampled 100 times, no
   normalisation; the neutron scan: the whole first half turn against the mirrored second).
   The consensus is the mean of the two references. For the neutron scan the endpoint convention
   of its uniform angles (360 degrees with or without the last view at 360) is chosen by the
   mirror residual of the half turns.
2. **import = stack.** ``nanoct import --center-offset auto`` and ``nanoct stack`` (through
   :func:`nanoct.cli.run`) on the I13 TIFF folder; the store's axis against the stack's.
3. **Known motion added to I13.** Horizontal: drift + harmonics of the rotation + jitter;
   vertical: cubic in time + jitter (fixed seed); each projection moved by
   ``scipy.ndimage.shift(p, (-v_k, -d_k), order=3, mode="nearest")`` and the motion recovered by
   :func:`~nanoct.motion.estimate.estimate_motion`. Errors are gauge-free RMS: the difference to
   the truth less its least-squares fit on ``(1, cos phi, sin phi)`` (horizontal) or its mean
   (vertical), against the added motion alone ("raw") and with the estimate on the unmoved
   scan subtracted first (the scan's own motion: "relative"). The gauge hides the constant, so
   the axis chosen for the moved scan is checked with it: reconstructing with axis ``c`` and
   shifts ``e_k`` equals axis ``c - e_k`` per view, so the pair is right when ``c - a`` equals
   the unmoved scan's consensus axis (``a`` the constant of the fit of ``e - d``). The same on
   rows 76: and columns 40:120 (the object wider than the field of view, no air).
4. **FRC.** Slices reconstructed by :func:`~nanoct.recon.stack.corrected_fbp` from the even and
   from the odd views, compared by :func:`~nanoct.evaluation.frc.frc` (a soft disc on the field
   of view, rings summed over the slices); first crossing of 1/7 and of the half-bit curve.
5. **The stack on the wider crop.** The same moved crop (rows 76:, columns 40:120) imported with
   ``nanoct import --line-integrals --center-offset auto`` and run through ``nanoct stack`` (its
   default estimator where no air is seen, and ``--refine 2,2,2,1``, Dremel and projection
   matching); the recorded shifts, vertical shifts and axis with the errors of part 3. And the
   stack on the K11 interior crop (no known motion: method, axis, shifts, vertical guard).
6. **Picture** ``real_motion_i13.png``: the moved scan uncorrected, corrected, and the unmoved
   reference (a middle slice and a vertical cut).

Usage::

    PYTHONPATH=src python benchmarks/real_scans.py --png-dir docs/img
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import tifffile
from scipy import ndimage
from skimage.registration import phase_cross_correlation

from nanoct.core.geometry import Geometry
from nanoct.evaluation.frc import frc, frc_resolution, ring_counts
from nanoct.motion.axis import axis_rows, estimate_axis
from nanoct.motion.estimate import estimate_motion
from nanoct.motion.matching import apply_vertical
from nanoct.preprocess import Corrections, apply_corrections
from nanoct.recon.stack import corrected_fbp

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "realdata"
I13 = DATA / "i13-24737-tiff"
SEED = 31
ROWS = []  # markdown table rows: (part, measure, value, target, seconds)


def record(part: str, measure: str, value: str, target: str = "", seconds: float | None = None) -> None:
    ROWS.append((part, measure, value, target, "" if seconds is None else f"{seconds:.1f}"))
    print(f"[{part}] {measure}: {value}" + (f"   (target {target})" if target else ""))


# ---------------------------------------------------------------- loading


def load_i13() -> tuple[np.ndarray, np.ndarray]:
    """Line integrals (91, 135, 160) after flat/dark and ``-log``, and the angles in radians."""
    flat = tifffile.imread(I13 / "flat_00001.tiff").astype(np.float64)
    dark = tifffile.imread(I13 / "dark_00001.tiff").astype(np.float64)
    raw = np.stack([tifffile.imread(p) for p in sorted((I13 / "tiffs").glob("raw_*.tiff"))]).astype(np.float64)
    gain = flat - dark
    good = gain > 0  # one dead pixel: transmission 1, as nanoct's import does
    trans = np.where(good, (raw - dark) / np.where(good, gain, 1.0), 1.0)
    angles = np.deg2rad(np.loadtxt(I13 / "angles.txt")[10:101])
    return -np.log(np.clip(trans, 1e-6, None)), angles


def load_neutron() -> tuple[np.ndarray, np.ndarray, float, str]:
    """Line integrals (459, 503) over 360 degrees, the angles, the view index of 180 degrees, the convention."""
    raw = tifffile.imread(DATA / "neutron-360-sinogram" / "sinogram_360_neutron_image.tif").astype(np.float64)
    beam = np.median(raw[:, 2:28], axis=1)
    sino = -np.log(np.clip(raw / beam[:, None], 1e-6, None))
    k = sino.shape[0]
    # 360 degrees with the last view at 360 (step 360/458: 180 degrees at view 229) or without
    # it (step 360/459: 180 degrees between views 229 and 230): the smaller mirror residual wins
    smooth = ndimage.gaussian_filter(sino, (0, 1.0))
    residuals = {}
    for name, half in (("last view at 360", 229.0), ("last view before 360", 229.5)):
        lo, w = int(half), half - int(half)
        n = k - lo - 1
        residuals[name] = mirror_residual(smooth[:n], (1 - w) * smooth[lo : lo + n] + w * smooth[lo + 1 : lo + 1 + n])
    chosen = min(residuals, key=residuals.get)
    angles = np.linspace(0, 2 * np.pi, k) if chosen == "last view at 360" else np.arange(k) * 2 * np.pi / k
    text = ", ".join(f"{name} {value:.5f}" for name, value in residuals.items())
    half = 229.0 if chosen == "last view at 360" else 229.5
    return sino, angles, half, f"{chosen} (mirror residual {text})"


def load_k11() -> tuple[np.ndarray, np.ndarray]:
    """Line integrals (3001, 22, 26) after flat/dark (means of the 100 each) and ``-log``, and the angles."""
    with h5py.File(DATA / "k11-18014-nexus" / "k11-18014.nxs", "r") as f:
        data = f["/entry/imaging/data"][()].astype(np.float64)
        key = f["/entry/instrument/imaging/image_key"][()]
        angles = np.deg2rad(f["/entry/imaging_sum/gts_theta_value"][()])
    flat, dark = data[key == 1].mean(axis=0), data[key == 2].mean(axis=0)
    trans = (data[key == 0] - dark) / (flat - dark)
    return -np.log(np.clip(trans, 1e-6, None)), angles[key == 0]


# ---------------------------------------------------------------- axis references


def mirror_offset(first: np.ndarray, opposite: np.ndarray) -> float:
    """Axis offset from ``first`` against ``opposite`` mirrored (``(..., L)`` arrays): half the shift."""
    shift, _, _ = phase_cross_correlation(first, opposite[..., ::-1], upsample_factor=100, normalization=None)
    return float(shift[-1]) / 2.0


def mirror_residual(first: np.ndarray, opposite: np.ndarray) -> float:
    """Mean square of ``first`` less ``opposite`` mirrored and moved by the best shift (margins left out)."""
    offset = mirror_offset(first, opposite)
    moved = ndimage.shift(opposite[:, ::-1], (0, 2 * offset), order=3, mode="nearest")
    margin = first.shape[1] // 10
    return float(np.mean((first - moved)[:, margin:-margin] ** 2))


def vo_offset(sino_180: np.ndarray) -> float:
    """Algotom's ``find_center_vo`` with its defaults, as an offset from the detector centre."""
    from algotom.prep.calculation import find_center_vo

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        column = float(find_center_vo(np.ascontiguousarray(sino_180)))
    for w in caught:
        print(f"  algotom: {w.message}")
    return column - (sino_180.shape[1] - 1) / 2


def axis_part() -> None:
    """nanoct's axis estimators beside find_center_vo and the mirror match, per scan."""
    proj, phi = load_i13()
    sino, sphi, half, convention = load_neutron()
    k11, kphi = load_k11()
    lo, w = int(half), half - int(half)
    n = sino.shape[0] - lo - 1
    opposite = (1 - w) * sino[lo : lo + n] + w * sino[lo + 1 : lo + 1 + n]
    scans: dict[str, dict[str, Any]] = {
        "I13 24737": {
            "sinos": proj.transpose(1, 0, 2)[axis_rows(proj.shape[1])],
            "phi": phi,
            "vo": lambda: vo_offset(proj[:, proj.shape[1] // 2]),
            "mirror": lambda: mirror_offset(proj[0], proj[-1]),
        },
        "neutron 360": {
            "sinos": sino[None],
            "phi": sphi,
            "vo": lambda: vo_offset(sino[: lo + 1]),  # the first 180 degrees
            "mirror": lambda: mirror_offset(sino[:n], opposite),
        },
        "K11 18014 (interior)": {
            "sinos": k11.transpose(1, 0, 2)[axis_rows(k11.shape[1])],
            "phi": kphi,
            "vo": lambda: vo_offset(k11[:, k11.shape[1] // 2]),
            "mirror": lambda: mirror_offset(k11[:5].mean(axis=0), k11[-5:].mean(axis=0)),
        },
    }
    record("axis", "neutron angles", convention)
    for name, scan in scans.items():
        start = time.perf_counter()
        estimate = estimate_axis(scan["sinos"], scan["phi"])
        seconds = time.perf_counter() - start
        vo, mirror = scan["vo"](), scan["mirror"]()
        consensus = 0.5 * (vo + mirror)
        values = ", ".join(f"{key} {value:+.2f}" for key, value in estimate.estimates.items())
        record(
            "axis", f"{name}: nanoct estimators", f"{values}; chosen {estimate.offset:+.2f} ({'+'.join(estimate.used)})"
        )
        for note in estimate.notes:
            print(f"  nanoct note: {note}")
        record("axis", f"{name}: find_center_vo / mirror / consensus", f"{vo:+.2f} / {mirror:+.2f} / {consensus:+.2f}")
        error = abs(estimate.offset - consensus)
        record("axis", f"{name}: abs(nanoct - consensus) px", f"{error:.2f}", "<= 0.5", seconds)


def import_stack_part() -> None:
    """``nanoct import --center-offset auto`` then ``nanoct stack`` on the I13 folder: the same axis?"""
    from nanoct.cli import run
    from nanoct.io.store import DataStore

    with tempfile.TemporaryDirectory() as tmp:
        angles = Path(tmp) / "angles.txt"
        np.savetxt(angles, np.loadtxt(I13 / "angles.txt")[10:101])
        store = Path(tmp) / "store"
        start = time.perf_counter()
        flat_dark = ["--flats", str(I13 / "flat_00001.tiff"), "--darks", str(I13 / "dark_00001.tiff")]
        code = run(
            ["import", str(I13 / "tiffs"), "--out", str(store), "--format", "tiff", "--angles", str(angles), *flat_dark]
            + ["--center-offset", "auto"]
        )
        seconds_import = time.perf_counter() - start
        if code != 0:
            raise SystemExit(f"nanoct import failed (exit status {code})")
        start = time.perf_counter()
        code = run(["stack", str(store), "--quiet"])
        seconds_stack = time.perf_counter() - start
        if code != 0:
            raise SystemExit(f"nanoct stack failed (exit status {code})")
        opened = DataStore.open(store)
        imported = float(opened.geometry.center_offset)
        recorded = opened.meta["scan"].get("axis", {}).get("offset", float("nan"))
        stacked = float(opened.recons.motion_info("fbp_stack")["center_offset"])
    record(
        "import/stack",
        "I13: import axis (geometry; scan['axis'])",
        f"{imported:+.4f}; {recorded:+.4f}",
        "",
        seconds_import,
    )
    record("import/stack", "I13: stack axis (motion_info center_offset)", f"{stacked:+.4f}", "", seconds_stack)
    record("import/stack", "I13: abs(import - stack) px", f"{abs(imported - stacked):.4f}", "0 (same axis)")


# ---------------------------------------------------------------- known motion


def added_motion(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal ``d`` (drift + rotation harmonics + jitter) and vertical ``v`` (cubic + jitter), pixels."""
    rng = np.random.default_rng(SEED)
    t = np.linspace(-1.0, 1.0, phi.size)
    d = 2.0 * t + 1.2 * np.cos(phi) + 2.0 * np.sin(2 * phi) + 1.5 * np.cos(3 * phi) + rng.normal(0, 0.5, phi.size)
    v = 2.0 * t**3 + 1.0 * t + rng.normal(0, 0.5, phi.size)
    return d, v


def move(proj: np.ndarray, d: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``m_k(z, x) = Q_k(z + v_k, x + d_k)`` by cubic interpolation."""
    return np.stack([ndimage.shift(p, (-vk, -dk), order=3, mode="nearest") for p, dk, vk in zip(proj, d, v)])


def gauge_free_rms(error: np.ndarray, phi: np.ndarray, horizontal: bool) -> float:
    """RMS of ``error`` less its least-squares fit on (1, cos, sin) (horizontal) or its mean (vertical)."""
    if horizontal:
        basis = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
        error = error - basis @ np.linalg.lstsq(basis, error, rcond=None)[0]
    else:
        error = error - error.mean()
    return float(np.sqrt(np.mean(error**2)))


def motion_case(
    name: str, reference: np.ndarray, moved: np.ndarray, phi: np.ndarray, truth: tuple, target_h: str, axis: float
):
    """Estimate the motion of the unmoved and the moved projections; print the gauge-free errors.

    ``axis``: the unmoved scan's axis (consensus of find_center_vo and the mirror match).
    """
    d, v = truth
    start = time.perf_counter()
    ref = estimate_motion(reference, phi)
    seconds_ref = time.perf_counter() - start
    start = time.perf_counter()
    est = estimate_motion(moved, phi)
    seconds = time.perf_counter() - start
    record(
        "motion", f"{name}: horizontal estimator (moved; unmoved)", f"{est.horizontal_method}; {ref.horizontal_method}"
    )
    values = ", ".join(f"{key} {value:+.2f}" for key, value in est.axis.estimates.items())
    record(
        "motion",
        f"{name}: axis of moved (unmoved)",
        f"{est.axis.offset:+.2f} ({ref.axis.offset:+.2f}); moved: {values}",
    )
    record("motion", f"{name}: own motion of the unmoved scan (RMS h, v)",
           f"{gauge_free_rms(ref.horizontal, phi, True):.3f}, {gauge_free_rms(ref.vertical, phi, False):.3f}",
           "", seconds_ref)  # fmt: skip
    # the axis that goes with the shifts: reconstructing with (axis c, shifts e_k) equals (c - e_k)
    # per view, so the pair is right when c - a equals the unmoved scan's axis, a being the
    # constant of the least-squares fit of e - d on (1, cos phi, sin phi)
    basis = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
    constant = np.linalg.lstsq(basis, est.horizontal - d, rcond=None)[0][0]
    consistent = est.axis.offset - constant - axis
    record("motion", f"{name}: axis error of the moved scan given its shifts (axis - a - consensus)",
           f"{consistent:+.2f}", "abs <= 0.5")  # fmt: skip
    for label, base_d, base_v in (("raw", 0.0, 0.0), ("relative", ref.horizontal, ref.vertical)):
        eh = gauge_free_rms(est.horizontal - base_d - d, phi, True)
        ev = gauge_free_rms(est.vertical - base_v - v, phi, False)
        record(
            "motion",
            f"{name}: horizontal RMS error, {label}",
            f"{eh:.3f}",
            target_h,
            seconds if label == "raw" else None,
        )
        record("motion", f"{name}: vertical RMS error, {label}", f"{ev:.3f}", "<= 0.25")
    return est


# ---------------------------------------------------------------- FRC and picture


def without_air(lines: np.ndarray) -> np.ndarray:
    """Line integrals less each view's open-beam absorbance (nanoct's open-beam correction)."""
    return apply_corrections(lines, Corrections(open_beam=True), kind="line_integrals").line_integrals


def disc_mask(n: int) -> np.ndarray:
    """A disc of radius 0.45 n with a cosine edge 0.05 n wide (weight 1 inside, 0 outside)."""
    r = np.hypot(*np.meshgrid(np.arange(n) - (n - 1) / 2, np.arange(n) - (n - 1) / 2, indexing="ij"))
    edge = np.clip((r - 0.40 * n) / (0.05 * n), 0.0, 1.0)
    return 0.5 + 0.5 * np.cos(np.pi * edge)


def slices(proj: np.ndarray, phi: np.ndarray, center: float, d: np.ndarray | None, rows: Any, views=slice(None)):
    """Slices ``rows`` of ``(K, R, L)`` projections by corrected FBP from the views ``views``."""
    n_det = proj.shape[2]
    geometry = Geometry.from_angles(phi[views], n_det, n_det, center_offset=center)
    shifts = None if d is None else d[views]
    return np.stack([corrected_fbp(geometry, proj[views, r], shifts) for r in rows])


def even_odd_frc(proj: np.ndarray, phi: np.ndarray, center: float, d: np.ndarray | None, rows: Any) -> str:
    """1/7 and half-bit crossings of even against odd view reconstructions (rings summed over ``rows``)."""
    even = slices(proj, phi, center, d, rows, slice(0, None, 2))
    odd = slices(proj, phi, center, d, rows, slice(1, None, 2))
    freq, curve = frc(even, odd, mask=disc_mask(even.shape[-1]))
    f7, p7 = frc_resolution(freq, curve, "1/7")
    fh, ph = frc_resolution(freq, curve, "half-bit", counts=len(rows) * ring_counts(even.shape[-2:]))

    def text(f: float | None, p: float | None) -> str:
        return "above to Nyquist" if f is None else f"{f:.3f} c/px ({p:.2f} px)"

    return f"1/7: {text(f7, p7)}; half-bit: {text(fh, ph)}"


def motion_and_frc_part(png_dir: Path | None) -> None:
    """Known motion added to I13 (inside and wider than the field of view), recovered; FRC and picture."""
    proj, phi = load_i13()
    d, v = added_motion(phi)
    record("motion", "added motion (gauge-free RMS h, v)", f"{gauge_free_rms(d, phi, True):.2f}, {v.std():.2f} px")
    moved = move(proj, d, v)
    consensus = 0.5 * (vo_offset(proj[:, proj.shape[1] // 2]) + mirror_offset(proj[0], proj[-1]))
    est = motion_case("I13 inside the field of view", proj, moved, phi, (d, v), "<= 0.25", consensus)
    wide = (slice(None), slice(76, None), slice(40, 120))
    est_wide = motion_case(
        "I13 rows 76:, columns 40:120 (wider)", proj[wide], moved[wide], phi, (d, v), "<= 0.4", consensus
    )
    start = time.perf_counter()
    rows = np.arange(8, proj.shape[1] - 7, 8)
    ref_axis = estimate_axis(proj.transpose(1, 0, 2)[axis_rows(proj.shape[1])], phi).offset
    # the slices are reconstructed after the open beam (absorbance ~0.4 in air) is removed from
    # every view, so that views moved against the detector edge leave no streaks
    cases = {
        "I13 unmoved (reference)": (without_air(proj), ref_axis, None),
        "I13 moved, uncorrected": (without_air(moved), est.axis.offset, None),
        "I13 moved, corrected": (apply_vertical(without_air(moved), est.vertical), est.axis.offset, est.horizontal),
    }
    for name, (data, center, shifts) in cases.items():
        record("FRC even/odd", name, even_odd_frc(data, phi, center, shifts, rows))
    wide_rows = np.arange(4, moved[wide].shape[1] - 3, 6)
    straight_wide = apply_vertical(moved[wide], est_wide.vertical)
    record("FRC even/odd", "I13 wider, unmoved", even_odd_frc(proj[wide], phi, est_wide.axis.offset, None, wide_rows))
    record("FRC even/odd", "I13 wider, moved, uncorrected",
           even_odd_frc(moved[wide], phi, est_wide.axis.offset, None, wide_rows))  # fmt: skip
    record("FRC even/odd", "I13 wider, moved, corrected",
           even_odd_frc(straight_wide, phi, est_wide.axis.offset, est_wide.horizontal, wide_rows),
           "", time.perf_counter() - start)  # fmt: skip
    if png_dir is not None:
        start = time.perf_counter()
        all_rows = np.arange(proj.shape[1])
        volumes = [slices(data, phi, center, shifts, all_rows) for data, center, shifts in cases.values()]
        picture(png_dir / "real_motion_i13.png", [volumes[1], volumes[2], volumes[0]], proj.shape[1] // 2)
        record("picture", "real_motion_i13.png", str(png_dir / "real_motion_i13.png"), "", time.perf_counter() - start)


def _stack_run(lines: np.ndarray, phi: np.ndarray, extra: list[str]) -> tuple[dict, np.ndarray, float]:
    """``nanoct import`` of ``(K, R, L)`` line integrals, then ``nanoct stack``: motion record, shifts, seconds."""
    from nanoct.cli import run
    from nanoct.io.store import DataStore

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        np.save(folder / "p.npy", lines.astype(np.float32))
        np.savetxt(folder / "a.txt", np.rad2deg(phi))
        store = folder / "store"
        args = ["import", str(folder / "p.npy"), "--out", str(store), "--angles", str(folder / "a.txt")]
        if run([*args, "--line-integrals", "--center-offset", "auto", "-q"]) != 0:
            raise SystemExit("nanoct import failed")
        start = time.perf_counter()
        if run(["stack", str(store), "--workers", "0", "-q", *extra]) != 0:
            raise SystemExit("nanoct stack failed")
        seconds = time.perf_counter() - start
        data = DataStore.open(store)
        return data.recons.motion_info("fbp_stack"), data.recons.shared_shifts("fbp_stack"), seconds


def stack_part() -> None:
    """``nanoct stack`` on the I13 crop wider than the field of view with the added motion, and on K11."""
    proj, phi = load_i13()
    d, v = added_motion(phi)
    consensus = 0.5 * (vo_offset(proj[:, proj.shape[1] // 2]) + mirror_offset(proj[0], proj[-1]))
    wide = move(proj, d, v)[:, 76:, 40:120]
    basis = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
    for label, extra in (("default", []), ("--refine 2,2,2,1", ["--refine", "2,2,2,1"])):
        info, shifts, seconds = _stack_run(wide, phi, extra)
        constant = np.linalg.lstsq(basis, shifts - d, rcond=None)[0][0]
        record("stack", f"I13 wider, {label}: method; axis by", f"{info['horizontal_method']}; {info['center_method']}")
        record("stack", f"I13 wider, {label}: horizontal RMS error", f"{gauge_free_rms(shifts - d, phi, True):.3f}",
               "<= 0.4", seconds)  # fmt: skip
        record("stack", f"I13 wider, {label}: vertical RMS error",
               f"{gauge_free_rms(np.asarray(info['vertical']) - v, phi, False):.3f}", "<= 0.25")  # fmt: skip
        record("stack", f"I13 wider, {label}: axis error given the shifts (axis - a - consensus)",
               f"{info['center_offset'] - constant - consensus:+.2f}", "abs <= 0.5")  # fmt: skip
    k11, kphi = load_k11()
    info, shifts, seconds = _stack_run(k11, kphi, [])
    guard = {"misfit_ratio": float("nan"), "profile_snr": float("nan"), "raw_rms": float("nan")}
    guard.update(info.get("vertical_guard", {}))
    how = f"{info['horizontal_method']}; {info['center_offset']:+.3f} ({info['center_method']})"
    record("stack", "K11 interior: method; axis (by)", how, "", seconds)
    tests = f"misfit ratio {guard['misfit_ratio']:.2f}, SNR {guard['profile_snr']:.2f}, raw {guard['raw_rms']:.2f} px"
    record("stack", "K11 interior: shifts, gauge-free RMS; vertical RMS (guard)",
           f"{gauge_free_rms(shifts, kphi, True):.3f}; {np.std(info['vertical']):.3f} ({tests})")  # fmt: skip


def other_scans_frc() -> None:
    """Even/odd FRC of the neutron and K11 slices at nanoct's axis (no motion added)."""
    start = time.perf_counter()
    sino, phi, _, _ = load_neutron()
    center = estimate_axis(sino[None], phi).offset
    if phi[-1] - phi[0] > 2 * np.pi - 1e-9:  # the view at 360 degrees repeats the first: left out of FBP
        sino, phi = sino[:-1], phi[:-1]
    record("FRC even/odd", "neutron 360 (nanoct's axis)", even_odd_frc(sino[:, None], phi, center, None, [0]))
    k11, kphi = load_k11()
    center = estimate_axis(k11.transpose(1, 0, 2)[axis_rows(k11.shape[1])], kphi).offset
    record("FRC even/odd", "K11 interior (nanoct's axis)",
           even_odd_frc(k11, kphi, center, None, np.arange(k11.shape[1])), "", time.perf_counter() - start)  # fmt: skip


def picture(png: Path, volumes: list[np.ndarray], row: int) -> None:
    """Middle slice (top) and a vertical cut through the object's centre in that slice (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    titles = ["moved, uncorrected", "moved, corrected", "unmoved reference"]
    n = volumes[0].shape[-1]
    lo, hi = np.percentile(volumes[2][row], [1, 99.5])
    fig, axes = plt.subplots(2, 3, figsize=(7.5, 5.6), gridspec_kw={"height_ratios": [n, volumes[0].shape[0]]})
    for i, (volume, title) in enumerate(zip(volumes, titles)):
        axes[0, i].imshow(volume[row], cmap="gray", vmin=lo, vmax=hi)
        axes[0, i].set_title(f"{title}\nslice {row}", fontsize=9)
        centre = np.unravel_index(np.argmax(ndimage.gaussian_filter(volume[row], 3.0)), (n, n))[0]
        axes[1, i].imshow(volume[:, centre, :], cmap="gray", vmin=lo, vmax=hi)
        axes[1, i].set_title(f"vertical cut (image row {centre})", fontsize=9)
        for ax in axes[:, i]:
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(png, dpi=72)
    plt.close(fig)
    from PIL import Image

    Image.open(png).convert("L").save(png, optimize=True)  # grey levels only: a small file


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--png-dir", type=Path, default=None, help="Write real_motion_i13.png here.")
    parser.add_argument("--skip-cli", action="store_true", help="Leave out nanoct import / stack (about 45 s).")
    parser.add_argument("--skip-axis", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--only-stack", action="store_true", help="Run only part 5 (the stack, about 80 s).")
    args = parser.parse_args()
    total = time.perf_counter()
    parts = (None if args.skip_axis else axis_part, None if args.skip_cli else import_stack_part, other_scans_frc)
    for part in (stack_part,) if args.only_stack else (*parts, stack_part):
        if part is not None:
            start = time.perf_counter()
            part()
            print(f"-- {part.__name__}: {time.perf_counter() - start:.1f} s")
    start = time.perf_counter()
    if not args.only_stack:
        motion_and_frc_part(args.png_dir)
        print(f"-- motion_and_frc_part: {time.perf_counter() - start:.1f} s")
    print(f"\ntotal {time.perf_counter() - total:.1f} s\n")
    print("| part | measure | value | target | seconds |")
    print("|---|---|---|---|---|")
    for row in ROWS:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
