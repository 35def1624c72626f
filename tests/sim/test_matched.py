"""A set matched to a measured scan: its geometry, noise and motion equal the scan's; it resumes."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import zarr

from nanoct.core.errors import NanoctError, StoreError
from nanoct.core.operators import RayTransform
from nanoct.io.store import DataStore
from nanoct.recon.measured import looks_measured
from nanoct.sim import matched
from nanoct.sim.generate import fill_dataset
from nanoct.sim.matched import generate_like, parse_mix, plan_matched
from nanoct.sim.scan_stats import air_noise, binned_offset
from scan_like import AIR, ANGLES_DEG, N_DET, OFFSET, SIGMA, SLICES, scan_store


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    return scan_store(tmp_path_factory.mktemp("scan") / "scan")


@pytest.fixture(scope="module")
def moved_scan(tmp_path_factory):
    k = ANGLES_DEG.size
    shifts = 0.6 * np.sin(2 * np.pi * np.arange(k) / k) + np.random.default_rng(5).normal(0, 0.08, k)
    store = scan_store(tmp_path_factory.mktemp("moved") / "scan", shifts=shifts)
    _write_slices(store, "fbp_stack", SLICES)  # a finished stack result: its motion is the default source
    return store, shifts


def _write_slices(store: DataStore, name: str, count: int) -> None:
    """Mark the first ``count`` slices of result ``name`` written (blank images with its motion)."""
    shifts = store.recons.shared_shifts(name)
    for i in range(count):
        store.write_reconstruction(name, i, np.zeros(store.geometry.image_shape, np.float32), shifts=shifts)


def _add_result(path, name: str, shifts: np.ndarray, slices: int = SLICES) -> None:
    """A stack result ``name`` of the scan at ``path`` with motion ``shifts`` and its first ``slices`` slices."""
    store = DataStore.open(path, mode="r+")
    store.prepare_reconstruction(name, {"method": "fbp"}, shifts=True)
    store.recons.set_shared_shifts(name, shifts)
    store.recons.set_motion_info(name, {"center_offset": OFFSET})
    _write_slices(store, name, slices)


def _copy(store: DataStore, tmp_path) -> DataStore:
    """A copy of a module's scan that a test may add results to."""
    return DataStore.open(shutil.copytree(store.path, tmp_path / "scan"))


def test_the_plan_has_the_scans_views_binned_detector_axis_and_noise(scan):
    plan = plan_matched(scan.path, binning=2)
    g = plan.geometry
    np.testing.assert_array_equal(g.angles, np.deg2rad(ANGLES_DEG))
    assert (g.n_angles, g.n_det, g.n) == (ANGLES_DEG.size, N_DET // 2, N_DET // 2)
    assert g.center_offset == pytest.approx(binned_offset(OFFSET, N_DET, 2))
    like = plan.simulation["like"]
    # 2 x 2 binning of white noise halves its std; the estimate is within 10 % of that
    assert like["noise"]["sigma"] == pytest.approx(SIGMA / 2, rel=0.1)
    assert plan.simulation["noise_std"] == like["noise"]["sigma"]
    assert like["motion"] == {"from": None} and plan.simulation["motion"]["max_shift"] == 2.0  # the paper's
    assert like["axis_from"] == "the imported scan" and like["bin"] == 2 and like["store"] == str(scan.path.resolve())
    assert "measured_shift" not in like  # a three-family set is recorded as before
    assert plan.slices.shape == (SLICES // 2, N_DET // 2, N_DET // 2) and (plan.slices >= 0).all()
    assert like["value_scale"] == pytest.approx(float(np.percentile(plan.slices[plan.slices > 0], 99.9)), rel=0.3)


def test_the_generated_noise_and_geometry_equal_the_scans(scan, tmp_path):
    plan = plan_matched(scan.path, binning=2, perturbed=False)
    store = generate_like(tmp_path / "matched", plan, 8, seed=1, workers=0, progress=False)
    assert store.geometry == plan.geometry and store.done.all()
    y, y_eta = store.read_array("sinograms", range(8)), store.read_array("sinograms_eta", range(8))
    sigma = plan.simulation["like"]["noise"]["sigma"]
    assert np.std(y - y_eta) == pytest.approx(sigma, rel=0.05)  # unmoved: the difference is the noise alone
    # the same estimator on the matched set's air finds the scan's noise again
    assert air_noise(y)["sigma"] == pytest.approx(sigma, rel=0.15)
    phantoms = store.read_phantoms(range(8))
    assert phantoms.max() <= plan.simulation["like"]["value_scale"] * 1.5 and phantoms.min() >= 0
    with pytest.raises(NanoctError, match="matched to a measured scan"):  # its samples are not the paper's
        fill_dataset(store, workers=0, progress=False)


def test_the_simulated_sinograms_carry_the_scans_open_beam(scan, tmp_path):
    """The scan's air level per view is added, so the methods treat the matched set as they treat the scan."""
    plan = plan_matched(scan.path, binning=2)
    level = np.asarray(plan.simulation["like"]["open_beam"]["level"])
    angles = np.deg2rad(ANGLES_DEG)
    assert level == pytest.approx(AIR + 0.005 * np.sin(angles), abs=0.012)  # within the air bands' noise
    store = generate_like(tmp_path / "m", plan, 4, seed=1, workers=0, progress=False)
    for i in range(4):
        sample = store.read_sample(i)
        found = matched.air_level(sample.sinogram)  # the median of 2 x 3 noisy air pixels per view
        assert np.abs(found - level).mean() < 0.01 and np.abs(found - level).max() < 0.04
        model = matched.air_level(sample.sinogram_eta) - level  # noise-free: the level and the object's fringe
        assert model.min() >= -1e-6 and model.max() < 0.005
        assert looks_measured(sample.sinogram) and looks_measured(scan.read_array("sinograms", [0])[0])


def test_a_stack_motion_gives_the_motion_statistics_and_axis(moved_scan):
    store, shifts = moved_scan
    plan = plan_matched(store.path, binning=2)
    motion = plan.simulation["like"]["motion"]
    assert motion["from"] == "fbp_stack"
    assert motion["amplitude"] == pytest.approx(0.6 / 2, rel=0.15)  # binned pixels
    assert motion["jitter"] == pytest.approx(0.08 / 2, rel=0.25)
    assert plan.simulation["motion"]["max_shift"] == motion["amplitude"]
    assert plan.simulation["motion"]["jitter_std_mean"] == motion["jitter"]
    assert plan.geometry.center_offset == pytest.approx(binned_offset(OFFSET + 0.5, N_DET, 2))
    assert "fbp_stack" in plan.simulation["like"]["axis_from"]
    with pytest.raises(NanoctError, match="--motion-from 'nope'"):
        plan_matched(store.path, motion_from="nope")


def test_an_interrupted_result_is_not_the_default_motion_source(moved_scan, tmp_path):
    """'nanoct stack' records its motion before its slices: one stopped halfway (here 'dremel_stack', first in
    name order) is passed over by default until all its slices are done; asked for by name, it is used."""
    store, shifts = moved_scan
    scan = _copy(store, tmp_path)
    _add_result(scan.path, "dremel_stack", 2 * shifts, slices=2)
    assert plan_matched(scan.path, binning=2).simulation["like"]["motion"]["from"] == "fbp_stack"
    assert plan_matched(scan.path, binning=2, motion_from="dremel_stack").simulation["like"]["motion"]["from"] == (
        "dremel_stack"
    )
    assert "passed over the unfinished dremel_stack" in plan_matched(scan.path, binning=2).describe()[4]
    _write_slices(DataStore.open(scan.path, mode="r+"), "dremel_stack", SLICES)  # finished: first in name order
    plan = plan_matched(scan.path, binning=2)
    assert plan.simulation["like"]["motion"]["from"] == "dremel_stack"
    assert "the first by name of dremel_stack, fbp_stack; --motion-from takes another" in plan.describe()[4]


def test_resuming_keeps_the_motion_source_the_set_was_made_with(moved_scan, tmp_path, capsys):
    """A result added to the scan later (first in name order) does not change the source of a set at --out;
    asking for it names the nested key that differs and the --motion-from that resumes the set."""
    from nanoct.cli import run

    store, shifts = moved_scan
    scan, out = _copy(store, tmp_path), tmp_path / "matched"
    generate_like(out, plan_matched(scan.path, binning=2), 2, workers=0, progress=False)
    _add_result(scan.path, "a_stack", 2 * shifts)
    plan = plan_matched(scan.path, binning=2, out=out)
    assert plan.simulation["like"]["motion"]["from"] == "fbp_stack" and "as the set at" in plan.describe()[4]
    zarr.open_group(str(out), mode="r+")["done"][1] = False
    assert generate_like(out, plan, 2, workers=0, progress=False).done.all()  # resumed
    argv = ["generate", "--like", str(scan.path), "--bin", "2", "--n", "2", "--out", str(out)]
    assert run([*argv, "--plan"]) == 0
    text = capsys.readouterr().out
    assert "from 'fbp_stack'" in text and "(2 already made)" in text
    for asked in (None, "a_stack"):  # the default without --out, and the other result by name
        with pytest.raises(StoreError, match="differs in: simulation.like.motion.from, ") as refused:
            generate_like(out, plan_matched(scan.path, binning=2, motion_from=asked), 2, workers=0, progress=False)
        assert "took the motion of 'fbp_stack' (this run: 'a_stack'): give --motion-from fbp_stack" in str(
            refused.value
        )
    assert run([*argv, "-w", "0", "-q", "--motion-from", "a_stack"]) == 2
    assert "--motion-from fbp_stack to resume it" in capsys.readouterr().err
    DataStore.open(scan.path, mode="r+").delete_reconstruction("fbp_stack")  # gone: the default pick again
    assert plan_matched(scan.path, binning=2, out=out).simulation["like"]["motion"]["from"] == "a_stack"
    with pytest.raises(StoreError, match="no longer holds: use another --out"):
        generate_like(out, plan_matched(scan.path, binning=2, out=out), 2, workers=0, progress=False)


def test_a_set_made_without_a_motion_resumes_without_one(scan, tmp_path):
    """A set matched before any 'nanoct stack' keeps the paper's motion when a stack result appears later."""
    copy, out = _copy(scan, tmp_path), tmp_path / "matched"
    generate_like(out, plan_matched(copy.path, binning=2), 2, workers=0, progress=False)
    _add_result(copy.path, "fbp_stack", np.linspace(-0.5, 0.5, ANGLES_DEG.size))
    plan = plan_matched(copy.path, binning=2, out=out)
    assert plan.simulation["like"]["motion"] == {"from": None} and "as the set at" in plan.describe()[4]
    assert generate_like(out, plan, 2, workers=0, progress=False).done.all()
    with pytest.raises(StoreError, match="made without a stack motion .*leave --motion-from out to resume it"):
        generate_like(out, plan_matched(copy.path, binning=2), 2, workers=0, progress=False)


def test_resume_makes_only_the_missing_samples_with_the_same_bytes(scan, tmp_path):
    plan = plan_matched(scan.path, binning=2, mix=(0.0, 0.0, 1.0))
    out = tmp_path / "matched"
    store = generate_like(out, plan, 5, seed=3, workers=0, progress=False)
    before = store.read_array("sinograms", range(5)), store.read_phantoms(range(5))
    assert (before[1].reshape(5, -1).max(axis=1) > 0).all()  # scan slices as phantoms
    zarr.open_group(str(out), mode="r+")["done"][2] = False
    again = generate_like(out, plan_matched(scan.path, binning=2, mix=(0.0, 0.0, 1.0)), 5, seed=3, workers=0,
                          progress=False)  # fmt: skip
    assert again.done.all()
    np.testing.assert_array_equal(again.read_array("sinograms", range(5)), before[0])
    np.testing.assert_array_equal(again.read_phantoms(range(5)), before[1])
    with pytest.raises(StoreError, match="holds a different data set"):
        generate_like(out, plan_matched(scan.path, binning=1), 5, seed=3, workers=0, progress=False)


def test_bad_input_is_named(scan, tiny_store, tmp_path):
    with pytest.raises(NanoctError, match="no data set there"):
        plan_matched(tmp_path / "missing")
    with pytest.raises(NanoctError, match="is a simulated data set, not a measured scan"):
        plan_matched(tiny_store.path)
    with pytest.raises(NanoctError, match="--bin 3 does not divide"):
        plan_matched(scan.path, binning=3)
    for bad in ("1,2", "1e308,1e308,1"):  # too few; a sum that overflows
        with pytest.raises(NanoctError, match="--mix"):
            parse_mix(bad)
    assert parse_mix("2,1,1") == (0.5, 0.25, 0.25)
    with pytest.raises(NanoctError, match="--n 0"):
        generate_like(tmp_path / "x", plan_matched(scan.path, binning=2), 0, workers=0, progress=False)
    assert not (tmp_path / "x").exists()


def test_a_long_stack_is_sampled_evenly(scan, monkeypatch):
    np.testing.assert_array_equal(matched._slice_groups(10, 2), np.arange(10).reshape(5, 2))
    np.testing.assert_array_equal(matched._slice_groups(1, 2), [[0]])
    # fewer rows than the binning: each row is one slice, binned along the detector only, one group each
    np.testing.assert_array_equal(matched._slice_groups(3, 4), [[0], [1], [2]])
    for rows, b in ((3, 4), (10, 2), (11, 2)):
        binned = matched.bin_sinograms(np.zeros((matched._slice_groups(rows, b).size, 2, 8)), b)
        assert binned.shape[0] == matched._slice_groups(rows, b).shape[0]
    monkeypatch.setattr(matched, "MAX_SLICES", 2)
    np.testing.assert_array_equal(matched._slice_groups(11, 2), [[0, 1], [8, 9]])
    plan = plan_matched(scan.path, binning=1)
    assert plan.simulation["like"]["slices_measured"] == 2
    full = scan.read_array("sinograms", [0, SLICES - 1])  # the first and the last slice
    np.testing.assert_allclose(plan.slices, matched.scan_slices(full, plan.geometry), rtol=1e-6)


def test_held_out_rows_serve_as_no_phantom_and_no_measured_pair(scan):
    """--hold-out: a binned slice with any held-out row is dropped from the scan slices and the measured pairs
    (what is left equals the full plan without it); the scan-wide measurements are unchanged."""
    assert matched.parse_rows("4:6, 1,2") == (1, 2, 4, 5) and matched.parse_rows(None) == matched.parse_rows("") == ()
    for bad in ("3:3", "-1", "a", "1:2:3", "1,,2", "1,"):
        with pytest.raises(NanoctError, match="--hold-out"):
            matched.parse_rows(bad)
    full = plan_matched(scan.path, binning=2, mix=parse_mix("1,0,1,1"))
    held = plan_matched(scan.path, binning=2, mix=parse_mix("1,0,1,1"), hold_out=(3,))  # row 3: binned slice 1
    assert full.rows.tolist() == [0, 2, 4] and held.rows.tolist() == [0, 4]
    np.testing.assert_array_equal(held.slices, full.slices[[0, 2]])
    np.testing.assert_array_equal(held.measured, full.measured[[0, 2]])
    assert "2 slices kept, 0 nearly empty left out, 1 held out, of 3 measured" in "\n".join(held.describe())
    # fewer than 4 scan slices among the phantoms (here 2, 67 % of the mix): the plan warns that they can be learnt
    assert held.describe()[-1].startswith("note       67% of the phantoms are the scan's 2 slice(s)")
    no_scan = plan_matched(scan.path, binning=2, mix=parse_mix("1,1,0"), hold_out=(3,))
    assert not no_scan.describe()[-1].startswith("note")
    like, like_full = dict(held.simulation["like"]), dict(full.simulation["like"])
    assert like.pop("held_out") == {"rows": [3], "slices": 1} and "held_out" not in like_full
    assert like.pop("slices") == like_full.pop("slices") - 1 and like == like_full
    with pytest.raises(NanoctError, match="--hold-out row 99 is outside the scan"):
        plan_matched(scan.path, binning=2, hold_out=(99,))
    with pytest.raises(NanoctError, match="holds out every slice"):
        plan_matched(scan.path, binning=2, hold_out=tuple(range(SLICES)))


@pytest.mark.slow
def test_dask_workers_give_the_same_bytes_as_one_process(scan, tmp_path):
    plan = plan_matched(scan.path, binning=2)
    serial = generate_like(tmp_path / "serial", plan, 6, seed=4, workers=0, progress=False)
    dask = generate_like(tmp_path / "dask", plan, 6, seed=4, workers=2, progress=False)
    for name in ("phantoms", "sinograms", "sinograms_eta", "motion"):
        np.testing.assert_array_equal(serial.read_array(name, range(6)), dask.read_array(name, range(6)))


def _centroids(sino: np.ndarray) -> np.ndarray:
    """Per-view centroid (detector pixels) of a sinogram with its air level removed."""
    body = np.clip(sino - matched.air_level(sino)[:, None], 0.0, None)
    return (body * np.arange(sino.shape[1])).sum(axis=1) / body.sum(axis=1)


def test_measured_pairs_are_the_scans_views_moved_as_the_simulator_moves_a_phantom(moved_scan, tmp_path):
    store, _ = moved_scan
    plan = plan_matched(store.path, binning=2, mix=parse_mix("0,0,0,1"))
    assert plan.simulation["like"]["mix"] == {"shapes": 0.0, "ellipses": 0.0, "scan": 0.0, "measured": 1.0}
    assert plan.simulation["like"]["measured_shift"] == "fourier"  # recorded: a set of linear-read pairs differs
    out = generate_like(tmp_path / "pairs", plan, 4, seed=2, split_fractions=(0.0, 1.0, 0.0), workers=0, progress=False)
    assert out.indices("val").size == 4
    stored = zarr.open_group(str(out.path), mode="r")["like_measured"]
    assert stored.attrs["rows"] == plan.rows.tolist() == [0, 2, 4]  # the first scan row of each binned slice
    np.testing.assert_array_equal(stored[:], plan.measured)
    g = out.geometry
    for i in range(4):
        family, j = matched.matched_source(out, i)
        assert family == "measured"
        sample = out.read_sample(i)
        raw = plan.measured[j].astype(np.float64)
        # the unmoved views: the scan's with its estimated motion undone; no noise added to the moved ones
        np.testing.assert_allclose(sample.sinogram_eta, matched.read_moved(raw, plan.shifts, "fourier"), atol=1e-6)
        phi = g.angles
        along = sample.motion[:, 0] * np.cos(phi) + sample.motion[:, 1] * np.sin(phi)
        np.testing.assert_allclose(sample.sinogram, matched.read_moved(raw, plan.shifts - along, "fourier"), atol=1e-6)
        assert np.all(sample.motion[:, 2] == 0) and np.abs(along).max() > 0.1
        # the phantom is the reference: FBP of the unmoved views, air level removed, zero outside the view
        reference = matched.fbp(g, sample.sinogram_eta - matched.air_level(sample.sinogram_eta)[:, None]).image
        np.testing.assert_allclose(sample.phantom, reference * matched.fov_disc(g), atol=1e-5)
    # the views move as the simulator moves a phantom under the same translation (sign and size): the
    # centroid of a noise-free simulated view moves by -t . e_u, as the pair's views are read
    k = g.n_angles
    motion = np.zeros((k, 3), np.float32)
    motion[:, 0], motion[:, 1] = 1.5 * np.sin(np.linspace(0, 3, k)), np.cos(np.linspace(0, 2, k))
    yy, xx = np.mgrid[: 2 * g.n, : 2 * g.n] - (2 * g.n - 1) / 2
    fine = (0.1 * np.exp(-((yy - 6) ** 2 + (xx + 4) ** 2) / (2 * 6.0**2))).astype(np.float32)  # a smooth blob
    moved = RayTransform(g, motion, oversample=2).forward(fine)
    still = RayTransform(g, np.zeros_like(motion), oversample=2).forward(fine)
    along = motion[:, 0] * np.cos(g.angles) + motion[:, 1] * np.sin(g.angles)
    np.testing.assert_allclose(_centroids(moved) - _centroids(still), -along, atol=0.05)
    pair = matched.measured_pair(g, still, np.zeros(k), motion)  # the still views as if measured
    np.testing.assert_allclose(_centroids(pair.sinogram) - _centroids(still), -along, atol=0.05)


def test_a_set_of_measured_pairs_alone_is_reconstructed_as_the_scan(moved_scan, tmp_path):
    """RESESOP takes eta from Dremel's residual by default, as on the imported scan (not the drawn motion's eta)."""
    from nanoct.recon.batch import reconstruct_dataset

    store, _ = moved_scan
    pairs = generate_like(tmp_path / "pairs", plan_matched(store.path, binning=2, mix=parse_mix("0,0,0,1")), 3,
                          split_fractions=(0.0, 1.0, 0.0), workers=0, progress=False)  # fmt: skip
    with pytest.raises(NanoctError, match="estimate:residual needs the first reconstruction 'dremel'"):
        reconstruct_dataset(pairs.path, "resesop", workers=0, progress=False)
    mixed = generate_like(tmp_path / "mixed", plan_matched(store.path, binning=2, mix=parse_mix("1,0,0,1")), 3,
                          split_fractions=(0.0, 1.0, 0.0), workers=0, progress=False)  # fmt: skip
    name = reconstruct_dataset(mixed.path, "resesop", workers=0, progress=False)  # a simulation's true eta
    assert "eta" not in mixed.reconstruction_params(name) or mixed.reconstruction_params(name)["eta"] == "true"


def test_a_zero_fourth_mix_is_the_three_family_set():
    assert parse_mix("2,1,1,0") == parse_mix("2,1,1") == (0.5, 0.25, 0.25)
    assert parse_mix("0,0,1,1") == (0.0, 0.0, 0.5, 0.5)
    with pytest.raises(NanoctError, match="three or four numbers"):
        parse_mix("1,1,1,1,1")


def test_the_field_of_view_is_where_every_view_sees_in_image_units():
    """The disc every view sees: radius ((L - 1) / 2 - |axis offset|) detector pixels of det_spacing each."""
    from nanoct.core.geometry import Geometry

    angles = np.linspace(0, np.pi, 8, endpoint=False)
    r2 = (np.arange(41) - 20.0) ** 2
    r2 = r2[None, :] + r2[:, None]
    for spacing, offset, radius in ((2.0, -3.0, 14.0), (0.5, 4.0, 3.0)):  # ((21 - 1) / 2 - |offset|) * spacing
        g = Geometry.from_angles(angles, 41, 21, det_spacing=spacing, center_offset=offset)
        np.testing.assert_array_equal(matched.fov_disc(g) > 0, r2 <= radius**2)
