"""Constructed 3-D scans and known motion shared by the tests (``from scan_cases import ...``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.ndimage as ndi

from nanoct.sim.analytic import ellipse_sinogram, stack_phantom


def known_motion(angles: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal drift + rotation harmonics + jitter and vertical cubic + jitter (pixels)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(-1, 1, angles.size)
    horizontal = 1.5 * t + 1.0 * np.sin(angles) + 0.6 * np.cos(2 * angles) + 0.3 * rng.standard_normal(angles.size)
    vertical = 1.0 * t**3 - 0.8 * t + 0.25 * rng.standard_normal(angles.size)
    return horizontal, vertical


def moved(projections: np.ndarray, horizontal: np.ndarray, vertical: np.ndarray) -> np.ndarray:
    """``m_k(z, x) = Q_k(z + v_k, x + d_k)``: each projection moved up by ``v_k`` and left by ``d_k``."""
    return np.stack(
        [ndi.shift(p, (-v, -d), order=3, mode="nearest") for p, v, d in zip(projections, vertical, horizontal)]
    )


def gauge_free_rms(estimate: np.ndarray, truth: np.ndarray, angles: np.ndarray, *, vertical: bool = False) -> float:
    """RMS of ``estimate - truth`` less what the data cannot fix (a constant; horizontally also cos and sin)."""
    diff = np.asarray(estimate, dtype=np.float64) - truth
    columns = [np.ones_like(angles)] if vertical else [np.ones_like(angles), np.cos(angles), np.sin(angles)]
    basis = np.stack(columns, axis=1)
    diff = diff - basis @ np.linalg.lstsq(basis, diff, rcond=None)[0]
    return float(np.sqrt(np.mean(diff**2)))


def analytic_projections(angles: np.ndarray, n_det: int, n_rows: int, center: float, seed: int = 2) -> np.ndarray:
    """``(K, R, L)`` exact projections of a stack of ellipse slices about an axis at ``center``.

    The slices' density follows a smooth bump in ``z`` (an object with a top and a bottom inside
    the rows), so that the stack has vertical structure.
    """
    slices = stack_phantom(n_det, n_rows, seed=seed)
    z = np.linspace(-1, 1, n_rows)
    envelope = 0.5 + 0.5 * np.tanh((0.6 - np.abs(z)) * 8) + 0.3 * np.sin(5 * z)
    sinos = [w * ellipse_sinogram(e, angles, n_det, center_offset=center) for w, e in zip(envelope, slices)]
    return np.stack(sinos, axis=1)


#: The slab tests' small stack: views, rows, columns, axis offset.
SLAB_K, SLAB_R, SLAB_L, SLAB_OFFSET = 90, 7, 48, 1.4


def slab_line_integrals(d=None, v=None):
    """(K, R, L) line integrals of a stack whose slices change smoothly with the row; moved by (d, v)."""
    k_views, n_rows, n_det = SLAB_K, SLAB_R, SLAB_L
    phi = np.arange(k_views) * np.pi / k_views
    phantoms = stack_phantom(n_det, n_rows + 8, seed=4)
    rows = np.arange(n_rows + 8, dtype=np.float64) - 4  # rows -4 .. R + 3: room for vertical moves
    sinos = np.stack([ellipse_sinogram(e, phi, n_det, shifts=d, center_offset=SLAB_OFFSET) for e in phantoms])
    out = np.empty((k_views, n_rows, n_det), np.float32)
    for k in range(k_views):
        z = np.arange(n_rows) + (0.0 if v is None else v[k])  # p_k(u, z) = P_k(u + d_k, z + v_k)
        for col in range(n_det):
            out[k, :, col] = np.interp(z, rows, sinos[:, k, col])
    return phi, out


def write_raw_scan(tmp_path: Path, data: np.ndarray, phi: np.ndarray) -> tuple[Path, dict]:
    """A raw scan as .npy intensities with flats and darks (transmission exp(-p) times a flat of 1000, dark 50)."""
    shape = (2, SLAB_R, SLAB_L)
    flat = np.full(shape, 1000.0, np.float32)
    dark = np.full(shape, 50.0, np.float32)
    np.save(tmp_path / "proj.npy", (dark[0] + (flat[0] - dark[0]) * np.exp(-data)).astype(np.float32))
    np.save(tmp_path / "flats.npy", flat)
    np.save(tmp_path / "darks.npy", dark)
    np.savetxt(tmp_path / "angles.txt", np.rad2deg(phi))
    read = {"angles_file": str(tmp_path / "angles.txt"), "flats": str(tmp_path / "flats.npy")}
    read["darks"] = str(tmp_path / "darks.npy")
    return tmp_path / "proj.npy", read


#: ETSpy's STEM needle tilt series (77 tilts, +-76 degrees), binned 2 x 2, with the group's alignment.
NEEDLE = Path(__file__).resolve().parent / "data" / "realdata" / "etspy-needle-tilt"


def needle_series(binning: int = 1) -> tuple[np.ndarray, np.ndarray, dict]:
    """Projections ``(K, R, L)`` as nanoct reads the vendored copy (tilt axis along the rows), further
    averaged over ``binning`` x ``binning`` pixels; angles (radians); the reference (``reference.npz``)."""
    from nanoct.io.scanio import ReaderOptions, read_scan

    scan = read_scan(NEEDLE / "needle_bin2.mrc", is_line_integral=True, options=ReaderOptions(tilt_axis="rows"))
    proj = np.asarray(scan.projections, dtype=np.float64)
    k, r, c = proj.shape
    proj = proj.reshape(k, r // binning, binning, c // binning, binning).mean(axis=(2, 4))
    return proj, np.asarray(scan.angles), dict(np.load(NEEDLE / "reference.npz"))


def needle_errors(d, v, center: float, tilt_deg: float, angles: np.ndarray, ref: dict, binning: int) -> dict:
    """nanoct's alignment of the needle against ETSpy's, in full-size pixels (``binning``: of ``d``, ``v``, ``center``).

    Both move the raw frames, then rotate: horizontal ``binning * d`` against the reference's row
    shifts, gauge-free; vertical ``binning * v`` against its column shifts less the mean; the axis:
    view ``k``'s axis row ``127.5 + binning (c - d_k)`` against the row ETSpy levels to 128 at the
    middle column less the shift, their difference's constant on ``(1, cos, sin)``; the tilt against
    ``-tiltaxis_deg`` (ETSpy's rotation that levels the axis).
    """
    shifts = ref["shifts_yx"]
    horizontal = gauge_free_rms(binning * np.asarray(d), shifts[:, 0], angles)
    vertical = gauge_free_rms(binning * np.asarray(v), shifts[:, 1], angles, vertical=True)
    theta = np.deg2rad(float(ref["tiltaxis_deg"]))
    row = 128.0 + (float(ref["yshift"]) + 0.5 * np.sin(theta)) / np.cos(theta)
    basis = np.stack([np.ones_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    axis_diff = 127.5 + binning * (center - np.asarray(d)) - (row - shifts[:, 0])
    axis = float(np.linalg.lstsq(basis, axis_diff, rcond=None)[0][0])
    return {"horizontal": horizontal, "vertical": vertical, "axis": axis, "tilt": tilt_deg + float(ref["tiltaxis_deg"])}
