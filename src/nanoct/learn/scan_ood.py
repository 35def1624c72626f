"""An out-of-distribution statistic of the measured data: the scan's apparent motion, no network.

The centroid of every view of a parallel-beam sinogram, minus its least-squares fit on
``(1, cos phi, sin phi)`` (:func:`nanoct.motion.center.centroid_motion`), is the object's motion
along the detector per view. Two features describe it (:func:`scan_features`):

- ``jitter``: the view-to-view noise, ``1.4826 * MAD(second differences) / sqrt(6)`` (the std of
  white noise; sinusoids of a few views per period add to it, slow ones hardly);
- ``low``: the rest of the motion, ``sqrt(max(rms^2 - jitter^2, 0))`` (the damped sinusoids).

Both scale with the motion amplitude. The score of a scan (:func:`scan_scores`) is the sum of
the logs of its features over the reference median (larger = more motion than usual); its
conformal p-value against the scores of the data set's train and validation samples
(:func:`scan_reference`, stored with the calibration) flags scans that move more than the
training data did. The statistic does not depend on the network, so the reference can use
many more samples than the validation split.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..io.store import DataStore
from ..motion.center import centroid_motion

__all__ = [
    "SCAN_REFERENCE_MAX",
    "SCAN_STATISTIC",
    "scan_features",
    "scan_reference",
    "scan_scores",
    "store_scan_scores",
]

#: Name of the statistic in the calibration and in the note ``ood``.
SCAN_STATISTIC = "scan_motion"
#: At most this many train and validation samples (evenly spread) form the reference.
SCAN_REFERENCE_MAX = 1000
#: Floor of a feature in pixels (a static scan's features are 0; the log needs a positive value).
_FLOOR = 1e-6
_READ_CHUNK = 100


def scan_features(sinograms: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """The apparent-motion features ``(low, jitter)`` of each sinogram, in detector pixels.

    Parameters
    ----------
    sinograms : ndarray of shape (n, K, L)
        Measured line integrals, one sinogram per sample.
    angles : ndarray of shape (K,)
        View angles in radians.

    Returns
    -------
    ndarray of shape (n, 2), float64
        Per sample the low-frequency RMS and the jitter of the detector-direction motion (see the
        module docstring), each at least 1e-6.
    """
    sinograms = np.asarray(sinograms)
    out = np.empty((len(sinograms), 2))
    for j, sino in enumerate(sinograms):
        _, d, _ = centroid_motion(sino, angles)
        d2 = np.diff(d, 2)
        jitter = 1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0) if d2.size else 0.0
        low = np.sqrt(max(float(np.mean(d**2)) - jitter**2, 0.0))
        out[j] = (low, jitter)
    return np.maximum(out, _FLOOR)


def scan_scores(features: np.ndarray, median: list[float] | np.ndarray) -> np.ndarray:
    """The score of each scan: ``sum_c log(feature_c / median_c)`` (larger = more motion).

    Parameters
    ----------
    features : ndarray of shape (n, 2)
        :func:`scan_features`.
    median : array_like of shape (2,)
        The reference's median features.
    """
    return np.log(np.asarray(features, np.float64) / np.asarray(median, np.float64)).sum(axis=1)


def _features_of(store: DataStore, indices: np.ndarray) -> np.ndarray:
    angles = store.geometry.angles
    parts = [
        scan_features(store.read_array("sinograms", indices[s : s + _READ_CHUNK]), angles)
        for s in range(0, indices.size, _READ_CHUNK)
    ]
    return np.concatenate(parts) if parts else np.empty((0, 2))


def store_scan_scores(store: DataStore, indices: np.ndarray, reference: dict[str, Any]) -> np.ndarray:
    """:func:`scan_scores` of the measured sinograms of ``indices`` against a :func:`scan_reference`."""
    return scan_scores(_features_of(store, np.asarray(indices)), reference["median"])


def scan_reference(store: DataStore, max_samples: int = SCAN_REFERENCE_MAX) -> dict[str, Any] | None:
    """The reference of the scan statistic: the train and validation samples of ``store``.

    At most ``max_samples`` of them, evenly spread over the index range, are used.

    Returns
    -------
    dict or None
        ``statistic`` = "scan_motion", ``n_samples``, ``median`` (the median features) and
        ``scores`` (the samples' :func:`scan_scores`, sorted); None if the store has no train or
        validation sample.
    """
    pool = np.union1d(store.indices("train"), store.indices("val"))
    if pool.size == 0:
        return None
    if pool.size > max_samples:
        pool = pool[np.linspace(0, pool.size - 1, max_samples).round().astype(int)]
    features = _features_of(store, pool)
    median = np.median(features, axis=0)
    return {
        "statistic": SCAN_STATISTIC,
        "n_samples": int(pool.size),
        "median": median.tolist(),
        "scores": sorted(scan_scores(features, median).tolist()),
    }
