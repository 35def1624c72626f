"""Evaluation tables: name scheme, model groups, input mixing, uncertainty scores."""

import json

import numpy as np
import pytest

from nanoct.evaluation.evaluate import (
    evaluate_store,
    format_mixing,
    format_table,
    format_uncertainty_table,
    mixing_matrices,
    per_image_values,
    store_setting,
    write_report_tables,
)
from nanoct.evaluation.metrics import edge_std, psnr, ssim, support_mask
from nanoct.io.store import DataStore


def _scores(p):
    return {"psnr_mean": p, "psnr_std": 1.0, "ssim_mean": p / 100, "ssim_std": 0.01, "n": 3}


def test_mixing_and_tables():
    results = {
        name: _scores(20 + i)
        for i, name in enumerate(
            ["fbp", "resesop", "fbp+unet", "resesop+unet", "fbp+unet@resesop", "resesop+unet@fbp", "resesop+cinn"]
        )
    }
    mix = mixing_matrices(results)
    assert set(mix) == {"unet"}  # cinn was applied to one input only
    assert mix["unet"]["fbp"]["resesop"]["psnr_mean"] == 25  # trained on fbp, applied to resesop
    assert mix["unet"]["resesop"]["fbp"]["psnr_mean"] == 24
    table = format_table(results)
    assert table.index("**no post-processing**") < table.index("**+ cinn**") < table.index("**+ unet**")
    assert "| fbp+unet | 22.00 ± 1.00 | 0.220 ± 0.010 | – | – | - | 3 |" in table  # no registered scores given
    assert "PSNR registered [dB]" in table and "Registered: the same after the best sub-pixel translation" in table
    text = format_mixing(mix)
    assert "| fbp | 22.00 ± 1.00 | 25.00 ± 1.00 |" in text  # row fbp: applied to fbp, resesop


def _calibration(levels: dict[str, float], edge: dict[str, float]) -> dict:
    """A stored calibration as :func:`nanoct.learn.calibration.fit_intervals` makes it (values made up)."""
    width_map = {"std": [0.02, 0.05, 0.08], "width": [0.01, 0.05, 0.06]}  # made up, increasing
    return {
        "delta": 0.1,
        "levels": {
            k: {"map": width_map, "multiplier": q, "guaranteed_coverage": float(k) - 0.1, "rcps_multiplier": None}
            for k, q in levels.items()
        },
        "edge_sigma": 1.5,
        "edge_multipliers": edge,
        "ood": {"statistic": "mean_std", "alpha": 0.05, "val": [0.04, 0.05, 0.06]},
    }


def test_every_reported_uncertainty_number_is_recomputed_from_the_stored_arrays(tiny_store, tmp_path):
    """One truth: evaluate --json and the report's numbers are those of uncertainty/<name> and its multipliers."""
    from scipy import stats

    store = DataStore.open(tiny_store.path, mode="r+")
    test = store.indices("test")
    gts = store.read_phantoms(test).astype(np.float64)
    cal = _calibration({"0.68": 1.0, "0.9": 1.645, "0.95": 1.96}, {"0.68": 30.0, "0.9": 50.0, "0.95": 60.0})
    store.prepare_reconstruction("eval_truth+fake", {"calibration": cal}, uncertainty=True)
    rng = np.random.default_rng(0)
    for i, g in zip(test, gts):
        std = rng.uniform(0.02, 0.08, g.shape).astype(np.float32)  # errors drawn with this std
        store.write_reconstruction("eval_truth+fake", int(i), g + rng.normal(0, 1, g.shape) * std, std=std)
    results = evaluate_store(store, "test", names=["eval_truth+fake"])
    md, js = write_report_tables(store, results, tmp_path)
    r = json.loads(js.read_text())["results"]["eval_truth+fake"]
    # independent recomputation from the arrays in the store
    recos = store.read_reconstruction("eval_truth+fake", test).astype(np.float64)
    stored = store.read_uncertainty("eval_truth+fake", test).astype(np.float64)
    err = np.abs(recos - gts)
    edges = edge_std(recos, 1.5)
    assert r["psnr_mean"] == pytest.approx(np.mean([psnr(x, g) for x, g in zip(recos, gts)]))
    for region, mask in (("all", np.ones(err.shape, bool)), ("support", support_mask(gts))):
        u, e, s_, b_ = r["uncertainty"][region], err[mask], stored[mask], edges[mask]
        assert u["n_pixels"] == mask.sum()
        assert u["std_error_corr"] == pytest.approx(stats.pearsonr(s_, e).statistic, abs=1e-9)
        assert u["std_error_spearman"] == pytest.approx(stats.spearmanr(s_, e).statistic, abs=1e-9)
        # partial correlation: correlation of the residuals of both after a linear fit on the edge baseline
        res_s = s_ - np.polyval(np.polyfit(b_, s_, 1), b_)
        res_e = e - np.polyval(np.polyfit(b_, e, 1), b_)
        assert u["partial_corr_given_baseline"] == pytest.approx(np.corrcoef(res_s, res_e)[0, 1], abs=1e-6)
        assert u["mean_std"] == pytest.approx(s_.mean())
        for key, entry in cal["levels"].items():
            iv, q = u["intervals"][key], entry["multiplier"]
            # the width map by hand: linear in log-log between the knots, end slopes beyond
            lx, ly = np.log([0.02, 0.05, 0.08]), np.log([0.01, 0.05, 0.06])
            ls = np.log(s_)
            slope = np.where(ls < lx[1], (ly[1] - ly[0]) / (lx[1] - lx[0]), (ly[2] - ly[1]) / (lx[2] - lx[1]))
            half = q * np.exp(np.where(ls < lx[1], ly[0], ly[1]) + slope * (ls - np.where(ls < lx[1], lx[0], lx[1])))
            assert iv["coverage"] == pytest.approx(np.mean(e <= half))
            assert iv["mean_half_width"] == pytest.approx(half.mean())
            assert iv["width_error_corr"] == pytest.approx(stats.pearsonr(half, e).statistic, abs=1e-9)
            order = np.argsort(s_, kind="stable")
            fifths = np.array_split((e <= half)[order], 5)
            assert iv["coverage_by_width"] == pytest.approx([f.mean() for f in fifths])
            full = np.zeros(err.shape)
            full[mask] = half
            per_image = [np.mean(err[i][mask[i]] <= full[i][mask[i]]) for i in range(len(test))]
            assert iv["image_coverage"]["std"] == pytest.approx(np.std(per_image))
            assert iv["image_coverage"]["min"] == pytest.approx(min(per_image))
            assert r["guarantee"]["levels"][key]["guaranteed_coverage"] == entry["guaranteed_coverage"]
            edge_cov = r["edge_baseline"][region]["intervals"][key]["coverage"]
            assert edge_cov == pytest.approx(np.mean(e <= cal["edge_multipliers"][key] * b_))
        # AUSE by brute force: MAE left after removing the largest std vs the largest errors
        n = e.size
        keep = [n - int(np.floor(f * n + 1e-9)) for f in np.arange(100) / 100]
        by_std, by_err = e[np.argsort(-s_, kind="stable")][::-1], np.sort(e)
        curve = np.array([by_std[:k].mean() for k in keep]) / e.mean()
        oracle = np.array([by_err[:k].mean() for k in keep]) / e.mean()
        assert u["ause"] == pytest.approx(np.trapezoid(curve - oracle, np.arange(100) / 100), rel=1e-6)
    assert r["std_error_corr"] == r["uncertainty"]["all"]["std_error_corr"] > 0.3
    assert r["uncertainty"]["all"]["intervals"]["0.9"]["coverage"] > 0.5
    text = md.read_text()
    u = r["uncertainty"]["all"]
    assert f"| eval_truth+fake | all | {u['std_error_corr']:.3f} | {u['std_error_spearman']:.3f} |" in text
    cov = u["intervals"]["0.9"]["coverage"]
    assert f"| eval_truth+fake | all | 0.9 | {100 * cov:.1f} | 80.0 |" in text
    store.delete_reconstruction("eval_truth+fake")
    assert not store.has_uncertainty("eval_truth+fake")


def test_uncertainty_table_without_calibration():
    u = {
        "std_error_corr": 0.5,
        "std_error_spearman": 0.4,
        "partial_corr_given_baseline": 0.25,
        "intervals": {},
        "ause": 0.1,
        "ause_random": 0.4,
        "ause_ratio": 0.25,
    }
    edge = {"sigma": 1.0, "all": u | {"partial_corr_given_baseline": None}, "support": u}
    guarantee = {"delta": None, "levels": {}}
    results = {
        "fbp": _scores(20),
        "fbp+cinn": _scores(21)
        | {"uncertainty": {"all": u, "support": u}, "edge_baseline": edge, "guarantee": guarantee},
    }
    table = format_uncertainty_table(results)
    assert "| fbp+cinn | all | 0.500 | 0.400 | 0.250 | 0.100 / 0.400 (0.25) | 0.500 | 0.400 |" in table
    assert "| fbp |" not in table and format_uncertainty_table({"fbp": _scores(20)}) == ""


def test_per_image_values_in_split_order_and_conclusions_in_json(tiny_store, tmp_path):
    """Per-image PSNR/SSIM follow the split's index order (pairs line up across rows); the JSON has the checks."""
    import shutil

    from nanoct.evaluation.conclusions import check_conclusions

    # a private copy: other modules write their own "fbp" into the session's store
    store = DataStore.open(shutil.copytree(tiny_store.path, tmp_path / "copy"), mode="r+")
    test = store.indices("test")
    gts = store.read_phantoms(test)
    rng = np.random.default_rng(5)
    for name, noise in (("fbp", 0.2), ("dremel", 0.02)):  # dremel: ten times less noise than fbp
        store.delete_reconstruction(name)  # another module's real reconstruction, if it ran first
        store.prepare_reconstruction(name, {})
        for i, g in zip(test, gts):
            store.write_reconstruction(name, int(i), g + rng.normal(0, noise, g.shape).astype(np.float32))
    results = evaluate_store(store, "test", names=["fbp", "dremel"])
    for name in ("fbp", "dremel"):
        recos = store.read_reconstruction(name, test)
        assert results[name]["psnr_values"] == pytest.approx([psnr(r, g) for r, g in zip(recos, gts)])
        assert results[name]["ssim_values"] == pytest.approx([ssim(r, g) for r, g in zip(recos, gts)])
        p = [psnr(r, g) for r, g in zip(recos, gts)]
        assert (results[name]["psnr_mean"], results[name]["psnr_std"]) == pytest.approx((np.mean(p), np.std(p)))
        assert results[name]["n"] == len(gts)
    values = per_image_values(results)
    assert values["fbp"]["psnr"].shape == (len(test),)
    assert store_setting(store) == "parallel"
    checks = check_conclusions(values, "parallel")
    beat = next(c for c in checks if c["comparisons"] and c["comparisons"][0]["label"] == "dremel > fbp")
    assert [c["verdict"] for c in beat["comparisons"] if c["label"] == "dremel > fbp"] == ["holds", "holds"]
    for name in ("fbp", "dremel"):  # registered scores for every row, never below the plain ones
        r = results[name]
        lengths = {len(r[k]) for k in ("psnr_registered_values", "ssim_registered_values", "shift_values")}
        assert lengths == {len(gts)}
        assert all(a >= b for a, b in zip(r["psnr_registered_values"], r["psnr_values"]))
    _, js = write_report_tables(store, results, tmp_path, conclusions=checks, setting="parallel")
    payload = json.loads(js.read_text())
    assert {"psnr_registered_mean", "ssim_registered_mean", "shift_mean"} <= set(payload["results"]["fbp"])
    assert set(payload["gauge"]) == {"plain", "registered"}
    md = (tmp_path / "evaluation.md").read_text()
    assert "| dremel | " in md and "PSNR registered [dB]" in md
    assert payload["setting"] == "parallel" and payload["conclusions"][0]["id"] == checks[0]["id"]
    assert "The paper's conclusions (parallel)" in (tmp_path / "evaluation.md").read_text()
    # a store with none of the conclusions' rows (one row, "fbp" renamed) gets no block of "not applicable"
    only = {"other": results["fbp"]}
    none_apply = check_conclusions(per_image_values(only), "parallel")
    assert {c["verdict"] for c in none_apply} == {"not applicable"}
    _, js = write_report_tables(store, only, tmp_path / "none", conclusions=none_apply, setting="parallel")
    assert "The paper's conclusions" not in (tmp_path / "none" / "evaluation.md").read_text()
    assert len(json.loads(js.read_text())["conclusions"]) == len(none_apply)


def test_paper_comparison_keeps_the_papers_convention():
    """The comparison with the paper uses the scores as reconstructed, not the registered ones, and says so."""
    from nanoct.evaluation.paper import PAPER_GAUGE, format_comparison

    scores = {**_scores(28.0), "psnr_registered_mean": 35.0, "psnr_registered_std": 1.0}
    scores |= {"ssim_registered_mean": 0.9, "ssim_registered_std": 0.01}
    text = format_comparison({"fbp": scores}, "parallel")
    row = next(line for line in text.splitlines() if line.startswith("| fbp |"))
    assert "28.00 ± 1.00" in row and "35.00" not in row
    assert PAPER_GAUGE in text


def test_intervals_whose_support_is_found_from_the_mean_are_scored(rng):
    """A calibration fitted on measured references finds the support from the prediction's mean (relative to each
    image's level): ``uncertainty_scores`` passes the mean, and scores the half-widths ``half_width`` gives."""
    from nanoct.evaluation.conformal import half_width
    from nanoct.evaluation.evaluate import uncertainty_scores
    from nanoct.learn.calibration import fit_intervals

    yy, xx = np.mgrid[:24, :24] - 12
    disc = np.hypot(xx, yy) <= 6
    gts = np.stack([disc * level for level in (0.2, 0.002, 0.05, 0.1)] * 3) + rng.normal(0, 1e-4, (12, 24, 24))
    means = gts + rng.normal(0, 0.003, gts.shape)
    stds = np.abs(rng.normal(0.003, 0.001, gts.shape))
    cal = fit_intervals(means[:8], stds[:8], gts[:8], levels=(0.9,), support_source="relative")
    scores = uncertainty_scores(stds[8:], means[8:], gts[8:], calibration=cal)
    inside = np.abs(means[8:] - gts[8:]) <= half_width({"calibration": cal}, stds[8:], 0.9, mean=means[8:])
    assert scores["uncertainty"]["all"]["intervals"]["0.9"]["coverage"] == pytest.approx(inside.mean())


def test_measured_references_are_scored_on_their_object_not_on_their_positive_noise(rng):
    """A measured reference is positive over about half its background (its noise): the support row scores the
    object :func:`truth_support` finds (here the disc), says how many references are measured, and the table's
    note says how their support is found; phantoms keep ``gt > 0`` and the note as it was."""
    from nanoct.evaluation.evaluate import format_uncertainty_table, uncertainty_scores
    from nanoct.evaluation.metrics import support_mask, truth_support
    from nanoct.learn.calibration import fit_intervals

    yy, xx = np.mgrid[:32, :32] - 16
    disc = np.hypot(xx, yy) <= 7
    gts = disc * 0.1 + rng.normal(0, 2e-3, (12, 32, 32))
    means = gts + rng.normal(0, 0.003, gts.shape) * (1 + 2 * disc)
    stds = np.abs(rng.normal(0.003, 0.001, gts.shape))
    cal = fit_intervals(means[:8], stds[:8], gts[:8], levels=(0.9,), support_source="relative")
    scores = uncertainty_scores(stds[8:], means[8:], gts[8:], calibration=cal)
    found = truth_support(gts[8:])
    # the disc dilated (the smoothing widens it by a pixel or two), not the positive noise
    assert (found >= support_mask(disc)).all() and (found <= support_mask(disc, 4)).all()
    assert support_mask(gts[8:]).mean() > 2 * found.mean()
    err = np.abs(means[8:] - gts[8:])
    assert scores["uncertainty"]["support"]["mean_abs_error"] == pytest.approx(err[found].mean())
    assert scores["measured_references"] == 4
    note = format_uncertainty_table({"dremel+ciunet-res": scores})
    assert scores["references"] == 4
    assert "4 of the 4 references are measured" in note and "truth_support" in note

    phantoms = np.clip(gts, 0, None)
    plain = uncertainty_scores(stds[8:], means[8:], phantoms[8:], calibration=cal)
    assert "measured_references" not in plain
    assert plain["uncertainty"]["support"]["mean_abs_error"] == pytest.approx(
        np.abs(means[8:] - phantoms[8:])[support_mask(phantoms[8:])].mean()
    )
    assert "are measured" not in format_uncertainty_table({"dremel+ciunet-res": plain})
