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
    read_std,
    store_setting,
    write_report_tables,
)
from nanoct.evaluation.metrics import apply_std_map, coverage, edge_std, psnr, ssim, support_mask
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
    assert "| fbp+unet | 22.00 ± 1.00 | 0.220 ± 0.010 | 3 |" in table
    text = format_mixing(mix)
    assert "| fbp | 22.00 ± 1.00 | 25.00 ± 1.00 |" in text  # row fbp: applied to fbp, resesop


@pytest.mark.slow
def test_evaluate_store_with_uncertainty(tiny_store, tmp_path):
    store = DataStore.open(tiny_store.path, mode="r+")
    test = store.indices("test")
    gts = store.read_phantoms(test)
    scale = 0.5  # as predict stored it before the map: calibrated std = scale * raw, scale in the parameters
    store.prepare_reconstruction(
        "eval_truth+fake", {"calibration": {"scale": scale, "edge_scale": 3.0, "edge_sigma": 1.5}}, uncertainty=True
    )
    rng = np.random.default_rng(0)
    for i, g in zip(test, gts):
        std = rng.uniform(0.02, 0.08, g.shape).astype(np.float32)  # errors drawn with this (raw) std
        store.write_reconstruction("eval_truth+fake", int(i), g + rng.normal(0, 1, g.shape) * std, std=scale * std)
    results = evaluate_store(store, "test", names=["eval_truth+fake"])
    r = results["eval_truth+fake"]
    recos = store.read_reconstruction("eval_truth+fake", test)
    expected = np.mean([psnr(x, g) for x, g in zip(recos, gts)])
    assert r["psnr_mean"] == pytest.approx(expected) and r["n"] == len(test)
    u = r["uncertainty"]
    assert u["all"]["scale"] == scale and u["all"]["mean_std"] == pytest.approx(0.05, rel=0.01)  # raw = stored / scale
    assert u["all"]["coverage"]["raw"]["1"] == pytest.approx(0.683, abs=0.05)
    assert u["all"]["coverage"]["calibrated"]["1"] == pytest.approx(
        coverage(recos - gts, store.read_uncertainty("eval_truth+fake", test))["1"]
    )
    assert u["all"]["calibration"] == "scale" and u["all"]["coverage"]["scaled"] == u["all"]["coverage"]["calibrated"]
    mask = support_mask(gts)
    assert u["support"]["n_pixels"] == mask.sum() < u["all"]["n_pixels"]
    edge = r["edge_baseline"]
    assert edge["sigma"] == 1.5 and edge["scale"] == 3.0
    raw_edge = edge_std(recos, 1.5)
    ref = coverage((recos - gts)[mask], 3.0 * raw_edge[mask])
    assert edge["support"]["coverage"]["calibrated"] == pytest.approx(ref)
    assert r["std_error_corr"] == u["all"]["std_error_corr"] > 0.3
    assert u["all"]["ause_ratio"] < 0.8
    md, js = write_report_tables(store, results, tmp_path)
    payload = json.loads(js.read_text())
    assert set(payload["results"]["eval_truth+fake"]) >= {
        "psnr_mean",
        "psnr_std",
        "ssim_mean",
        "ssim_std",
        "n",
        "std_error_corr",
        "uncertainty",
        "edge_baseline",
    }
    text = md.read_text()
    assert "within 1/2/3 std, raw [%]" in text and "| eval_truth+fake | support |" in text
    store.delete_reconstruction("eval_truth+fake")
    assert not store.has_uncertainty("eval_truth+fake")


def test_evaluate_store_with_a_std_map(tiny_store, tmp_path):
    """Predict stores the raw std through the map: read_std inverts it, the report has all three coverages."""
    store = DataStore.open(tiny_store.path, mode="r+")
    test = store.indices("test")
    gts = store.read_phantoms(test)
    std_map = {"std": [0.03, 0.06], "calibrated": [0.01, 0.05]}  # slope log(5)/log(2) in log-log
    cal = {"std_map": std_map, "scale": 0.5, "edge_scale": 3.0, "edge_sigma": 1.0}
    store.prepare_reconstruction("eval_map+fake", {"calibration": cal}, uncertainty=True)
    rng = np.random.default_rng(1)
    raws = []
    for i, g in zip(test, gts):
        raw = rng.uniform(0.02, 0.08, g.shape).astype(np.float32)
        true = apply_std_map(raw, std_map)  # the errors follow the mapped std
        store.write_reconstruction("eval_map+fake", int(i), g + rng.normal(0, 1, g.shape) * true, std=true)
        raws.append(raw)
    recovered, got = read_std(store, "eval_map+fake", test)
    np.testing.assert_allclose(recovered, np.stack(raws), rtol=1e-5)
    assert got == cal
    r = evaluate_store(store, "test", names=["eval_map+fake"])["eval_map+fake"]
    recos = store.read_reconstruction("eval_map+fake", test)
    u = r["uncertainty"]["all"]
    assert u["calibration"] == "map" and u["mean_std"] == pytest.approx(0.05, rel=0.01)
    assert u["coverage"]["calibrated"] == pytest.approx(
        coverage(recos - gts, store.read_uncertainty("eval_map+fake", test))
    )
    assert u["coverage"]["calibrated"]["2"] == pytest.approx(0.9545, abs=0.01)
    assert u["coverage"]["scaled"] == pytest.approx(coverage(recos - gts, 0.5 * np.stack(raws)))
    assert r["edge_baseline"]["all"]["calibration"] == "scale"  # the edge baseline keeps its one factor
    _, js = write_report_tables(store, {"eval_map+fake": r}, tmp_path)
    payload = json.loads(js.read_text())["results"]["eval_map+fake"]["uncertainty"]["all"]["coverage"]
    assert set(payload) == {"expected", "raw", "scaled", "calibrated"}
    text = (tmp_path / "evaluation.md").read_text()
    cells = [_pct(u["coverage"][k]) for k in ("raw", "scaled")] + ["0.5", _pct(u["coverage"]["calibrated"])]
    assert "| eval_map+fake | all | " in text and " | ".join(cells) in text
    store.delete_reconstruction("eval_map+fake")


def _pct(cov):
    return " / ".join(f"{cov[k] * 100:.0f}" for k in ("1", "2", "3"))


def test_uncertainty_table_without_calibration():
    u = {
        "std_error_corr": 0.5,
        "coverage": {"raw": {"1": 0.9, "2": 0.95, "3": 1.0}, "calibrated": None},
        "scale": None,
        "ause": 0.1,
        "ause_random": 0.4,
        "ause_ratio": 0.25,
    }
    edge = {"sigma": 1.0, "scale": None, "all": u, "support": u}
    results = {
        "fbp": _scores(20),
        "fbp+cinn": _scores(21) | {"uncertainty": {"all": u, "support": u}} | {"edge_baseline": edge},
    }
    table = format_uncertainty_table(results)
    assert "| fbp+cinn | all | 0.500 | 90 / 95 / 100 | - | - | - | 0.100 / 0.400 (0.25) | 0.500 | - |" in table
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
    _, js = write_report_tables(store, results, tmp_path, conclusions=checks, setting="parallel")
    payload = json.loads(js.read_text())
    assert payload["setting"] == "parallel" and payload["conclusions"][0]["id"] == checks[0]["id"]
    assert "The paper's conclusions (parallel)" in (tmp_path / "evaluation.md").read_text()
