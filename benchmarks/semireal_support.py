"""The semi-real run without measured pairs: its phantom-calibrated intervals with the std's and the mean's support.

Usage::

    PYTHONPATH=src:benchmarks python benchmarks/semireal_support.py [--n 2500] [--epochs 32] [--seed 0] --work DIR

The run "without" of ``benchmarks/semireal_networks.py`` (``--mix 0.4,0.2,0.4``: the paper's
shapes, ellipses and the scan's own slices, no measured pairs), CiUNetRes only, each step one CLI
command (resumed in a kept ``--work`` folder): the moved I13 24737 scan, ``nanoct stack``, ``nanoct
generate --like``, Dremel on the matched set, ``nanoct train`` of CiUNetRes, the binned moved scan
and its Dremel, ``nanoct predict`` on the matched set's validation split (the calibration, 16
antithetic samples) and on the scan. The calibration is then fitted again on the same validation
predictions with the object's support found in the network's std and in its mean (the delivered
default, :func:`nanoct.learn.calibration.fit_intervals`), and both are scored on the scan against
the unmoved scan's reconstruction: 90 % coverage of the object and of the background in the
field of view, registered, mean over the evaluated slices, as ``semireal_networks.py`` scores it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import semireal_networks as sr
from cli_run import cli
from nanoct.evaluation.conformal import half_width
from nanoct.io.store import DataStore
from nanoct.learn.calibration import fit_intervals

NAME = "dremel+ciunet-res"


def prepare(work: Path, args: argparse.Namespace, proj: np.ndarray, angles: np.ndarray) -> dict[str, float]:
    """The stores, the network and its predictions (each step a CLI command, as ``semireal_networks.py`` runs it);
    their seconds."""
    sr.build_stores(work, proj, sr.move(proj, *sr.known_motion(proj.shape[0])), angles)
    t: dict[str, float] = {}
    matched, run = sr.matched_set(work, args.n, "0.4,0.2,0.4", [], t), work / "run_ciunet"
    t["train"] = sr.train_ciunet(matched, run, args.epochs, "auto", args.seed)
    real = sr.binned_scan(work, t)
    sampling = ("--samples", 16, "--antithetic", "-q")
    t["calibrate"] = cli("predict", matched, "--run", run, "--split", "val", *sampling)
    t["predict"] = cli("predict", real, "--run", run, *sampling)
    return t


def scored(work: Path, proj: np.ndarray, angles: np.ndarray, slices: list[int]) -> dict[str, dict]:
    """Coverage on the scan per support (std, mean); the delivered intervals must equal the mean's refit."""
    matched, store = DataStore.open(work / "matched"), DataStore.open(work / "moved_bin2")
    val = matched.indices("val")
    vm, vs = matched.read_reconstruction(NAME, val), matched.read_uncertainty(NAME, val)
    gts = matched.read_phantoms(val)
    mean, std = store.read_reconstruction(NAME, slices), store.read_uncertainty(NAME, slices)
    refs, g_ref = sr.reference(proj, angles, matched.geometry)
    noise, disc = sr.reference_noise(proj, g_ref), sr.fov(g_ref)
    scores = [sr.score(mean[i], refs[s], disc) for i, s in enumerate(slices)]
    objs = [sr.object_mask(refs[s], disc) for s in slices]
    out = {}
    for source in ("std", "mean"):
        hw = half_width({"calibration": fit_intervals(vm, vs, gts, levels=(0.9,), support_source=source)}, std, 0.9,
                        mean=mean)  # fmt: skip
        if source == "mean" and not np.array_equal(
            hw, half_width(store.reconstruction_params(NAME), std, 0.9, mean=mean)
        ):
            raise SystemExit("the delivered intervals differ from the mean's refit")
        cov = [sr.coverage(mean[i], hw[i], refs[s], disc, scores[i]["shift"], noise[s]) for i, s in enumerate(slices)]
        out[source] = {
            "object": float(np.mean([c["object_reg"] for c in cov])),
            "background": float(np.mean([c["background_reg"] for c in cov])),
            "width_object": float(np.mean([np.median(2 * hw[i][o]) for i, o in enumerate(objs)])),
            "width_background": float(np.mean([np.median(2 * hw[i][disc & ~o]) for i, o in enumerate(objs)])),
            "object_per_slice": [round(c["object_reg"], 3) for c in cov],
        }
    dremel = store.read_reconstruction("dremel", slices)
    gain = [scores[i]["psnr_reg"] - sr.score(dremel[i], refs[s], disc)["psnr_reg"] for i, s in enumerate(slices)]
    out["psnr_gain_registered"] = {"mean": float(np.mean(gain)), "worst": min(gain), "best": max(gain)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=2500)
    parser.add_argument("--epochs", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0, help="nanoct train --seed")
    parser.add_argument("--slices", default=",".join(str(s) for s in range(15, 61, 5)))
    parser.add_argument("--work", required=True, help="the stores and the run (a kept folder: the steps resume)")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    proj, angles = sr.load_scan()
    seconds = prepare(work, args, proj, angles)
    print("seconds: " + ", ".join(f"{k} {v:.0f}" for k, v in seconds.items()))
    result = scored(work, proj, angles, [int(s) for s in args.slices.split(",")])
    print("CiUNetRes 90 %, calibrated on the matched set's validation split, registered, mean over the slices:")
    for source in ("std", "mean"):
        r = result[source]
        print(f"  support from the {source}: object {r['object']:.3f}, background {r['background']:.3f}; median width "
              f"object {r['width_object']:.4f}, background {r['width_background']:.4f}; object per slice "
              f"{r['object_per_slice']}")  # fmt: skip
    g = result["psnr_gain_registered"]
    print(
        f"CiUNetRes - Dremel, registered PSNR: mean {g['mean']:+.2f} dB, worst {g['worst']:+.2f}, best {g['best']:+.2f}"
    )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
