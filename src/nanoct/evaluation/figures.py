"""Figures of a data set and of its post-processing networks (matplotlib, Agg backend, written to files)."""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.names import parse_name, prediction_name
from ..io.fileio import atomic_write_bytes
from ..io.store import DataStore
from ..recon.fbp import fbp
from ..sim.motion import plot_motion
from .conformal import half_width
from .evaluate import format_uncertainty_table
from .metrics import reliability

__all__ = [
    "RELIABILITY_LEVELS",
    "SCAN_PANELS",
    "compare_reconstructions",
    "reliability_diagram",
    "show_sample",
    "training_curves",
    "uncertainty_maps",
    "uncertainty_report",
]

#: Nominal probabilities of the central Gaussian intervals in the reliability diagram.
RELIABILITY_LEVELS = np.array([0.05, *np.arange(0.1, 0.95, 0.1), 0.95, 0.99])


def _save(fig, out: str | os.PathLike[str], dpi: int) -> Path:
    """Write a figure as PNG atomically."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return atomic_write_bytes(out, buf.getvalue())


def show_sample(store: DataStore, index: int, out: str | os.PathLike[str]) -> Path:
    """Write a figure of one sample, like the paper's figures 1-3.

    Panels: the phantom; its motion per view; unperturbed and perturbed sinograms and their
    difference; FBP of the unperturbed and of the perturbed data (the motion artefacts). A slice
    of an imported scan, which has no phantom, motion or unperturbed data, shows its measured
    sinogram, its FBP with the stored axis and the slice's reconstructions in the store.

    Parameters
    ----------
    store : DataStore
        Data set.
    index : int
        Sample index.
    out : path
        PNG file to write (written to a temporary name, then renamed).

    Returns
    -------
    Path
        The written file.
    """
    from matplotlib.figure import Figure

    if store.is_scan:
        return _show_scan(store, index, out)
    sample = store.read_sample(index)
    geometry = store.geometry
    fbp_eta = fbp(geometry, sample.sinogram_eta).image
    fbp_meas = fbp(geometry, sample.sinogram).image
    fig = Figure(figsize=(15, 8.5), layout="constrained")
    grid = fig.add_gridspec(2, 4)
    split_name = {0: "train", 1: "val", 2: "test"}[int(store.split[index])]

    def image(ax, data, title, cmap="gray", vmin=None, vmax=None, extent=None, aspect="equal"):
        im = ax.imshow(data, cmap=cmap, vmin=vmin, vmax=vmax, extent=extent, aspect=aspect, interpolation="nearest")
        ax.set_title(title, fontsize=10)
        fig.colorbar(im, ax=ax, shrink=0.8)
        return im

    top = float(sample.phantom.max()) if sample.phantom.max() > 0 else 1.0  # a matched set's scale is the scan's
    image(fig.add_subplot(grid[0, 0]), sample.phantom, f"phantom #{index} ({split_name})", vmin=0, vmax=top)
    plot_motion(sample.motion, ax=fig.add_subplot(grid[0, 1:3]), angles=geometry.angles)
    ax = fig.add_subplot(grid[0, 3])
    ax.plot(np.rad2deg(geometry.angles), sample.eta, lw=1)
    ax.set_xlabel("view angle [deg]")
    ax.set_ylabel("eta_k = max_l |y - y_eta|")
    ax.set_title("per-view model error", fontsize=10)
    deg = np.rad2deg(geometry.angle_range)
    extent = (0, deg, geometry.n_det - 0.5, -0.5)
    vmax = float(max(sample.sinogram.max(), sample.sinogram_eta.max()))
    for col, (data, title) in enumerate(
        ((sample.sinogram_eta, "unperturbed sinogram y_eta"), (sample.sinogram, "perturbed sinogram y"))
    ):
        ax = fig.add_subplot(grid[1, col])
        image(ax, data.T, title, vmin=0, vmax=vmax, extent=extent, aspect="auto")
        ax.set_xlabel("view angle [deg]")
        ax.set_ylabel("detector pixel")
    image(fig.add_subplot(grid[1, 2]), fbp_eta, "FBP of y_eta (no motion)", vmin=0, vmax=top)
    image(fig.add_subplot(grid[1, 3]), fbp_meas, "FBP of y (motion artefacts)", vmin=0, vmax=top)
    fig.suptitle(f"{store.path.name}: {geometry.kind} beam, N={geometry.n}, K={geometry.n_angles}, L={geometry.n_det}")
    return _save(fig, out, dpi=100)


#: Reconstructions of a scan's slice that :func:`show_sample` shows next to its FBP.
SCAN_PANELS = 3


def _show_scan(store: DataStore, index: int, out: str | os.PathLike[str]) -> Path:
    """:func:`show_sample` for a slice of an imported scan."""
    from matplotlib.figure import Figure

    sinogram = store.read_sample(index).sinogram
    geometry = store.geometry
    names = [name for name in store.reconstruction_names() if store.recons.done(name, [index])[0]]
    images = [(f"{name} (store)", store.read_reconstruction(name, [index])[0]) for name in names[:SCAN_PANELS]]
    images.insert(
        0, (f"FBP, axis {geometry.center_offset:+.2f} px, no motion correction", fbp(geometry, sinogram).image)
    )
    fig = Figure(figsize=(4.2 * (1 + len(images)), 4.4), layout="constrained")
    axes = fig.subplots(1, 1 + len(images), squeeze=False)[0]
    deg = np.rad2deg(geometry.angles)
    extent = (0, sinogram.shape[0], geometry.n_det - 0.5, -0.5)
    im = axes[0].imshow(sinogram.T, cmap="gray", extent=extent, aspect="auto", interpolation="nearest")
    axes[0].set_title(f"measured sinogram, {deg.min():.1f} to {deg.max():.1f} deg", fontsize=10)
    axes[0].set_xlabel("view (acquisition order)")
    axes[0].set_ylabel("detector pixel")
    fig.colorbar(im, ax=axes[0], shrink=0.8)
    for ax, (title, image) in zip(axes[1:], images):
        low, high = np.percentile(image, [0.5, 99.5])
        im = ax.imshow(image, cmap="gray", vmin=low, vmax=high, interpolation="nearest")
        ax.set_title(title, fontsize=10)
        fig.colorbar(im, ax=ax, shrink=0.8)
    more = f"; {len(names) - SCAN_PANELS} more reconstructions not shown" if len(names) > SCAN_PANELS else ""
    fig.suptitle(
        f"{store.path.name}: measured slice {index} of {store.n}, K={geometry.n_angles}, L={geometry.n_det}, "
        f"N={geometry.n} (no ground truth{more})"
    )
    return _save(fig, out, dpi=100)


def compare_reconstructions(
    store: DataStore, names: list[str], indices: list[int], out: str | os.PathLike[str]
) -> Path:
    """Figure: ground truth and each reconstruction (top) with its difference image (below).

    One block of two rows per sample; columns are the ground truth followed by ``names``.
    Titles carry each image's PSNR/SSIM.
    """
    from matplotlib.figure import Figure

    from .metrics import psnr, ssim

    gts = store.read_phantoms(indices)
    recos = {name: store.read_reconstruction(name, indices) for name in names}
    cols = len(names) + 1
    fig = Figure(figsize=(2.6 * cols, 2.5 * 2 * len(indices)), layout="constrained")
    axes = fig.subplots(2 * len(indices), cols, squeeze=False)
    for row, (index, gt) in enumerate(zip(indices, gts)):
        top, bottom = axes[2 * row], axes[2 * row + 1]
        top[0].imshow(gt, cmap="gray", vmin=0, vmax=1)
        top[0].set_title(f"ground truth #{index}", fontsize=9)
        bottom[0].axis("off")
        for col, name in enumerate(names, start=1):
            reco = recos[name][row]
            top[col].imshow(reco, cmap="gray", vmin=0, vmax=1)
            top[col].set_title(f"{name}\n{psnr(reco, gt):.1f} dB / {ssim(reco, gt):.3f}", fontsize=8)
            im = bottom[col].imshow(reco - gt, cmap="RdBu_r", vmin=-0.3, vmax=0.3)
            bottom[col].set_title(f"{name} - gt", fontsize=8)
        fig.colorbar(im, ax=bottom[-1], shrink=0.8)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    return _save(fig, out, dpi=90)


def uncertainty_maps(store: DataStore, names: list[str], indices: list[int], out: str | os.PathLike[str]) -> Path:
    """Figure like the paper's uncertainty figures: per (model, sample) the input, mean, absolute error and std.

    One row per (name, sample). The input is ``reconstructions/<input>`` of the name
    (:func:`nanoct.names.parse_name`; an empty panel if absent); the last panel is the half-width
    of the calibrated 90 % interval (:func:`nanoct.evaluation.conformal.half_width` of the stored
    std; the stored std itself where the result has no calibration). Error and
    half-width share a colour scale per row so they can be compared directly.
    """
    from matplotlib.figure import Figure

    gts = store.read_phantoms(indices)
    present = set(store.reconstruction_names())
    rows = [(name, i, gt) for name in names for i, gt in zip(indices, gts)]
    fig = Figure(figsize=(10.4, 2.5 * len(rows)), layout="constrained")
    axes = fig.subplots(len(rows), 4, squeeze=False)
    for ax_row, (name, index, gt) in zip(axes, rows):
        input_name = str(store.reconstruction_params(name).get("input") or parse_name(name)[0])
        reco = store.read_reconstruction(name, [index])[0]
        std = store.read_uncertainty(name, [index])[0]
        params = store.reconstruction_params(name)
        levels = (params.get("calibration") or {}).get("levels") or {}
        level = "0.9" if "0.9" in levels else next(iter(levels), None)
        if level is not None:
            std = half_width(params, std, float(level), mean=reco)
        err = np.abs(reco - gt)
        top = float(max(err.max(), std.max())) or 1.0
        if input_name in present and input_name != name:
            ax_row[0].imshow(store.read_reconstruction(input_name, [index])[0], cmap="gray", vmin=0, vmax=1)
        ax_row[0].set_title(f"input {input_name} #{index}", fontsize=9)
        ax_row[1].imshow(reco, cmap="gray", vmin=0, vmax=1)
        ax_row[1].set_title(f"{name} (mean)", fontsize=9)
        ax_row[2].imshow(err, cmap="magma", vmin=0, vmax=top)
        ax_row[2].set_title("|mean - gt|", fontsize=9)
        im = ax_row[3].imshow(std, cmap="magma", vmin=0, vmax=top)
        label = "std" if level is None else f"{float(level):.0%} interval half-width"
        ax_row[3].set_title(label, fontsize=9)
        fig.colorbar(im, ax=ax_row[3], shrink=0.8)
        for ax in ax_row:
            ax.set_xticks([])
            ax.set_yticks([])
    return _save(fig, out, dpi=80)


def reliability_diagram(
    store: DataStore,
    panels: dict[str, list[str]],
    indices: list[int] | np.ndarray,
    out: str | os.PathLike[str],
    levels: np.ndarray = RELIABILITY_LEVELS,
) -> Path:
    """Reliability diagram: observed vs nominal coverage, of the stored std read as a Gaussian and of the intervals.

    One column per panel (e.g. per model), one line per reconstruction name. Top row: the stored
    std read as a Gaussian std (interval of level p ``|err| <= k_p std``, ``k_p`` the two-sided
    Gaussian quantile, :func:`nanoct.evaluation.metrics.reliability`); bottom row: the calibrated intervals
    (:func:`nanoct.evaluation.conformal.half_width`) at their levels, with the coverage guaranteed on the validation
    split (open markers). Pixels of all ``indices`` are pooled. On the diagonal a map is
    calibrated; above it too wide, below too narrow.
    """
    from matplotlib.figure import Figure

    gts = store.read_phantoms(indices).astype(np.float64)
    kinds = ("stored std as a Gaussian std", "calibrated intervals (open: guaranteed)")
    fig = Figure(figsize=(3.2 * len(panels), 6.2), layout="constrained")
    axes = fig.subplots(len(kinds), len(panels), squeeze=False, sharex=True, sharey=True)
    for col, (title, names) in enumerate(panels.items()):
        for name in names:
            mean = store.read_reconstruction(name, indices)
            err = np.abs(mean - gts)
            std = store.read_uncertainty(name, indices).astype(np.float64)
            line = axes[0, col].plot(levels, reliability(err, std, levels), marker=".", label=name)[0]
            params = store.reconstruction_params(name)
            cal = (params.get("calibration") or {}).get("levels") or {}
            nominal = [float(k) for k in cal]
            observed = [float(np.mean(err <= half_width(params, std, float(k), mean=mean))) for k in cal]
            axes[1, col].plot(nominal, observed, marker="o", color=line.get_color(), label=name)
            guaranteed = [v["guaranteed_coverage"] for v in cal.values()]
            axes[1, col].plot(nominal, guaranteed, ls="none", marker="o", mfc="none", color=line.get_color())
        for row, kind in enumerate(kinds):
            ax = axes[row, col]
            ax.plot([0, 1], [0, 1], color="0.5", ls="--", lw=1)
            ax.set_title(f"{title}: {kind}", fontsize=9)
            ax.set_xlim(0, 1)
            ax.set_ylim(0, 1.01)
            ax.grid(alpha=0.3)
            ax.set_xlabel("nominal coverage")
        axes[0, col].legend(fontsize=7, loc="lower right")
    for row in range(len(kinds)):
        axes[row, 0].set_ylabel("observed coverage")
    return _save(fig, out, dpi=90)


def _read_log(path: Path, column: str) -> tuple[list[float], list[float]]:
    """(epochs, values of ``column``) of a training log.csv; empty lists if absent or without that column."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError:
        return [], []
    pairs = [(float(r["epoch"]), float(r[column])) for r in rows if r.get(column) not in (None, "")]
    return [e for e, _ in pairs], [v for _, v in pairs]


def training_curves(
    panels: dict[str, dict[str, str | os.PathLike[str]]],
    out: str | os.PathLike[str],
    column: str = "val_loss",
) -> Path:
    """Validation loss per epoch of training runs, from each run's ``log.csv``.

    ``panels`` maps a panel title (e.g. the model) to ``{line label: run directory}``; runs
    without a log (or without ``column``) are left out of their panel. For the invertible
    networks ``val_nll_bpd`` is the validation negative log-likelihood; their ``val_loss`` adds
    the location term of a network trained with ``location_weight``.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3.4 * len(panels), 3.0), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, (title, runs) in zip(axes, panels.items()):
        for label, run in runs.items():
            epochs, values = _read_log(Path(run) / "log.csv", column)
            if epochs:
                ax.plot(epochs, values, marker=".", label=label)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    axes[0].set_ylabel(f"{column} (log.csv)")
    return _save(fig, out, dpi=90)


def uncertainty_report(
    store: DataStore,
    results: dict[str, dict[str, Any]],
    models: list[str],
    inputs: list[str],
    runs_dir: str | os.PathLike[str],
    report_dir: str | os.PathLike[str],
    split: str = "test",
) -> str:
    """The uncertainty part of a study's report: its table and three figures; returns the Markdown.

    For each sampling model in ``models`` (applied to ``inputs``, runs at
    ``<runs_dir>/<model>-<input>``): ``uncertainty_<model>.png`` (:func:`uncertainty_maps` of
    the first ``split`` sample, one row per input), one ``reliability.png`` (:func:`reliability_diagram`, all
    ``split`` samples) and one ``training_curves.png`` (validation NLL per epoch). Names not in
    ``results`` (incomplete) are left out; an empty string when no model has a std.
    """
    report = Path(report_dir)
    names = {
        m: [prediction_name(i, m) for i in inputs if "uncertainty" in results.get(prediction_name(i, m), {})]
        for m in models
    }
    names = {m: n for m, n in names.items() if n}
    if not names:
        return ""
    idx = store.indices(split)
    text = ["## Uncertainty", "", format_uncertainty_table(results, f"Pixel-wise std and intervals, split '{split}'")]
    for m, ns in names.items():
        uncertainty_maps(store, ns, [int(idx[0])], report / f"uncertainty_{m}.png")
        text.append(f"### {m}: input, mean, |error|, 90 % half-width\n\n![{m}](uncertainty_{m}.png)\n")
    reliability_diagram(store, names, idx, report / "reliability.png")
    text.append("### Reliability diagram (stored std, calibrated intervals)\n\n![reliability](reliability.png)\n")
    runs = {m: {i: Path(runs_dir) / f"{m}-{i}" for i in inputs} for m in names}
    training_curves(runs, report / "training_curves.png", column="val_nll_bpd")
    text.append("### Validation NLL per epoch\n\n![training curves](training_curves.png)\n")
    return "\n".join(text)
