"""Out-of-distribution check of predict: conformal p-values of the std level and of the scan's apparent motion."""

from __future__ import annotations

import warnings
from functools import partial

import numpy as np
import pytest

from nanoct.core.geometry import get_preset
from nanoct.io.store import DataStore
from nanoct.learn.calibration import image_statistic, ood_p_values
from nanoct.learn.predict import OutOfDistributionWarning, ood_check
from nanoct.learn.scan_ood import scan_features, scan_reference, scan_scores, store_scan_scores
from nanoct.sim.generate import generate_dataset
from nanoct.sim.simulate import SimulationConfig
from nanoct.study.shift import shift_config


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


def test_ood_check_warns_on_a_shifted_set_and_records_it(tiny_store, monkeypatch):
    """Constructed shift: std levels 1.5 times the validation split's are flagged, in-distribution ones rarely
    (the stds read 5 images at a time, so that the p-values are checked across the chunks' borders)."""
    import nanoct.learn.predict as predict_mod

    monkeypatch.setattr(predict_mod, "OOD_CHUNK", 5)
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
        assert record["statistic"] == "mean_std" and record["std"]["flagged"] == record["flagged"]
        assert record["flagged_by"] == {str(i): ["std"] for i in record["flagged"]}
        flagged[name] = len(record["flagged"]) / store.n
        expected = ood_p_values(image_statistic(store.read_uncertainty(name, everything)), ood["val"])
        assert [record["p_values"][str(i)] for i in everything] == pytest.approx(expected)
    assert flagged["ood_shifted+fake"] >= 0.9 and flagged["ood_same+fake"] <= 0.1
    # a later check of some samples keeps the others' record
    part = ood_check(store, "ood_same+fake", everything[:2])
    assert set(part["p_values"]) == {str(i) for i in everything}
    for name in flagged:
        store.delete_reconstruction(name)


def _footprint_case(tmp_path, **calibration):
    """A scan store and a calibration on one sample's measured pairs (a footprint, fitted on the field of view),
    with ``calibration`` added to it; fresh slices of the sample (mean, std) and its known pixels."""
    from nanoct.core.geometry import Geometry
    from nanoct.io.store import create_scan
    from nanoct.learn.calibration import fit_intervals
    from nanoct.sim.matched import fov_disc

    geometry = Geometry.from_dict({**get_preset("tiny-parallel").to_dict(), "center_offset": 20.0})
    known = fov_disc(geometry) > 0  # radius 25 px of a 63 px image: the corners are outside
    size, n = geometry.n, 20
    store = create_scan(tmp_path / "scan", geometry, np.zeros((8, *geometry.sino_shape)), {"file": "constructed"})
    rng = np.random.default_rng(8)
    yy, xx = np.mgrid[:size, :size] - (size - 1) / 2
    radii = rng.uniform(10, 16, n)
    levels = rng.lognormal(np.log(0.05), 1.0, n)  # slices whose intensity differs by orders of magnitude

    def slices(noise: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        gts = np.stack([(np.hypot(xx, yy) <= r) * v for r, v in zip(radii, levels)])
        gts = gts + noise.normal(0, 1e-3, gts.shape)
        return gts, gts + noise.normal(0, 2e-3, gts.shape), np.abs(noise.normal(2e-3, 5e-4, gts.shape))

    gts, means, stds = slices(rng)
    rule = {"support_source": "relative", "known": known, "object_conditional": True, "footprint": True}
    cal = fit_intervals(means, stds, gts, levels=(0.9,), **rule) | calibration
    _, fresh, fresh_std = slices(np.random.default_rng(9))
    return store, cal, (fresh, fresh_std), known, (xx, yy, levels)


def test_ood_check_flags_images_outside_the_footprint_of_the_calibrating_scan(tmp_path):
    """A calibration on one sample's measured pairs (a footprint, fitted on the field of view): fresh slices of the
    sample pass, also with something beyond the field of view; the sample moved by 12 px is flagged by
    ``footprint`` with the fraction of its support outside the footprint; a later check of one sample, moved back,
    unflags it and keeps the others' record; the std level, the calibration's, flags nothing."""
    from nanoct.evaluation.conformal import decode_mask, footprint_outside

    store, cal, (fresh, fresh_std), known, (xx, yy, levels) = _footprint_case(tmp_path)
    assert not known.all()
    groups = cal["levels"]["0.9"]["groups"]
    assert decode_mask(groups["footprint"]).mean() < 0.5
    name = "footprint+fake"
    store.prepare_reconstruction(name, {"calibration": cal}, uncertainty=True)
    corner = (np.hypot(xx + 28, yy + 28) <= 4) * levels.max()  # outside the field of view
    images = {
        i: fresh[i] + (corner if i == 2 else 0) if i not in (1, 5) else np.roll(fresh[i], 12, axis=1) for i in range(8)
    }
    for i, image in images.items():
        store.write_reconstruction(name, i, image.astype(np.float32), std=fresh_std[i].astype(np.float32))
    everything = np.arange(8)
    with pytest.warns(OutOfDistributionWarning, match="outside the footprint of the scan"):
        record = ood_check(store, name, everything)
    assert store.reconstruction_note(name, "ood") == record
    written = store.read_reconstruction(name, everything), store.read_uncertainty(name, everything)
    expected = footprint_outside(written[1], groups, written[0], known)
    assert [record["footprint"]["outside"][str(i)] for i in everything] == pytest.approx(expected.tolist())
    assert record["footprint"]["flagged"] == record["flagged"] == [1, 5]
    assert record["flagged_by"] == {"1": ["footprint"], "5": ["footprint"]}
    assert "unchecked" not in record["footprint"]  # no sampling recorded: every image is checked
    assert footprint_outside(written[1][2], groups, written[0][2])[0] > 0.02  # the corner, were every pixel counted
    store.write_reconstruction(name, 5, fresh[5].astype(np.float32), std=fresh_std[5].astype(np.float32))
    again = ood_check(store, name, np.array([5]))
    assert again["flagged"] == again["footprint"]["flagged"] == [1] and set(again["flagged_by"]) == {"1"}
    assert set(again["footprint"]["outside"]) == {str(i) for i in everything}


def test_the_footprint_check_skips_a_mean_whose_sampling_noise_makes_its_support(tmp_path):
    """A faint slice averaged over a few independent draws: its support relative to its level is speckle of the
    sampling noise, which leaves the footprint. Its mean's noise (the median std over sqrt(M)) is a large share
    of its level, so it is recorded as unchecked with a warning instead of flagged; the sample moved is still
    flagged. The same images from antithetic pairs (no such noise estimate) are checked and flagged."""
    from nanoct.evaluation.conformal import FOOTPRINT_NOISY_MEAN, mean_noise_ratio

    rng = np.random.default_rng(4)
    for antithetic in (False, True):
        reconstruct = {"n_samples": 4} | ({"antithetic": True} if antithetic else {})
        store, cal, (fresh, _), known, _ = _footprint_case(tmp_path / str(antithetic), n_samples=4,
                                                           reconstruct=reconstruct)  # fmt: skip
        name = "noisy+fake"
        store.prepare_reconstruction(name, {"calibration": cal}, uncertainty=True)
        std = np.full(fresh.shape[1:], 0.004, np.float32)  # the draws' spread; their mean's noise 0.002
        faint = fresh[0] / fresh[0].max() * 0.003 + rng.normal(0, 0.002, std.shape)
        store.write_reconstruction(name, 0, faint.astype(np.float32), std=std)
        moved = np.roll(fresh[1], 12, axis=1)
        store.write_reconstruction(name, 1, moved.astype(np.float32), std=std)
        ratios = mean_noise_ratio(np.stack([std, std]), np.stack([faint, moved]), 4, known)
        assert ratios[0] > FOOTPRINT_NOISY_MEAN > ratios[1]
        if antithetic:
            with pytest.warns(OutOfDistributionWarning):
                record = ood_check(store, name, np.arange(2))
            assert record["footprint"]["flagged"] == [0, 1] and "unchecked" not in record["footprint"]
            continue
        with pytest.warns(UserWarning, match=r"not made on 1 of 2 images .*samples 0\).*--antithetic or more"):
            record = ood_check(store, name, np.arange(2))
        assert record["footprint"]["outside"]["0"] > 0.02  # measured, but not a flag
        assert record["footprint"]["flagged"] == [1] and "footprint" not in record["flagged_by"].get("0", [])
        assert record["footprint"]["unchecked"] == {"0": pytest.approx(ratios[0])}
        # a later check of the other sample keeps the record of the unchecked one
        assert ood_check(store, name, np.array([1]))["footprint"]["unchecked"] == {"0": pytest.approx(ratios[0])}
        # nanoct info (and predict) summarise the note
        from nanoct.cli.output import ood_line

        brief = store.info()["reconstructions"][name]["ood"]
        flagged = store.reconstruction_note(name, "ood")["flagged"]
        assert brief == {"checks": ["std", "footprint"], "checked": 2, "flagged": flagged, "unchecked": [0]}
        assert ood_line(brief) == (
            f"{len(flagged)} of 2 flagged: {', '.join(map(str, flagged))}; checks std, footprint; 1 left out by "
            "footprint (mean too noisy)"
        )


def _moved_profiles(shifts: np.ndarray, n_det: int = 91, width: float = 6.0) -> np.ndarray:
    """A sinogram whose view k is a Gaussian profile centred at detector coordinate ``shifts[k]``."""
    x = np.arange(n_det) - (n_det - 1) / 2
    return np.exp(-((x[None, :] - shifts[:, None]) ** 2) / (2 * width**2))


def test_scan_features_of_constructed_motion():
    """Known jitter and a damped sinusoid along the detector; an object translation (a cos + b sin) is not motion."""
    k = 400
    phi = np.arange(k) * np.pi / k
    rng = np.random.default_rng(11)
    smooth = np.exp(-2 * np.arange(k) / k) * np.sin(2 * np.pi * 4 * np.arange(k) / k)
    jitter = 0.2 * rng.standard_normal(k)
    translation = 3.0 * np.cos(phi) - 2.0 * np.sin(phi) + 1.5
    sinos = np.stack([_moved_profiles(smooth + jitter + translation), _moved_profiles(smooth + jitter)])
    feats = scan_features(sinos, phi)
    rest = smooth - np.linalg.lstsq(np.stack([np.ones(k), np.cos(phi), np.sin(phi)], 1), smooth, rcond=None)[0] @ [
        np.ones(k),
        np.cos(phi),
        np.sin(phi),
    ]
    assert feats[0] == pytest.approx(feats[1], rel=1e-6)
    assert feats[0, 1] == pytest.approx(0.2, rel=0.15)
    assert feats[0, 0] == pytest.approx(np.sqrt(np.mean(rest**2)), rel=0.15)
    # twice the motion: twice each feature, a score of log 4 against the first
    double = scan_features(_moved_profiles(2 * (smooth + jitter))[None], phi)
    assert double[0] == pytest.approx(2 * feats[1], rel=0.02)
    assert scan_scores(double, feats[1]) == pytest.approx([np.log(4)], abs=0.04)
    # a static scan: both features at their floor, far below any moving one
    assert scan_features(_moved_profiles(np.zeros(k))[None], phi)[0] == pytest.approx([1e-6, 1e-6])


@pytest.fixture(scope="module")
def motion_stores(tmp_path_factory):
    """tiny-parallel: a reference set (train + val), fresh in-distribution samples and motion x 1.5 samples."""
    root = tmp_path_factory.mktemp("scan_ood")
    geometry = get_preset("tiny-parallel")
    base = SimulationConfig.for_geometry(geometry)
    make = partial(generate_dataset, geometry=geometry, workers=0, progress=False)
    return {
        "reference": make(root / "ref", n=160, seed=21, config=base, split_fractions=(0.9, 0.1, 0.0)),
        "same": make(root / "same", n=50, seed=22, config=base, split_fractions=(0.0, 0.0, 1.0)),
        "x1.5": make(
            root / "big", n=50, seed=23, config=shift_config("motion_x1.5", base, 1.0), split_fractions=(0.0, 0.0, 1.0)
        ),
    }


@pytest.mark.slow
def test_scan_features_scale_with_the_simulated_motion(motion_stores, tmp_path):
    """The same samples simulated with motion x 1.5 (the same draws, scaled): every feature about x 1.5."""
    store = motion_stores["same"]
    big = generate_dataset(
        tmp_path / "big",
        store.geometry,
        12,
        seed=store.seed,
        config=shift_config("motion_x1.5", SimulationConfig.from_dict(store.meta["simulation"]), 1.0),
        split_fractions=(0.0, 0.0, 1.0),
        workers=0,
        progress=False,
    )
    first = np.arange(12)
    np.testing.assert_allclose(
        big.read_array("motion", first), 1.5 * store.read_array("motion", first), rtol=1e-5, atol=1e-6
    )
    angles = store.geometry.angles
    ratio = scan_features(big.read_array("sinograms", first), angles) / scan_features(
        store.read_array("sinograms", first), angles
    )
    assert np.median(ratio, axis=0) == pytest.approx([1.5, 1.5], rel=0.05)


@pytest.mark.slow
def test_ood_check_flags_more_motion_by_the_scan_statistic(motion_stores):
    """Motion x 1.5 is flagged (>= 90 %) by the scan statistic, fresh in-distribution samples rarely (<= 10 %)."""
    reference = scan_reference(motion_stores["reference"])
    assert reference["n_samples"] == 160 and reference["statistic"] == "scan_motion"
    rng = np.random.default_rng(9)
    val_levels = rng.lognormal(np.log(0.05), 0.1, 20)
    ood = {"statistic": "mean_std", "alpha": 0.05, "val": sorted(val_levels.tolist()), "scan": reference}
    rates = {}
    for key in ("same", "x1.5"):
        store = DataStore.open(motion_stores[key].path, mode="r+")
        name = "scan_check+fake"
        store.prepare_reconstruction(name, {"calibration": {"ood": ood}}, uncertainty=True)
        everything = np.arange(store.n)
        for i in everything:  # std levels of the validation split's distribution: the std check flags nothing
            std = np.full((store.geometry.n,) * 2, rng.lognormal(np.log(0.05), 0.1), np.float32)
            store.write_reconstruction(name, int(i), np.zeros_like(std), std=std)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            record = ood_check(store, name, everything)
        rates[key] = len(record["flagged"]) / store.n
        scan_p = ood_p_values(store_scan_scores(store, everything, reference), reference["scores"])
        assert [record["scan"]["p_values"][str(i)] for i in everything] == pytest.approx(scan_p)
        std_p = [record["std"]["p_values"][str(i)] for i in everything]
        assert [record["p_values"][str(i)] for i in everything] == pytest.approx(
            np.minimum(1, 2 * np.minimum(std_p, scan_p))
        )
        assert record["statistic"] == "mean_std + scan_motion"
        assert record["flagged"] == sorted(int(i) for i in record["flagged_by"])
        assert all(v == ["scan"] for v in record["flagged_by"].values())
        assert record["cannot_flag"] == ["std"]  # 20 validation levels: no p-value below 1/21 > 0.025
        blind = [w for w in caught if w.category is not OutOfDistributionWarning]
        assert len(blind) == 1 and "'std' of reconstructions/scan_check+fake cannot flag" in str(blind[0].message)
        assert "at least 39 validation images" in str(blind[0].message)
        flagged = [w for w in caught if w.category is OutOfDistributionWarning]
        assert len(flagged) == bool(record["flagged"])
        if record["flagged"]:
            assert "sinogram" in str(flagged[0].message)
        store.delete_reconstruction(name)
    assert rates["x1.5"] >= 0.9 and rates["same"] <= 0.1
