"""Patch training on a measured scan of odd size: CiUNetRes on 64 x 64 patches against whole images, same wall time.

The raw neutron sinogram of ``tests/data/realdata`` (459 views over 360 degrees, 503 columns) is imported
binned by 2 (251 columns: an image size no network was trained on) with its open beam, rings removed and
the axis estimated, and reconstructed by Dremel; a set matched to it (``generate --like``, 400 pairs, paper
shapes, ellipses and the scan's slice as phantoms, the motion statistics of the scan's Dremel estimate)
trains CiUNetRes (the tiny study's architecture, Dremel input) twice:

* ``--patch 64`` for ``--epochs`` epochs (one 64 x 64 patch per image and epoch; validation and the
  the intervals on the validation images predicted in tiles), predicted in 64-pixel tiles (``--tile 0``);
* on the whole 251 x 251 images for ``--full-epochs`` epochs (about the same training time), predicted
  whole.

Both are scored on 40 further matched images (another seed) with ``nanoct evaluate``: PSNR and SSIM
against Dremel, paired per image, and the 90 % intervals' coverage (all pixels, the object). The patch
network then predicts the measured slice (tiled, calibrated on the matched set, with the OOD check) and
``--picture`` draws it. Every step is a resumable ``nanoct`` command, so the kept ``--work`` folder
reruns in seconds.

    PYTHONPATH=src:benchmarks .venv/bin/python benchmarks/patch_training.py --work /tmp/nt --picture docs/img
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from cli_run import cli
from nanoct.io.store import DataStore

REAL = Path(__file__).resolve().parents[1] / "tests" / "data" / "realdata" / "neutron-360-sinogram"
CIUNET = ["--model", "ciunet-res", "--input", "dremel", "--lr", "1e-3", "--param", "blocks_per_scale=1",
          "--param", "conditional_scale=location", "--param", "cond_channels=[16,16,32,32,64]"]  # fmt: skip


def data(work: Path, times: dict[str, float]) -> None:
    """The binned scan and its Dremel (whose joint motion the matched sets take), the matched set and the test
    set, each with its Dremel reconstruction."""
    if not (work / "scan" / "zarr.json").is_file():  # a kept scan is not read and corrected again
        times["import"] = cli("import", REAL / "sinogram_360_neutron_image.tif", "--angles", "0:360", "--open-beam",
                          "--stripes", "all", "--binning", "2", "--center-offset", "auto", "--out", work / "scan",
                          "-q")  # fmt: skip
    times["dremel scan"] = cli("reconstruct", work / "scan", "--method", "dremel", "-q")  # its motion: the sets'
    times["generate"] = cli("generate", "--like", work / "scan", "--n", 400, "--out", work / "matched", "-q")
    times["generate test"] = cli("generate", "--like", work / "scan", "--n", 40, "--seed", 1, "--split-fractions",
                                 "0,0,1", "--out", work / "test", "-q")  # fmt: skip
    for store in ("matched", "test"):
        times[f"dremel {store}"] = cli("reconstruct", work / store, "--method", "dremel", "-q")


def networks(work: Path, args: argparse.Namespace, times: dict[str, float]) -> None:
    """Train both networks and predict the test set (and the matched set first: the run's calibration)."""
    patch, full = work / f"run_p{args.patch}", work / f"run_full{args.full_epochs}"
    times["train patch"] = cli("train", work / "matched", *CIUNET, "--epochs", args.epochs, "--patch", args.patch,
                               "--out", patch, "-q")  # fmt: skip
    times["train whole"] = cli("train", work / "matched", *CIUNET, "--epochs", args.full_epochs, "--out", full, "-q")
    for store in ("matched", "test", "scan"):
        times[f"predict patch {store}"] = cli("predict", work / store, "--run", patch, "--tile", 0, "-q")
    for store in ("matched", "test"):
        times[f"predict whole {store}"] = cli("predict", work / store, "--run", full, "--name", "whole", "-q")


def scores(work: Path) -> dict[str, dict[str, Any]]:
    """PSNR / SSIM (mean, and the mean paired difference to Dremel with its standard error) and 90 % coverage."""
    cli("evaluate", work / "test")
    report = json.loads((work / "test" / "report" / "evaluation.json").read_text())["results"]
    dremel = report["dremel"]
    out = {}
    for name, label in (
        ("dremel", "Dremel"),
        ("dremel+ciunet-res", "+ CiUNetRes, patches"),
        ("whole", "+ CiUNetRes, whole"),
    ):
        row = report[name]
        row_out = {"psnr": row["psnr_mean"], "ssim": row["ssim_mean"]}
        for key in ("psnr", "ssim"):
            diff = np.asarray(row[f"{key}_values"]) - np.asarray(dremel[f"{key}_values"])
            row_out[f"{key}_diff"], row_out[f"{key}_se"] = diff.mean(), diff.std(ddof=1) / np.sqrt(diff.size)
        for group in ("all", "support"):
            intervals = (row.get("uncertainty") or {}).get(group, {}).get("intervals", {}).get("0.9")
            if intervals:
                row_out[f"coverage {group}"] = intervals["coverage"]
                row_out[f"fifths {group}"] = [min(intervals["coverage_by_width"]), max(intervals["coverage_by_width"])]
        out[label] = row_out
    return out


def picture(work: Path, folder: Path) -> Path:
    """The measured slice: Dremel, the patch network's tiled mean and its std."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    store = DataStore.open(work / "scan")
    images = [store.read_reconstruction("dremel", [0])[0], store.read_reconstruction("dremel+ciunet-res", [0])[0],
              store.read_uncertainty("dremel+ciunet-res", [0])[0]]  # fmt: skip
    titles = ["Dremel", "+ CiUNetRes (64-px patches, tiled)", "its std"]
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.9))
    top = float(np.percentile(images[0], 99.9))
    for ax, image, title in zip(axes, images, titles):
        shown = ax.imshow(image, cmap="gray", vmin=0, vmax=top if title != "its std" else None)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
        fig.colorbar(shown, ax=ax, fraction=0.046)
    fig.suptitle("measured neutron slice (459 views, 251 binned columns)", fontsize=10)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "neutron_patch.png"
    fig.savefig(path, dpi=90, bbox_inches="tight")
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--patch", type=int, default=64)
    p.add_argument("--epochs", type=int, default=32)
    p.add_argument("--full-epochs", type=int, default=4)
    p.add_argument("--picture", type=Path)
    args = p.parse_args()
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    data(args.work, times)
    networks(args.work, args, times)
    for label, row in scores(args.work).items():
        print(f"{label:22s} PSNR {row['psnr']:.2f} dB ({row['psnr_diff']:+.2f} ± {row['psnr_se']:.2f} to Dremel), "
              f"SSIM {row['ssim']:.3f} ({row['ssim_diff']:+.3f} ± {row['ssim_se']:.3f})")  # fmt: skip
        for group in ("all", "support"):
            if f"coverage {group}" in row:
                low, high = row[f"fifths {group}"]
                print(f"{'':22s} 90 % intervals, {group}: {100 * row[f'coverage {group}']:.1f} % "
                      f"(width fifths {100 * low:.1f}-{100 * high:.1f} %)")  # fmt: skip
    for run in (f"run_p{args.patch}", f"run_full{args.full_epochs}"):
        log = (args.work / run / "log.csv").read_text().splitlines()[1:]
        seconds = [float(line.split(",")[-1]) for line in log]
        print(f"{run}: {len(seconds)} epochs, {sum(seconds):.0f} s of epochs (median {np.median(seconds):.1f} s)")
    if args.picture is not None:
        print("picture:", picture(args.work, args.picture))
    print("seconds:", json.dumps(times), f"total {time.perf_counter() - t0:.0f}")


if __name__ == "__main__":
    main()
