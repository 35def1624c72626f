"""Conclusion checks on constructed result tables: holds, does not hold, undecided, not applicable."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.evaluation.conclusions import CLAIMS, VERDICTS, check_conclusions, format_conclusions, paper_conclusions
from nanoct.evaluation.paper import paper_mixing, paper_rows


def table(means, n=20, seed=0, noise=0.01):
    """Per-image rows around the given means: a large image effect shared by all rows plus small noise."""
    rng = np.random.default_rng(seed)
    image_psnr, image_ssim = rng.normal(0, 2.0, n), rng.normal(0, 0.02, n)
    out = {}
    for name, (p, s) in means.items():
        out[name] = {
            "psnr": p + image_psnr + rng.normal(0, noise, n),
            "ssim": s + image_ssim + rng.normal(0, noise / 100, n),
        }
    return out


def paper_like(setting="parallel"):
    """Rows at the paper's published means (main table, plus mixing for parallel)."""
    entries = paper_rows(setting) + ([e for m in ("unet",) for e in paper_mixing(m)] if setting == "parallel" else [])
    return {e.name: (e.value.psnr_mean, e.value.ssim_mean) for e in entries if e.input != e.train_input}


def get(checks, claim):
    return next(c for c in checks if c["claim"] == claim)


def test_paired_difference_and_standard_error_by_hand():
    results = {
        "fbp": {"psnr": [0.0, 1.0, 1.0, 3.0], "ssim": [0.5, 0.5, 0.5, 0.5]},
        "dremel": {"psnr": [1.0, 2.0, 3.0, 4.0], "ssim": [0.6, 0.6, 0.6, 0.6]},
        "resesop": {"psnr": [1.0, 2.0, 3.0, 4.0], "ssim": [0.6, 0.6, 0.6, 0.6]},
    }
    check = get(check_conclusions(results, "parallel"), "methods_beat_fbp")
    comp = next(c for c in check["comparisons"] if c["label"] == "dremel > fbp" and c["metric"] == "psnr")
    # per-image differences 1, 1, 2, 1: mean 1.25, std (ddof=1) 0.5, s.e. 0.25
    assert comp["diff"] == pytest.approx(1.25) and comp["se"] == pytest.approx(0.25) and comp["n"] == 4
    assert comp["verdict"] == "holds"  # 1.25 > 2 * 0.25
    assert get(check_conclusions(results, "parallel", k=6), "methods_beat_fbp")["verdict"] == "undecided"


def test_pairing_over_images():
    """A small consistent gain under a large image-to-image spread is decided by pairing."""
    rng = np.random.default_rng(1)
    base = rng.normal(30, 3, 30)
    results = {
        "fbp": {"psnr": base, "ssim": base / 40},
        "dremel": {"psnr": base + 0.2 + rng.normal(0, 0.05, 30), "ssim": base / 40 + 0.01},
        "resesop": {"psnr": base + 0.3, "ssim": base / 40 + 0.02},
    }
    check = get(check_conclusions(results, "parallel"), "methods_beat_fbp")
    assert check["verdict"] == "holds" and check["counts"]["holds"] == 4


@pytest.mark.parametrize(
    ("change", "verdict"),
    [
        ({}, "holds"),
        ({"dremel": (27.0, 0.829)}, "does not hold"),  # Dremel below FBP in PSNR
        ({"dremel": (27.94, 0.829)}, "undecided"),  # Dremel equal to FBP in PSNR, within noise
    ],
)
def test_methods_beat_fbp(change, verdict):
    means = paper_like() | change
    check = get(check_conclusions(table(means), "parallel"), "methods_beat_fbp")
    assert check["verdict"] == verdict
    assert check["paper_verdict"] == "holds"


def test_unet_claims_hold_and_fail():
    checks = check_conclusions(table(paper_like()), "parallel")
    for claim in ("unet_largest_gain", "unet_gain_largest_on_resesop", "ciunet_res_best_inn"):
        assert get(checks, claim)["verdict"] == "holds", claim
    worse = paper_like() | {"dremel+unet": (30.0, 0.980)}  # below dremel+cinn (30.69) and below dremel
    checks = check_conclusions(table(worse), "parallel")
    assert get(checks, "unet_largest_gain")["verdict"] == "does not hold"
    bad = [c for c in get(checks, "unet_largest_gain")["comparisons"] if c["verdict"] == "does not hold"]
    assert {c["label"] for c in bad} == {
        "dremel+unet > dremel+cinn",
        "dremel+unet > dremel+cinn-res",
        "dremel+unet > dremel+ciunet-res",
    }
    # our raw eta rows are extra inputs: the UNet must raise them too
    extra = paper_like() | {"resesop_eta0.8": (38.5, 0.9)}
    assert get(check_conclusions(table(extra), "parallel"), "unet_improves_inputs")["verdict"] == "does not hold"


def test_best_row_and_best_inn():
    means = paper_like() | {"resesop_eta0.8+unet": (38.5, 0.995)}  # beats RESESOP + UNet
    checks = check_conclusions(table(means), "parallel")
    assert get(checks, "resesop_unet_best")["verdict"] == "does not hold"
    assert get(checks, "resesop_unet_best")["paper_verdict"] == "undecided"  # the paper's SSIM tie 0.993 / 0.993
    means = paper_like() | {"resesop+cinn-res": (34.5, 0.990)}
    best_inn = get(check_conclusions(table(means), "parallel"), "ciunet_res_best_inn")
    assert best_inn["verdict"] == "does not hold"
    assert {c["label"] for c in best_inn["comparisons"] if c["verdict"] == "does not hold"} == {
        "resesop+ciunet-res > resesop+cinn-res"
    }


def test_input_mixing_claim():
    check = get(check_conclusions(table(paper_like()), "parallel"), "resesop_trained_lose_most[unet]")
    assert check["verdict"] == "holds" and check["paper_verdict"] == "holds" and not check["missing"]
    # a RESESOP-trained UNet that transfers as well as the others
    robust = paper_like() | {"fbp+unet@resesop": (32.5, 0.985), "dremel+unet@resesop": (37.5, 0.99)}
    check = get(check_conclusions(table(robust), "parallel"), "resesop_trained_lose_most[unet]")
    assert check["verdict"] == "does not hold"
    # a missing mixing row is named, not silently left out of the mean
    partial = {k: v for k, v in paper_like().items() if k != "dremel+unet@fbp"}
    check = get(check_conclusions(table(partial), "parallel"), "resesop_trained_lose_most[unet]")
    assert check["missing"] == ["dremel+unet@fbp"] and len(check["comparisons"]) == 2  # only the Dremel-trained pair
    # no mixing rows for the CiNN: not applicable, with the rows it needed
    cinn = get(check_conclusions(table(paper_like()), "parallel"), "resesop_trained_lose_most[cinn]")
    assert cinn["verdict"] == "not applicable" and "fbp+cinn@resesop" in cinn["missing"]


def test_training_seed_spread():
    x = np.linspace(25, 35, 10)
    fbp = {"psnr": x, "ssim": x / 40}

    def seeds(offsets):
        return {
            "psnr": np.stack([x + o for o in offsets]),
            "ssim": np.stack([x / 40 + 0.01 + o / 100 for o in offsets]),
        }

    # per-image difference constant 1.5 dB on average; seed means 0, 1, 2 dB apart: s.e. sqrt(1/3)
    check = get(
        check_conclusions({"fbp": fbp, "fbp+unet": seeds([0.5, 1.5, 2.5])}, "unperturbed"),
        "unet_and_residual_improve_fbp",
    )
    comp = next(c for c in check["comparisons"] if c["metric"] == "psnr")
    assert comp["diff"] == pytest.approx(1.5) and comp["se"] == pytest.approx(np.sqrt(1 / 3)) and comp["seeds"] == 3
    assert comp["verdict"] == "holds"
    # the same mean gain with seeds 0, 4, 8 dB apart (s.e. 2.31) is within the training spread
    check = get(
        check_conclusions({"fbp": fbp, "fbp+unet": seeds([-2.5, 1.5, 5.5])}, "unperturbed"),
        "unet_and_residual_improve_fbp",
    )
    comp = next(c for c in check["comparisons"] if c["metric"] == "psnr")
    assert comp["diff"] == pytest.approx(1.5) and comp["verdict"] == "undecided"
    assert check["missing"] == ["fbp+cinn-res", "fbp+ciunet-res"]


def test_settings_and_not_applicable():
    assert {c["claim"] for c in check_conclusions({}, "fan")} == {i for i, v in CLAIMS.items() if "fan" in v[0]}
    for c in check_conclusions({}, "unperturbed") + check_conclusions({}, "fan") + check_conclusions({}, "parallel"):
        assert c["verdict"] == "not applicable" and c["missing"]
    # the paper's fan table has no FBP; ours does
    fan = table({"fbp": (25.0, 0.5), "dremel": (30.4, 0.78), "resesop": (30.1, 0.86)})
    check = get(check_conclusions(fan, "fan"), "methods_beat_fbp")
    assert check["verdict"] == "holds" and check["paper_verdict"] == "not applicable"


def test_paper_own_tables():
    parallel = {c["claim"]: c["verdict"] for c in paper_conclusions("parallel")}
    assert parallel["methods_beat_fbp"] == "holds"
    assert parallel["residual_beats_nonresidual"] == "does not hold"  # FBP + CiNNRes 28.82 < FBP + CiNN 30.60
    fan = {c["claim"]: c for c in paper_conclusions("fan")}
    assert fan["unet_improves_inputs"]["verdict"] == "does not hold"  # Dremel + UNet 30.37 < Dremel 30.41
    comp = next(c for c in fan["unet_improves_inputs"]["comparisons"] if c["verdict"] == "does not hold")
    assert comp["label"] == "dremel+unet > dremel" and comp["diff"] == pytest.approx(-0.04)
    assert all(c["verdict"] == "holds" for c in paper_conclusions("unperturbed"))


def test_output_is_json_and_markdown():
    checks = check_conclusions(table(paper_like()), "parallel", k=2.5)
    assert all(c["verdict"] in VERDICTS and c["paper_verdict"] in VERDICTS for c in checks)
    json.dumps(checks, allow_nan=False)
    text = format_conclusions(checks, k=2.5)
    assert len([line for line in text.splitlines() if line.startswith("| parallel |")]) == len(checks)
    assert "2.5 standard errors" in text
    single = {"fbp": {"psnr": [30.0], "ssim": [0.5]}, "dremel": {"psnr": [31.0], "ssim": [0.6]}}
    one = get(check_conclusions(single, "parallel"), "methods_beat_fbp")
    assert one["verdict"] == "undecided" and one["comparisons"][0]["se"] is None  # no spread from one image
    json.dumps(one, allow_nan=False)


@pytest.mark.parametrize(
    ("results", "kwargs", "match"),
    [
        ({"fbp": {"psnr": [1.0, 2.0], "ssim": [0.1, 0.2]}, "dremel": {"psnr": [1.0], "ssim": [0.1]}}, {}, "different"),
        ({"fbp": {"psnr": [1.0, np.nan], "ssim": [0.1, 0.2]}}, {}, "finite"),
        ({"fbp": {"psnr": [1.0, 2.0]}}, {}, "ssim"),
        ({}, {"k": -1.0}, "k = -1"),
        ({}, {"setting": "cone"}, "unknown setting"),
    ],
)
def test_bad_input(results, kwargs, match):
    setting = kwargs.pop("setting", "parallel")
    with pytest.raises(NanoctError, match=match):
        check_conclusions(results, setting, **kwargs)
