"""Calibration of a sampling network's std: fitted on validation data only, cached, applied by predict."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest
import torch
from scipy import ndimage

import nanoct.learn.calibration as cal_mod
import nanoct.learn.predict as predict_mod
from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset
from nanoct.evaluation.conformal import (
    apply_width_map,
    decode_mask,
    fit_group_intervals,
    fit_width_map,
    group_labels,
    half_width,
    support_of,
)
from nanoct.evaluation.metrics import interval_scores, support_mask, truth_support
from nanoct.io.store import DataStore, create_scan
from nanoct.learn.calibration import (
    CALIBRATION_FILE,
    CALIBRATION_FORMAT,
    calibrate,
    fit_intervals,
    load_calibration,
)
from nanoct.learn.checkpoint import load_checkpoint, model_from_checkpoint
from nanoct.learn.predict import predict
from nanoct.learn.scan_ood import scan_reference
from nanoct.learn.train import TrainConfig, train
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset

pytestmark = pytest.mark.usefixtures("one_thread")

SMALL = dict(
    n_scales=3,
    blocks_per_scale=1,
    fc_dim=8,
    fc_blocks=1,
    cond_channels=4,
    cond_width=4,
    fc_cond_dim=8,
    hidden_ratio=1.0,
)
M = {"n_samples": 4}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("calibration")
    path = root / "tiny"
    generate_dataset(
        path, get_preset("tiny-parallel"), 12, seed=7, workers=0, progress=False, split_fractions=(0.5, 0.25, 0.25)
    )
    reconstruct_dataset(path, "fbp", workers=0, progress=False)
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        run = train(
            path,
            root / "run",
            TrainConfig("cinn-res", "fbp", epochs=1, batch_size=2, model_kwargs=SMALL),
            progress=False,
        )
    finally:
        torch.set_num_threads(n)
    return path, run


def _copy(setup, tmp_path):
    """A private copy of the data set (its arrays may be altered) and of the run."""
    path, run = setup
    shutil.copytree(path, tmp_path / "data")
    shutil.copytree(run, tmp_path / "run")
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    config["store"] = str((tmp_path / "data").resolve())  # the copy is the run's own data set
    (tmp_path / "run" / "config.json").write_text(json.dumps(config))
    return tmp_path / "data", tmp_path / "run"


def _order_statistic(scores: np.ndarray, key: str) -> float:
    ratio = np.sort(np.asarray(scores).ravel())
    return float(ratio[int(np.ceil((ratio.size + 1) * float(key))) - 1])


def _check_groups(entry, err, std, mean, gts):
    """The support rule (on the mean) and the object's std fifths, recomputed by hand; returns the pixels' groups."""
    from scipy import ndimage

    rule, cuts = entry["support"], entry["cuts"]
    assert rule["source"] == "mean" and rule["radius"] == 2 and rule["fill"] is True
    disk = np.add.outer(np.arange(-2, 3) ** 2, np.arange(-2, 3) ** 2) <= 4

    def support_at(t):
        return np.stack([ndimage.binary_dilation(ndimage.binary_fill_holes(m > t), structure=disk) for m in mean])

    support = support_at(rule["threshold"])
    truth = np.stack([ndimage.binary_dilation(g > 0, structure=disk) for g in gts])
    iou = (support & truth).sum() / (support | truth).sum()
    for t in np.quantile(mean, np.linspace(0.5, 0.995, 64)):  # the threshold of the best match
        other = support_at(t)
        assert (other & truth).sum() / (other | truth).sum() <= iou + 1e-12
    np.testing.assert_allclose(cuts, np.quantile(std[support], [0.2, 0.4, 0.6, 0.8]), rtol=1e-5)
    labels = np.where(support, 1 + np.searchsorted(cuts, std, side="right"), 0)
    for fit in entry["levels"].values():
        assert fit["groups"]["n_pixels"] == np.bincount(labels.ravel(), minlength=6).tolist()
    return labels


@pytest.mark.slow
def test_fit_matches_a_direct_computation_and_is_cached(setup, tmp_path, monkeypatch):
    path, run = _copy(setup, tmp_path)
    entry = calibrate(path, run, reconstruct_kwargs=M)
    assert load_calibration(run)["best"] == entry == json.loads((run / CALIBRATION_FILE).read_text())["best"]
    assert entry["n_samples"] == 4 and entry["split"] == "val" and entry["checkpoint"] == "best"
    assert entry["format"] == CALIBRATION_FORMAT == 13 and entry["delta"] == 0.1
    # independent recomputation: the network on each validation image, seeded with its index
    store = DataStore.open(path)
    val = store.indices("val")
    model = model_from_checkpoint(load_checkpoint(run / "best.pt")).eval()
    means, stds = [], []
    for i in val:
        x = torch.from_numpy(store.read_reconstruction("fbp", [i]))[:, None]
        mean, std = model.reconstruct(x, n_samples=4, seed=int(i))
        means.append(mean[0, 0].numpy().astype(np.float64))
        stds.append(std[0, 0].numpy().astype(np.float64))
    mean, std = np.stack(means), np.stack(stds)
    err = np.abs(mean - store.read_phantoms(val))
    assert list(entry["levels"]) == ["0.68", "0.9", "0.95"]
    labels = _check_groups(entry, err, std, mean, store.read_phantoms(val))
    for key, fit in entry["levels"].items():
        pooled = fit["pooled"]  # the one-multiplier calibration, kept for comparison
        ref = fit_width_map(err, std, float(key))
        np.testing.assert_allclose(pooled["map"]["std"], ref["std"], rtol=1e-4)
        np.testing.assert_allclose(pooled["map"]["width"], ref["width"], rtol=1e-3)
        assert pooled["multiplier"] == pytest.approx(_order_statistic(err / apply_width_map(std, pooled["map"]), key))
        assert fit["multiplier"] == pooled["multiplier"]
        # the delivered intervals: per group, the split-conformal order statistic of its region's map
        groups = fit["groups"]
        maps = [fit_width_map(err[region], std[region], float(key)) for region in (labels == 0, labels > 0)]
        base = np.where(labels > 0, apply_width_map(std, maps[1]), apply_width_map(std, maps[0]))
        for g, q in enumerate(groups["multipliers"]):
            assert q == pytest.approx(_order_statistic(err[labels == g] / base[labels == g], key), rel=1e-3)
        half = np.asarray(groups["multipliers"])[labels] * base
        assert fit["val_coverage"] == pytest.approx(np.mean(err <= half), abs=2e-3)
        for g, cov in enumerate(groups["val_coverage"]):
            assert float(key) - 2e-3 <= cov == pytest.approx(np.mean(err[labels == g] <= half[labels == g]), abs=2e-3)
        assert 0 <= fit["guaranteed_coverage"] < fit["val_coverage"]  # three images: a weak guarantee
        assert fit["rcps_multiplier"] is None  # too few images for any guarantee at these levels
    assert entry["ood"]["val"] == pytest.approx(sorted(std.mean(axis=(1, 2))), rel=1e-5)
    scan = scan_reference(store)  # the apparent motion of the train and validation sinograms
    assert entry["ood"]["scan"] == scan and scan["n_samples"] == store.indices("train").size + val.size
    # a second call reuses the stored fit; other sampling arguments, levels or checkpoint file refit
    calls = []
    real = cal_mod.sample_outputs
    monkeypatch.setattr(cal_mod, "sample_outputs", lambda *a, **k: (calls.append(1), real(*a, **k))[1])
    assert calibrate(path, run, reconstruct_kwargs=M) == entry and calls == []
    other = calibrate(path, run, reconstruct_kwargs={"n_samples": 5})
    assert calls == [1] and other["n_samples"] == 5 and other["levels"] != entry["levels"]
    two = calibrate(path, run, reconstruct_kwargs={"n_samples": 5}, levels=(0.5, 0.8))
    assert calls == [1, 1] and list(two["levels"]) == ["0.5", "0.8"]
    ckpt = torch.load(run / "best.pt", weights_only=True)
    ckpt["step"] += 1  # another checkpoint file
    torch.save(ckpt, run / "best.pt")
    refit = calibrate(path, run, reconstruct_kwargs={"n_samples": 5})
    assert calls == [1, 1, 1]
    # an entry of an earlier format is fitted again, not reused
    old = {k: v for k, v in refit.items() if k != "levels"} | {"format": 4}
    (run / CALIBRATION_FILE).write_text(json.dumps({"best": old}))
    assert calibrate(path, run, reconstruct_kwargs={"n_samples": 5}) == refit and calls == [1, 1, 1, 1]
    with pytest.raises(ValueError, match="strictly between 0 and 1"):
        calibrate(path, run, reconstruct_kwargs=M, levels=(0.9, 1.0))


@pytest.mark.slow
def test_fit_reads_validation_data_only(setup, tmp_path):
    path, run = _copy(setup, tmp_path)
    before = calibrate(path, run, reconstruct_kwargs=M)
    store = DataStore.open(path, mode="r+")
    rng = np.random.default_rng(0)
    for split in ("test", "train"):  # wreck the ground truth and the input of every non-validation sample
        for i in store.indices(split):
            store._group["phantoms"][int(i)] = rng.random((63, 63)).astype(np.float32)
            store._group["reconstructions/fbp"][int(i)] = rng.random((63, 63)).astype(np.float32)
    after = calibrate(path, run, reconstruct_kwargs=M, refit=True)
    assert after["levels"] == before["levels"] and after["edge_multipliers"] == before["edge_multipliers"]
    for i in store.indices("val"):  # alter the validation input: the fit changes
        x = store.read_reconstruction("fbp", [int(i)])[0]
        store._group["reconstructions/fbp"][int(i)] = x + 0.05 * rng.standard_normal(x.shape).astype(np.float32)
    changed = calibrate(path, run, reconstruct_kwargs=M, refit=True)
    new, old = changed["levels"]["0.9"]["pooled"]["map"]["width"], before["levels"]["0.9"]["pooled"]["map"]["width"]
    assert new != pytest.approx(old, rel=1e-3)
    # without refit the stored fit is reused, until the input is made again (reconstruct --overwrite: a new id)
    assert calibrate(path, run, reconstruct_kwargs=M) == changed
    store._group["reconstructions/fbp"].attrs["created"] = "made again"
    again = calibrate(path, run, reconstruct_kwargs=M)
    assert again["input_fingerprint"]["created"] == "made again" and again["levels"] == changed["levels"]


@pytest.mark.slow
def test_predict_stores_the_raw_std_and_the_calibration(setup, tmp_path):
    """The stored std is the network's (ranking kept exactly); the intervals are multiples of it."""
    from scipy.stats import spearmanr

    path, run = _copy(setup, tmp_path)
    (run / CALIBRATION_FILE).write_text(json.dumps({"best": {"format": 3, "checkpoint": "best", "scale": 1.0}}))
    name = predict(path, run, progress=False, reconstruct_kwargs=M)  # the old-format entry is refitted
    predict(path, run, progress=False, reconstruct_kwargs=M, name="raw", calibrate=False)
    entry = load_calibration(run)["best"]
    store = DataStore.open(path)
    test = store.indices("test")
    params = store.reconstruction_params(name)
    assert entry["format"] == CALIBRATION_FORMAT and params["calibration"] == entry
    assert "calibration" not in store.reconstruction_params("raw")
    raw, stored = store.read_uncertainty("raw", test), store.read_uncertainty(name, test)
    np.testing.assert_array_equal(stored, raw)
    np.testing.assert_array_equal(store.read_reconstruction(name, test), store.read_reconstruction("raw", test))
    groups = params["calibration"]["levels"]["0.9"]["groups"]
    means = store.read_reconstruction(name, test)
    for one_raw, one_stored, one_mean in zip(raw, stored, means):  # within each group the map ranks as the raw std
        half, labels = half_width(params, one_stored, 0.9, mean=one_mean), group_labels(one_stored, groups, one_mean)
        for g in np.unique(labels):
            if (labels == g).sum() > 2:
                rho = spearmanr(one_raw[labels == g], half[labels == g]).statistic
                assert rho == pytest.approx(1.0, abs=1e-12)
    # export --interval writes exactly these half-widths
    from nanoct.cli import run as cli

    out = str(tmp_path / "hw.npy")
    assert cli(["export", str(path), "--name", name, "--out", out, "--split", "test", "--interval", "0.9"]) == 0
    np.testing.assert_allclose(np.load(tmp_path / "hw.npy"), half_width(params, stored, 0.9, mean=means), rtol=1e-6)
    assert cli(["export", str(path), "--name", "raw", "--out", str(tmp_path / "x.npy"), "--interval", "0.9"]) == 2
    ood = store.reconstruction_note(name, "ood")
    assert set(ood["p_values"]) == {str(int(i)) for i in test} and store.reconstruction_note("raw", "ood") is None
    assert ood["statistic"] == "mean_std + scan_motion" and set(ood["scan"]["p_values"]) == set(ood["p_values"])
    with pytest.raises(NanoctError, match="std calibration"):  # a raw result is not silently mixed with calibrated
        predict(path, run, progress=False, reconstruct_kwargs=M, name="raw")
    with pytest.raises(NanoctError, match="level 0.5"):
        half_width(params, stored, 0.5)
    with pytest.raises(NanoctError, match="too small to guarantee"):
        half_width(params, stored, 0.9, guaranteed=True)
    with pytest.raises(NanoctError, match="no interval calibration"):
        half_width(store.reconstruction_params("raw"), stored, 0.9)


@pytest.mark.slow
def test_bad_input(setup, tmp_path):
    path, run = setup
    no_val = tmp_path / "noval"
    generate_dataset(no_val, get_preset("tiny-parallel"), 4, workers=0, progress=False, split_fractions=(0.5, 0, 0.5))
    with pytest.raises(NanoctError, match="no validation samples"):
        calibrate(no_val, run, reconstruct_kwargs=M)
    with pytest.raises(NanoctError, match="does not exist"):
        calibrate(path, tmp_path, reconstruct_kwargs=M)


def test_a_damaged_calibration_file_is_refused_not_overwritten(tmp_path):
    assert load_calibration(tmp_path) == {}
    for text in ('{"best": {', "[1, 2]"):
        (tmp_path / CALIBRATION_FILE).write_text(text)
        with pytest.raises(NanoctError, match=r"calibration.json are damaged .*delete the file"):
            load_calibration(tmp_path)
        assert (tmp_path / CALIBRATION_FILE).read_text() == text


@pytest.mark.slow
def test_prediction_under_a_refitted_calibration_is_redone(setup, tmp_path):
    """A calibrated result of an older calibration (e.g. format 1) is redone, not refused: the same request."""
    path, run = _copy(setup, tmp_path)
    name = predict(path, run, progress=False, reconstruct_kwargs=M)
    store = DataStore.open(path, mode="r+")
    old = {"format": 1, "checkpoint": "best", "scale": 2.0}  # what an earlier version stored
    params = {**store.reconstruction_params(name), "calibration": old}
    for key in (f"reconstructions/{name}", f"uncertainty/{name}"):
        if key in store._group:
            store._group[key].attrs["params"] = params
    assert store.reconstruction_params(name)["calibration"] == old
    assert predict(path, run, progress=False, reconstruct_kwargs=M) == name
    assert DataStore.open(path).reconstruction_params(name)["calibration"] == load_calibration(run)["best"]


@pytest.mark.slow
def test_a_checkpoint_replaced_while_predict_reads_it_is_refused(setup, tmp_path, monkeypatch):
    """The prediction and its calibration name the bytes each loaded: where ``best.pt`` is replaced between
    the two loads (a training run still writing it), predict stops, writes nothing, and says what to do."""
    path, run = _copy(setup, tmp_path)
    real = predict_mod.calibrate_run

    def replaced_first(*a, **k):
        ckpt = torch.load(run / "best.pt", weights_only=True)
        ckpt["epoch"] = int(ckpt["epoch"]) + 1
        torch.save(ckpt, run / "best.pt")
        return real(*a, **k)

    monkeypatch.setattr(predict_mod, "calibrate_run", replaced_first)
    with pytest.raises(NanoctError, match=r"best.pt was replaced while predict read it.*run the same command again"):
        predict(path, run, progress=False, reconstruct_kwargs=M, name="torn")
    assert "torn" not in DataStore.open(path).reconstruction_names()
    monkeypatch.setattr(predict_mod, "calibrate_run", real)
    assert predict(path, run, progress=False, reconstruct_kwargs=M, name="torn") == "torn"  # the same command
    recorded = DataStore.open(path).reconstruction_params("torn")
    assert recorded["checkpoint_sha256"] == recorded["calibration"]["checkpoint_sha256"]
    assert recorded["epoch"] == load_checkpoint(run / "best.pt")["epoch"]


@pytest.mark.slow
def test_calibrate_on_another_data_set_keeps_both_fits(setup, tmp_path):
    """--calibrate-on: the intervals fitted on another data set's validation split, stored beside the run's own."""
    path, run = _copy(setup, tmp_path)
    own = calibrate(path, run, reconstruct_kwargs=M)
    other = tmp_path / "pairs"
    generate_dataset(other, get_preset("tiny-parallel"), 3, seed=11, workers=0, progress=False,
                     split_fractions=(0.0, 1.0, 0.0))  # fmt: skip
    with pytest.raises(NanoctError, match="has no reconstruction .fbp."):
        predict(path, run, progress=False, reconstruct_kwargs=M, calibrate_on=other)
    reconstruct_dataset(other, "fbp", workers=0, progress=False)
    name = predict(path, run, progress=False, reconstruct_kwargs=M, calibrate_on=other, name="on-other")
    entries = load_calibration(run)
    key = cal_mod.entry_name(run, "best", other)
    assert key == f"best@{other.resolve()}" and cal_mod.entry_name(run, "best", path) == "best"
    assert entries["best"] == own and entries[key]["store"] == str(other.resolve())
    params = DataStore.open(path).reconstruction_params(name)
    assert params["calibration"] == entries[key] == calibrate(other, run, reconstruct_kwargs=M)
    assert entries[key]["levels"] != own["levels"]  # fitted on the other images
    assert entries[key]["ood"]["val"] != own["ood"]["val"]
    # the default prediction still takes the run's own fit, and a refit of one leaves the other
    default = predict(path, run, progress=False, reconstruct_kwargs=M)
    assert DataStore.open(path).reconstruction_params(default)["calibration"] == own
    assert load_calibration(run)[key] == entries[key]
    # the other data set made again at the same path (another seed): another data set, fitted again
    shutil.rmtree(other)
    generate_dataset(other, get_preset("tiny-parallel"), 3, seed=12, workers=0, progress=False,
                     split_fractions=(0.0, 1.0, 0.0))  # fmt: skip
    reconstruct_dataset(other, "fbp", workers=0, progress=False)
    again = calibrate(other, run, reconstruct_kwargs=M)
    assert again["store_meta_sha256"] != entries[key]["store_meta_sha256"] and again["levels"] != entries[key]["levels"]


@pytest.mark.slow
def test_a_tiled_prediction_of_another_image_size_uses_the_runs_own_calibration(setup, tmp_path):
    """--tile on a data set of another image size that has a validation split: the run's own (untiled) fit, made
    on the data set the run was trained on where it is not yet, as for a scan without one; with that data set
    gone from its recorded path, an error that names the ways out, and nothing written. The tiles per batch, on
    which the latent draws depend, are recorded."""
    path, run = _copy(setup, tmp_path)
    big = tmp_path / "big"
    generate_dataset(big, get_preset("small-parallel"), 2, seed=1, workers=0, progress=False,
                     split_fractions=(0, 0.5, 0.5))  # fmt: skip
    reconstruct_dataset(big, "fbp", workers=0, progress=False)
    path.rename(tmp_path / "away")
    with pytest.raises(
        NanoctError, match=r"127x127 images, the run .* 63x63.*config.json.*--calibrate-on .*--no-calib"
    ):
        predict(big, run, progress=False, tile=0, reconstruct_kwargs=M)
    assert DataStore.open(big).reconstruction_names() == ["fbp"]
    (tmp_path / "away").rename(path)
    assert not (run / CALIBRATION_FILE).exists()
    assert predict(big, run, progress=False, tile=0, reconstruct_kwargs=M, batch_size=4) == "fbp+cinn-res"
    params = DataStore.open(big).reconstruction_params("fbp+cinn-res")
    assert params["calibration"] == load_calibration(run)["best"] == calibrate(path, run, reconstruct_kwargs=M)
    assert params["calibration"]["store"] == str(path.resolve())
    assert params["tiling"] == {"size": 63, "overlap": 16, "margin": 2, "batch": 4}
    # an imported scan (no validation split) of the trained size: the same fit
    own = DataStore.open(path)
    scan = create_scan(tmp_path / "scan", own.geometry, own.read_array("sinograms", [0]), scan={"source": "test"})
    reconstruct_dataset(scan.path, "fbp", workers=0, progress=False)
    predict(scan.path, run, progress=False, reconstruct_kwargs=M)
    assert DataStore.open(scan.path).reconstruction_params("fbp+cinn-res")["calibration"] == params["calibration"]
    # another data set made at the run's recorded path (another seed) is not the one it was trained on: not fitted
    # on; the scan keeps the run's own fit, and a new request without one is refused
    shutil.rmtree(path)
    generate_dataset(path, get_preset("tiny-parallel"), 12, seed=8, workers=0, progress=False,
                     split_fractions=(0.5, 0.25, 0.25))  # fmt: skip
    reconstruct_dataset(path, "fbp", workers=0, progress=False)
    assert predict(scan.path, run, progress=False, reconstruct_kwargs=M, name="again") == "again"
    assert DataStore.open(scan.path).reconstruction_params("again")["calibration"] == params["calibration"]
    with pytest.raises(NanoctError, match=r"no validation samples .*config.json.*--calibrate-on"):
        predict(scan.path, run, progress=False, reconstruct_kwargs={"n_samples": 5}, name="other-m")


def test_calibrate_on_is_checked_before_any_work(setup, tmp_path):
    path, run = _copy(setup, tmp_path)
    with pytest.raises(NanoctError, match="no data set there"):
        predict(path, run, progress=False, reconstruct_kwargs=M, calibrate_on=tmp_path / "missing")
    no_val = tmp_path / "noval"
    generate_dataset(no_val, get_preset("tiny-parallel"), 4, workers=0, progress=False, split_fractions=(0.5, 0, 0.5))
    with pytest.raises(NanoctError, match="no validation samples"):
        predict(path, run, progress=False, reconstruct_kwargs=M, calibrate_on=no_val)
    fan = tmp_path / "fan"
    generate_dataset(fan, get_preset("tiny-fan"), 3, workers=0, progress=False, split_fractions=(0.0, 1.0, 0.0))
    with pytest.raises(NanoctError, match="another geometry"):
        predict(path, run, progress=False, reconstruct_kwargs=M, calibrate_on=fan)
    with pytest.raises(NanoctError, match="--no-calibrate switches off"):
        predict(path, run, progress=False, reconstruct_kwargs=M, calibrate_on=no_val, calibrate=False)
    assert not any(n.startswith("fbp+") for n in DataStore.open(path).reconstruction_names())


def _confident_objects(rng: np.random.Generator, n: int, size: int = 32):
    """Means, stds and truths of images with a bright disc and a faint one that the network is as sure of
    as of the background (its std is the background's), with errors of the std's size on the objects and
    a tenth of it on the background."""
    yy, xx = np.mgrid[:size, :size]
    means, stds, gts = [], [], []
    for _ in range(n):
        cy, cx = rng.uniform(10, 22, 2)
        r = np.hypot(yy - cy, xx - cx)
        big, faint = r <= 7, np.hypot(yy - (cy + 14) % size, xx - (cx + 14) % size) <= 3.5
        gt = np.where(big, 1.0, np.where(faint, 0.3, 0.0))
        std = np.where(big, 0.02 + 0.03 * (r > 5), 0.002)
        means.append(gt + np.where(big | faint, std, 0.1 * std) * rng.standard_normal(gt.shape))
        stds.append(std)
        gts.append(gt)
    return np.array(means), np.array(stds), np.array(gts)


def test_the_default_support_on_the_mean_keeps_a_confident_object_out_of_the_background():
    """A faint object with the background's std is background to a support on the std, and its pixels fill
    the object's narrow width fifths uncovered; on the mean (the default) every fifth holds its level."""
    rng = np.random.default_rng(0)
    cal, (mean, std, gt) = _confident_objects(rng, 60), _confident_objects(rng, 60)
    default = fit_intervals(*cal, levels=(0.9,))
    assert default["support"]["source"] == "mean"
    fits = {"mean": default, "std": fit_intervals(*cal, levels=(0.9,), support_source="std")}
    fifths = {}
    for source, fit in fits.items():
        half = half_width({"calibration": fit}, std, 0.9, mean=mean)
        fifths[source] = interval_scores(mean - gt, half, support_mask(gt))["coverage_by_width"]
    assert all(0.87 <= c <= 0.93 for c in fifths["mean"]), fifths["mean"]
    assert min(fifths["std"]) < 0.8, fifths["std"]


def test_measured_references_are_fitted_relative_to_each_image_on_the_field_of_view(tmp_path, tiny_store):
    """A split of measured pairs (FBP references: noise, zero outside the view) gets the relative support and
    the field of view; phantoms get neither, and pixels outside ``known`` do not move the fit."""
    from nanoct.sim.matched import fov_disc, generate_like, parse_mix, plan_matched
    from scan_like import scan_store

    scan = scan_store(tmp_path / "scan", shifts=np.zeros(48))
    pairs = generate_like(tmp_path / "pairs", plan_matched(scan.path, binning=2, mix=parse_mix("0,0,0,1")), 3,
                          split_fractions=(0.0, 1.0, 0.0), workers=0, progress=False)  # fmt: skip
    gts = pairs.read_phantoms(pairs.indices("val"))
    rule = cal_mod.reference_rule(pairs, gts)
    assert rule["support_source"] == "relative" and rule["object_conditional"] is True and rule["footprint"] is True
    # a split mixing measured pairs with phantoms (a matched set's): no footprint, the phantoms lie anywhere
    mixed = np.concatenate([gts, np.clip(gts[:1], 0, None)])
    assert cal_mod.reference_rule(pairs, mixed)["footprint"] is False
    np.testing.assert_array_equal(rule["known"], fov_disc(pairs.geometry) > 0)
    assert cal_mod.reference_rule(tiny_store, tiny_store.read_phantoms([0, 1])) == {}
    # the std outside ``known`` (the support is the mean's) does not move the fit; the groups' fit is that
    # of the known pixels alone
    rng = np.random.default_rng(1)
    means = gts + rng.normal(0, 0.01, gts.shape)
    stds = np.abs(rng.normal(0.01, 0.003, gts.shape))
    fit = cal_mod.fit_intervals(means, stds, gts, levels=(0.9,), **rule)
    again = cal_mod.fit_intervals(means, np.where(rule["known"], stds, 50.0), gts, levels=(0.9,), **rule)
    assert again["levels"] == fit["levels"] and fit["known_pixels"] == 3 * int(rule["known"].sum())
    groups = fit["levels"]["0.9"]["groups"]
    labels = np.where(rule["known"], group_labels(stds, groups, means), -1)
    truth = truth_support(gts, 0, known=rule["known"]) & rule["known"]
    # the footprint: the pixels of the field of view in the relative support of at least one image
    relative = means / np.percentile(np.abs(means), 99, axis=(1, 2))[:, None, None]
    supports = support_of(relative, groups["support"]["threshold"], groups["support"]["radius"], True)
    footprint = (supports & rule["known"]).any(axis=0)
    np.testing.assert_array_equal(decode_mask(groups["footprint"]), footprint)
    np.testing.assert_array_equal(labels == 6, footprint & ~supports & rule["known"])
    assert (labels == 6).any() and (labels == 0).any()
    by_hand = fit_group_intervals(np.abs(means - gts), stds, labels, 0.9, truth=truth, footprint=True)
    assert len(by_hand["multipliers"]) == 7
    assert {k: groups[k] for k in by_hand} == by_hand and groups["support"]["source"] == "relative"
    # nor does the mean outside ``known`` (an FBP's streaks there, beyond the support's 2 px dilation) move the
    # support's threshold, the groups or the multipliers (the support on the mean as given, so that the pixels
    # inside keep their values)
    absolute = {**rule, "support_source": "mean"}
    far = ~ndimage.binary_dilation(rule["known"], iterations=3)
    assert far.sum() > 50
    bright = np.where(far, means.max(), means)
    fit_abs = cal_mod.fit_intervals(means, stds, gts, levels=(0.9,), **absolute)
    assert cal_mod.fit_intervals(bright, stds, gts, levels=(0.9,), **absolute)["levels"] == fit_abs["levels"]
    assert fit["object_conditional"] and "class_multipliers" in groups
    assert not cal_mod.fit_intervals(means, stds, gts, levels=(0.9,))["object_conditional"]


@pytest.mark.slow
def test_a_moved_folder_keeps_its_calibration_and_prediction(setup, tmp_path, monkeypatch):
    """A data set and run moved together (the run's config.json still naming the old place): the fit is found by
    the data set's description and input id, recorded under the new path without a refit, and the prediction
    resumes with nothing recomputed; a data set made again at the moved path is fitted again."""
    path, run = _copy(setup, tmp_path / "a")
    name = predict(path, run, progress=False, reconstruct_kwargs=M)
    before = load_calibration(run)["best"]
    (tmp_path / "a").rename(tmp_path / "b")
    data, moved = tmp_path / "b" / "data", tmp_path / "b" / "run"

    def no_refit(*a, **k):
        raise AssertionError("refitted")

    monkeypatch.setattr(cal_mod, "sample_outputs", no_refit)
    monkeypatch.setattr(predict_mod, "model_from_checkpoint", no_refit)
    assert predict(data, moved, progress=False, reconstruct_kwargs=M) == name
    entries = load_calibration(moved)
    key = cal_mod.entry_name(moved, "best", data)
    assert key == f"best@{data.resolve()}" and entries["best"] == before
    assert entries[key] == before | {"store": str(data.resolve())}
    params = DataStore.open(data).reconstruction_params(name)
    assert params["calibration"] == entries[key] and params["run"] == str(moved.resolve())
    monkeypatch.undo()
    # another data set at the moved path: its input has another creation id, so no entry is taken for it
    shutil.rmtree(data)
    generate_dataset(data, get_preset("tiny-parallel"), 12, seed=7, workers=0, progress=False,
                     split_fractions=(0.5, 0.25, 0.25))  # fmt: skip
    reconstruct_dataset(data, "fbp", workers=0, progress=False)
    refits: list[int] = []
    real = cal_mod.sample_outputs
    monkeypatch.setattr(cal_mod, "sample_outputs", lambda *a, **k: (refits.append(1), real(*a, **k))[1])
    calibrate(data, moved, reconstruct_kwargs=M)
    assert refits == [1]


@pytest.mark.slow
def test_a_moved_folder_under_a_new_calibration_format_is_predicted_again(setup, tmp_path, monkeypatch):
    """A study folder copied elsewhere and run with a release whose calibration entries have another format:
    the entry is fitted again and the prediction made again with it, without --overwrite (the same checkpoint
    file under the moved run's path is the same request); before, it was refused naming --overwrite, which
    ``nanoct reproduce`` does not have."""
    path, run = _copy(setup, tmp_path / "a")
    name = predict(path, run, progress=False, reconstruct_kwargs=M)
    (tmp_path / "a").rename(tmp_path / "b")
    data, moved = tmp_path / "b" / "data", tmp_path / "b" / "run"
    monkeypatch.setattr(cal_mod, "CALIBRATION_FORMAT", cal_mod.CALIBRATION_FORMAT + 1)
    assert predict(data, moved, progress=False, reconstruct_kwargs=M) == name
    params = DataStore.open(data).reconstruction_params(name)
    assert params["calibration"]["format"] == cal_mod.CALIBRATION_FORMAT and params["run"] == str(moved.resolve())
    assert params["calibration"] == load_calibration(moved)[cal_mod.entry_name(moved, "best", data)]
    assert DataStore.open(data).reconstruction_done(name, np.arange(12)).sum() == 3


def test_a_footprint_fitted_on_noisy_means_of_independent_draws_is_warned_of(tiny_store):
    """Validation means whose sampling noise (std / sqrt(M)) is a large share of their level: their support is
    partly noise, so the footprint fitted on them is wider than the sample; antithetic means are not judged so."""
    rng = np.random.default_rng(3)
    known = np.ones((16, 16), bool)
    means, stds = rng.normal(0, 0.01, (3, 16, 16)), np.full((3, 16, 16), 0.02)
    means[0] += 1.0  # one bright image: ratio 0.01 / 1.0; the others about 0.01 / 0.025
    key = {"n_samples": 4, "reconstruct": {"n_samples": 4}}
    with pytest.warns(UserWarning, match=r"sampling noise of 2 of 3 means of 4 independent draws .*--antithetic"):
        cal_mod._warn_noisy_footprint(tiny_store, means, stds, key, known)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cal_mod._warn_noisy_footprint(tiny_store, means, stds, key | {"reconstruct": {"antithetic": True}}, known)
        cal_mod._warn_noisy_footprint(tiny_store, means[:1], stds[:1], key, known)
