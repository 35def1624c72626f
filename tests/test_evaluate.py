"""Evaluation tables: name scheme, model groups, input mixing, uncertainty scores."""

import json

import numpy as np
import pytest

from nanoct.evaluate import (
    evaluate_store,
    format_mixing,
    format_table,
    mixing_matrices,
    parse_name,
    write_report_tables,
)
from nanoct.metrics import psnr
from nanoct.store import DataStore


def test_parse_name():
    assert parse_name("resesop_eta0.8") == ("resesop_eta0.8", None, "resesop_eta0.8")
    assert parse_name("resesop+unet") == ("resesop", "unet", "resesop")
    assert parse_name("fbp+ciunet-res@resesop") == ("fbp", "ciunet-res", "resesop")


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


def test_evaluate_store_with_uncertainty(tiny_store, tmp_path):
    store = DataStore.open(tiny_store.path, mode="r+")
    test = store.indices("test")
    gts = store.read_phantoms(test)
    store.prepare_reconstruction("eval_truth+fake", {"t": 1}, uncertainty=True)
    rng = np.random.default_rng(0)
    for i, g in zip(test, gts):
        std = np.full(g.shape, 0.05, np.float32)
        store.write_reconstruction(
            "eval_truth+fake", int(i), g + rng.normal(0, 0.05, g.shape).astype(np.float32), std=std
        )
    results = evaluate_store(store, "test", names=["eval_truth+fake"])
    r = results["eval_truth+fake"]
    expected = np.mean([psnr(store.read_reconstruction("eval_truth+fake", [i])[0], g) for i, g in zip(test, gts)])
    assert r["psnr_mean"] == pytest.approx(expected) and r["n"] == len(test)
    assert r["calibration"]["observed"]["1"] == pytest.approx(0.683, abs=0.05)
    md, js = write_report_tables(store, results, tmp_path)
    payload = json.loads(js.read_text())
    assert set(payload["results"]["eval_truth+fake"]) >= {
        "psnr_mean",
        "psnr_std",
        "ssim_mean",
        "ssim_std",
        "n",
        "std_error_corr",
        "calibration",
    }
    assert "within 1/2/3 std" in md.read_text()
    store.delete_reconstruction("eval_truth+fake")
    assert not store.has_uncertainty("eval_truth+fake")
