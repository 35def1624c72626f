"""Flag rates of the scan out-of-distribution statistic against what the true motion allows.

Simulates tiny-parallel data sets in a temporary folder (no network, no training): a reference
set with the study's motion (train + validation split, the reference of
:func:`nanoct.learn.scan_ood.scan_reference`), fresh in-distribution scans, and one set per
shift of :data:`nanoct.study.shift.SHIFTS`. Prints per set the share flagged by the scan
statistic at ``p <= alpha / 2`` (its share when combined with the std check) and ``p <= alpha``
(alone), and, for motion x 1.5, the share flagged at the threshold that flags 10 % of the
in-distribution scans, for the scan statistic and for statistics of the TRUE simulated motion:

* ``true motion, all components``: sum of the log ratios to the reference median of the three
  jitter stds (t1, t2, theta; the simulated jitter, drawn again from the sample's generator) and
  the RMS of the damped sinusoids in t1 and t2;
* ``true jitter, likelihood ratio``: the Neyman-Pearson statistic of the three drawn jitter stds
  (|N(mu, sigma^2)| against |N(1.5 mu, (1.5 sigma)^2)|);
* ``true detector-direction motion``: the scan features computed from the true motion projected
  on the detector (t1 cos phi + t2 sin phi), detrended as the centroids are.

    PYTHONPATH=src .venv/bin/python benchmarks/ood_scan.py --n-ref 600 --n 400
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from nanoct.core.geometry import get_preset
from nanoct.io.store import DataStore
from nanoct.learn.calibration import OOD_ALPHA, ood_p_values
from nanoct.learn.scan_ood import scan_reference, scan_scores, store_scan_scores
from nanoct.sim.generate import generate_dataset
from nanoct.sim.motion import sample_motion_components
from nanoct.sim.simulate import SimulationConfig, sample_rngs
from nanoct.study.shift import SHIFTS, shift_config


def _detector_features(store: DataStore) -> np.ndarray:
    """The scan features of the true motion along the detector (no sinogram involved)."""
    phi = store.geometry.angles
    basis = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
    out = []
    for t in store.read_array("motion", store.indices("all")).astype(np.float64):
        d = t[:, 0] * np.cos(phi) + t[:, 1] * np.sin(phi)
        d -= basis @ np.linalg.lstsq(basis, d, rcond=None)[0]
        d2 = np.diff(d, 2)
        jitter = 1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0)
        out.append((np.sqrt(max(np.mean(d**2) - jitter**2, 0.0)), jitter))
    return np.maximum(np.array(out), 1e-6)


def _true_components(store: DataStore) -> np.ndarray:
    """Per sample the drawn jitter stds (t1, t2, theta) and the RMS of the sinusoids (t1, t2)."""
    config = SimulationConfig.from_dict(store.meta["simulation"])
    rows = []
    for i in store.indices("all"):
        eps, jitter = sample_motion_components(
            sample_rngs(store.seed, int(i))[1], store.geometry.n_angles, config.motion
        )
        rows.append(np.r_[jitter.std(axis=0), np.sqrt((eps.astype(np.float64) ** 2).mean(axis=0))])
    return np.array(rows)


def _at_ten_percent(inside: np.ndarray, shifted: np.ndarray) -> float:
    """Share of ``shifted`` above the score that 10 % of ``inside`` exceed."""
    return float(np.mean(shifted > np.quantile(inside, 0.9)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-ref", type=int, default=600, help="reference scans (train + validation)")
    parser.add_argument("--n", type=int, default=400, help="scans per test set")
    args = parser.parse_args()
    geometry = get_preset("tiny-parallel")
    base = SimulationConfig.for_geometry(geometry)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)

        def make(name: str, n: int, seed: int, config: SimulationConfig, fractions: tuple) -> DataStore:
            return generate_dataset(
                root / name, geometry, n, seed=seed, config=config, split_fractions=fractions, workers=0, progress=False
            )

        ref_store = make("reference", args.n_ref, 2000, base, (0.9, 0.1, 0.0))
        reference = scan_reference(ref_store)
        y_max = float(ref_store.read_array("sinograms", [0]).max())
        sets = {"in distribution": make("same", args.n, 4000, base, (0.0, 0.0, 1.0))}
        for s in SHIFTS:
            sets[s] = make(s, args.n, 1000, shift_config(s, base, y_max), (0.0, 0.0, 1.0))
        print(f"reference: {reference['n_samples']} scans; test sets: {args.n} scans each")
        print(f"| test set | scan p <= {OOD_ALPHA / 2:g} | scan p <= {OOD_ALPHA:g} |")
        print("|---|---|---|")
        scores = {}
        for name, store in sets.items():
            scores[name] = store_scan_scores(store, store.indices("all"), reference)
            p = ood_p_values(scores[name], reference["scores"])
            print(f"| {name} | {100 * np.mean(p <= OOD_ALPHA / 2):.1f} % | {100 * np.mean(p <= OOD_ALPHA):.1f} % |")

        same, big = sets["in distribution"], sets["motion_x1.5"]
        ref_true, same_true, big_true = (_true_components(s) for s in (ref_store, same, big))
        median = np.median(np.log(ref_true), axis=0)
        mu, sigma = base.motion.jitter_std_mean, base.motion.jitter_std_std

        def ratio(x: np.ndarray) -> np.ndarray:
            s = x[:, :3]
            return (((s - mu) ** 2 - (s / 1.5 - mu) ** 2) / (2 * sigma**2)).sum(axis=1)

        det_median = np.median(_detector_features(ref_store), axis=0)
        rows = {
            "scan statistic (sinogram)": (scores["in distribution"], scores["motion_x1.5"]),
            "true motion, all components": ((np.log(same_true) - median).sum(1), (np.log(big_true) - median).sum(1)),
            "true jitter, likelihood ratio": (ratio(same_true), ratio(big_true)),
            "true detector-direction motion": (
                scan_scores(_detector_features(same), det_median),
                scan_scores(_detector_features(big), det_median),
            ),
        }
        print("\n| statistic | motion x 1.5 flagged at 10 % in-distribution flags |")
        print("|---|---|")
        for name, (inside, shifted) in rows.items():
            print(f"| {name} | {100 * _at_ten_percent(inside, shifted):.1f} % |")


if __name__ == "__main__":
    main()
