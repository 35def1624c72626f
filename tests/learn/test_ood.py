"""Out-of-distribution check of predict: conformal p-values of the std level against the validation split's."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.io.store import DataStore
from nanoct.learn.calibration import image_statistic, ood_p_values
from nanoct.learn.predict import OutOfDistributionWarning, ood_check


def test_p_values_against_a_direct_count():
    ref = [0.1, 0.2, 0.2, 0.4]
    p = ood_p_values([0.05, 0.2, 0.3, 0.5], ref)
    assert p == pytest.approx([5 / 5, 4 / 5, 2 / 5, 1 / 5])  # (1 + #{ref >= value}) / (n + 1)
    assert image_statistic(np.ones((2, 3, 3)) * [[[1.0]], [[2.0]]]) == pytest.approx([1.0, 2.0])


def test_p_values_flag_at_most_alpha_of_exchangeable_images(rng):
    """Exchangeable statistics: the rate of p <= alpha is at most alpha (about 1 / (n + 1) here), over many draws."""
    n_val, trials = 20, 20_000
    draws = rng.lognormal(0, 0.3, (trials, n_val + 1))
    p = np.array([ood_p_values(d[-1:], d[:-1])[0] for d in draws])
    assert np.mean(p <= 0.05) == pytest.approx(1 / (n_val + 1), abs=0.005)


def test_ood_check_warns_on_a_shifted_set_and_records_it(tiny_store):
    """Constructed shift: std levels 1.5 times the validation split's are flagged, in-distribution ones rarely."""
    store = DataStore.open(tiny_store.path, mode="r+")
    rng = np.random.default_rng(5)
    val_levels = rng.lognormal(np.log(0.05), 0.1, 20)
    ood = {"statistic": "mean_std", "alpha": 0.05, "val": sorted(val_levels.tolist())}
    everything = np.arange(store.n)
    flagged = {}
    for name, factor in (("ood_same+fake", 1.0), ("ood_shifted+fake", 1.5)):
        store.prepare_reconstruction(name, {"calibration": {"ood": ood}}, uncertainty=True)
        for i in everything:
            level = factor * rng.lognormal(np.log(0.05), 0.1)
            std = rng.uniform(0.5, 1.5, (store.geometry.n,) * 2).astype(np.float32) * level
            store.write_reconstruction(name, int(i), np.zeros_like(std), std=std)
        if factor == 1.0:
            record = ood_check(store, name, everything)
        else:
            with pytest.warns(OutOfDistributionWarning, match="look out of distribution"):
                record = ood_check(store, name, everything)
        assert store.reconstruction_note(name, "ood") == record
        flagged[name] = len(record["flagged"]) / store.n
        expected = ood_p_values(image_statistic(store.read_uncertainty(name, everything)), ood["val"])
        assert [record["p_values"][str(i)] for i in everything] == pytest.approx(expected)
    assert flagged["ood_shifted+fake"] >= 0.9 and flagged["ood_same+fake"] <= 0.1
    # a later check of some samples keeps the others' record
    part = ood_check(store, "ood_same+fake", everything[:2])
    assert set(part["p_values"]) == {str(i) for i in everything}
    for name in flagged:
        store.delete_reconstruction(name)
