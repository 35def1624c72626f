"""Figures of a data set (matplotlib, Agg backend, written to files)."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from .fileio import atomic_write_bytes
from .motion import plot_motion
from .recon.fbp import fbp
from .store import DataStore

__all__ = ["compare_reconstructions", "show_sample", "uncertainty_maps"]


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
    difference; FBP of the unperturbed and of the perturbed data (the motion artefacts).

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

    image(fig.add_subplot(grid[0, 0]), sample.phantom, f"phantom #{index} ({split_name})", vmin=0, vmax=1)
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
    image(fig.add_subplot(grid[1, 2]), fbp_eta, "FBP of y_eta (no motion)", vmin=0, vmax=1)
    image(fig.add_subplot(grid[1, 3]), fbp_meas, "FBP of y (motion artefacts)", vmin=0, vmax=1)
    fig.suptitle(f"{store.path.name}: {geometry.kind} beam, N={geometry.n}, K={geometry.n_angles}, L={geometry.n_det}")
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
    """Figure like the paper's figure 8: per model, reconstruction, absolute error and std.

    One row per (model, sample); error and std share a colour scale per row so they can be
    compared directly.
    """
    from matplotlib.figure import Figure

    gts = store.read_phantoms(indices)
    rows = [(name, i, gt) for name in names for i, gt in zip(indices, gts)]
    fig = Figure(figsize=(8.4, 2.6 * len(rows)), layout="constrained")
    axes = fig.subplots(len(rows), 3, squeeze=False)
    for ax_row, (name, index, gt) in zip(axes, rows):
        reco = store.read_reconstruction(name, [index])[0]
        std = store.read_uncertainty(name, [index])[0]
        err = np.abs(reco - gt)
        top = float(max(err.max(), std.max())) or 1.0
        ax_row[0].imshow(reco, cmap="gray", vmin=0, vmax=1)
        ax_row[0].set_title(f"{name} #{index}", fontsize=9)
        ax_row[1].imshow(err, cmap="magma", vmin=0, vmax=top)
        ax_row[1].set_title("|reco - gt|", fontsize=9)
        im = ax_row[2].imshow(std, cmap="magma", vmin=0, vmax=top)
        ax_row[2].set_title("pixel-wise std", fontsize=9)
        fig.colorbar(im, ax=ax_row[2], shrink=0.8)
        for ax in ax_row:
            ax.set_xticks([])
            ax.set_yticks([])
    return _save(fig, out, dpi=90)
