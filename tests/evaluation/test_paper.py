"""The paper's typed-in numbers: spot values copied by hand, structure, lookups, comparison table."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest

from nanoct.core.errors import NanoctError
from nanoct.evaluation.paper import (
    INPUTS,
    MODELS,
    TABLES,
    comparison_rows,
    format_comparison,
    format_mixing_comparison,
    paper_entry,
    paper_lookup,
    paper_mixing,
    paper_rows,
    paper_value,
)
from nanoct.names import SETTINGS

# Copied by hand from the LaTeX tables (not from nanoct.evaluation.paper), so a typo in either shows.
# (setting, input, model, train_input): (psnr mean, psnr std, ssim mean, ssim std)
HAND_COPIED = {
    ("parallel", "fbp", None, None): (27.94, 2.81, 0.510, 0.103),
    ("parallel", "resesop", "unet", None): (38.17, 3.36, 0.993, 0.004),
    ("parallel", "resesop_eta1.2", "ciunet-res", None): (30.13, 2.49, 0.974, 0.011),
    ("parallel", "resesop_eta0.8", "cinn", None): (31.89, 2.16, 0.562, 0.012),
    ("fan", "dremel", "ciunet-res", None): (31.01, 3.26, 0.974, 0.010),
    ("fan", "resesop", "cinn", None): (31.19, 2.19, 0.506, 0.015),
    ("fan", "dremel", None, None): (30.41, 3.01, 0.778, 0.117),
    ("unperturbed", "fbp", "unet", None): (71.76, 3.18, 0.999, 9.027e-6),
    ("unperturbed", "resesop", None, None): (43.96, 2.34, 0.986, 0.006),
    ("unperturbed", "fbp", "ciunet-res", None): (63.53, 1.27, 0.999, 1.784e-5),
    # input mixing: model trained on train_input, applied to input
    ("parallel", "fbp", "unet", "resesop"): (26.41, 2.21, 0.958, 0.011),
    ("parallel", "fbp", "cinn-res", "resesop_eta0.8"): (28.22, 2.91, 0.584, 0.097),
    ("parallel", "resesop_eta0.8", "ciunet-res", "resesop"): (34.13, 2.88, 0.984, 0.006),
    ("parallel", "resesop_eta1.2", "ciunet", "dremel"): (21.38, 1.69, 0.681, 0.017),
    ("parallel", "resesop_eta0.8", "cinn", "fbp"): (31.47, 2.02, 0.645, 0.010),
}


@pytest.mark.parametrize("key", list(HAND_COPIED), ids=lambda k: "/".join(str(x) for x in k))
def test_hand_copied_values(key):
    assert tuple(paper_value(*key)) == pytest.approx(HAND_COPIED[key], rel=1e-12, abs=0)


def test_tables_are_complete():
    parallel = paper_rows("parallel")
    assert len(parallel) == 3 + 5 * 5
    assert {(e.input, e.model) for e in parallel} == {(i, None) for i in ("fbp", "dremel", "resesop")} | {
        (i, m) for i in INPUTS for m in MODELS
    }
    fan = paper_rows("fan")
    assert {(e.input, e.model) for e in fan} == {(i, m) for i in ("dremel", "resesop") for m in (None, *MODELS)}
    unperturbed = paper_rows("unperturbed")
    assert {(e.input, e.model) for e in unperturbed} == {(i, None) for i in ("fbp", "dremel", "resesop")} | {
        ("fbp", m) for m in MODELS
    }
    for model in MODELS:
        cells = paper_mixing(model)
        assert {(e.train_input, e.input) for e in cells} == {(t, i) for t in INPUTS for i in INPUTS}
        assert len(cells) == 25
        for e in cells:  # the diagonal repeats the main table's row
            if e.input == e.train_input:
                assert e.value == paper_value("parallel", e.input, model)
                assert e.value == paper_value("parallel", e.input, model, e.input)


def test_every_entry_is_valid():
    entries = [e for s in SETTINGS for e in paper_rows(s)] + [e for m in MODELS for e in paper_mixing(m)]
    assert len(entries) == 28 + 12 + 8 + 5 * 25
    for e in entries:
        assert e.setting in SETTINGS and e.input in INPUTS
        assert e.model is None or e.model in MODELS
        assert e.train_input is None or e.train_input in INPUTS
        assert e.table in TABLES.values()
        psnr_mean, psnr_std, ssim_mean, ssim_std = e.value
        assert 15 < psnr_mean < 80 and 0 < psnr_std < 5
        assert 0.4 < ssim_mean <= 1 and 0 < ssim_std < 0.2
        assert paper_lookup(e.setting, e.name).value == e.value
        json.dumps(e.to_dict())
    for s in SETTINGS:
        names = [e.name for e in paper_rows(s)]
        assert len(names) == len(set(names))
    assert paper_entry("fan", "dremel").table.label == "tab:fan_perturbed_quantitative"
    assert paper_entry("parallel", "fbp", "unet", "dremel").table.label == "tab:parallel_perturbed_quantitative_mixing"
    assert paper_entry("parallel", "fbp", "cinn", "dremel").table.label is None
    assert "cinnres" in paper_entry("parallel", "fbp", "cinn-res", "dremel").table.cite()


def test_missing_rows_and_bad_keys():
    assert paper_value("fan", "fbp") is None  # the fan table has no FBP
    assert paper_value("parallel", "resesop_eta0.8") is None  # no raw eta rows
    assert paper_value("unperturbed", "dremel", "unet") is None  # networks on FBP only
    assert paper_value("fan", "dremel", "unet", "resesop") is None  # mixing: parallel only
    assert paper_lookup("parallel", "kaczmarz") is None
    assert paper_lookup("parallel", "fbp+unet@resesop_eta0.9") is None
    assert paper_lookup("parallel", "fbp+unet@dremel").value.psnr_mean == 29.53
    for bad in (("cone", "fbp"), ("parallel", "sart"), ("parallel", "fbp", "vnet")):
        with pytest.raises(NanoctError, match="unknown"):
            paper_value(*bad)
    with pytest.raises(NanoctError, match="needs a model"):
        paper_value("parallel", "fbp", None, "dremel")
    with pytest.raises(NanoctError, match="unknown model"):
        paper_mixing("resnet")


def _scores(psnr, ssim, n=10):
    return {"psnr_mean": psnr, "psnr_std": 1.0, "ssim_mean": ssim, "ssim_std": 0.01, "n": n}


def test_comparison_rows_and_gains():
    results = {
        "fbp": _scores(28.0, 0.60),
        "fbp+unet": _scores(31.5, 0.95),
        "resesop_eta0.8": _scores(29.0, 0.80),
        "resesop+unet@fbp": _scores(27.0, 0.90),
    }
    rows = {r["name"]: r for r in comparison_rows(results, "parallel", mixing=True)}
    json.dumps(list(rows.values()))
    r = rows["fbp+unet"]
    assert r["gain_ours"]["psnr"] == pytest.approx(3.5) and r["gain_ours"]["ssim"] == pytest.approx(0.35)
    assert r["gain_paper"]["psnr"] == pytest.approx(33.04 - 27.94)
    assert r["gain_paper"]["ssim"] == pytest.approx(0.984 - 0.510)
    assert rows["resesop_eta0.8"]["paper"] is None and rows["resesop_eta0.8"]["gain_ours"] is None
    assert rows["dremel"]["ours"] is None and rows["dremel"]["paper"]["psnr_mean"] == 30.98
    assert rows["resesop+unet@fbp"]["paper"]["psnr_mean"] == 32.06  # trained on FBP, applied to RESESOP
    assert rows["resesop+unet@fbp"]["gain_ours"]["psnr"] is None  # our raw resesop row is missing
    assert rows["resesop+unet@fbp"]["gain_paper"]["psnr"] == pytest.approx(32.06 - 30.65)
    assert len(rows) == 28 + 1 + 5 * 20  # paper rows, our extra raw eta row, the off-diagonal mixing cells
    names = list(rows)
    assert names[:3] == ["fbp", "dremel", "resesop"] and names.index("fbp+unet") < names.index("fbp+cinn")
    fan = {r["name"]: r for r in comparison_rows(results, "fan")}
    assert fan["fbp"]["paper"] is None and fan["fbp+unet"]["gain_paper"] is None
    assert "resesop+unet@fbp" not in fan


def test_format_comparison():
    text = format_comparison({"fbp": _scores(28.0, 0.6), "fbp+unet": _scores(31.5, 0.95, n=7)}, "parallel", "T")
    lines = text.splitlines()
    assert lines[0] == "### T"
    row = next(line for line in lines if line.startswith("| fbp+unet |"))
    assert row == (
        "| fbp+unet | 31.50 ± 1.00 | 33.04 ± 3.87 | +3.50 | +5.10 "
        "| 0.950 ± 0.010 | 0.984 ± 0.008 | +0.350 | +0.474 | 7 |"
    )
    assert "tab:parallel_perturbed_quantitative" in text
    assert all(line.count("|") == 11 for line in lines if line.startswith("|"))


# The whole transcription against the LaTeX source, where it is available:
# NANOCT_PAPER_TEX=/path/to/paper.tex pytest tests/test_paper.py
# the paper's LaTeX source: $NANOCT_PAPER_TEX, else the project's shared/ beside the checkout (where CI has it)
_SHARED_TEX = Path(__file__).resolve().parents[2] / "shared" / "seed" / "000_97f2f407435e89fd.txt"
_TEX = os.environ.get("NANOCT_PAPER_TEX") or (str(_SHARED_TEX) if _SHARED_TEX.is_file() else None)
_NUM = r"([0-9.]+)\s*\\pm\s*([0-9.]+)(?:\s*\\cdot\s*10\^\{(-?\d+)\})?"
_TEX_INPUTS = {
    "FBP": "fbp",
    "Dremel": "dremel",
    "RESESOP": "resesop",
    "RESESOP ($\\eta=0$)": "resesop",
    "RESESOP 1.2$\\eta$": "resesop_eta1.2",
    "RESESOP 0.8$\\eta$": "resesop_eta0.8",
}
_TEX_MODELS = {"Id": None, "UNet": "unet", "CiNN": "cinn", "CiNNRes": "cinn-res", "CiUNet": "ciunet"}
_TEX_MODELS["CiUNetRes"] = "ciunet-res"


def _cells(line):
    return [(float(m[1]), float(m[2]) * (10 ** int(m[3]) if m[3] else 1)) for m in re.finditer(_NUM, line)]


@pytest.mark.skipif(not _TEX or not Path(_TEX).is_file(), reason="set NANOCT_PAPER_TEX to the paper's LaTeX source")
def test_every_value_against_latex_source():
    files = dict(re.findall(r"%% file: (\S+)\n(.*?)(?=\n%% file:|\Z)", Path(_TEX).read_text(), re.S))
    checked = 0
    for setting in SETTINGS:
        model, found = None, []
        for line in files[TABLES[setting].files[0]].splitlines():
            if m := re.search(r"F_\\theta\$?\s*=\s*(\w+)", line):
                model = _TEX_MODELS[m[1]]
            elif len(c := _cells(line)) == 2:
                label = line.split("&")[0].strip()
                inp, _, net = label.partition(" + ")
                found.append(((_TEX_INPUTS[inp], _TEX_MODELS[net] if net else model), (*c[0], *c[1])))
        assert [(e.input, e.model) for e in paper_rows(setting)] == [k for k, _ in found]
        for key, nums in found:
            assert tuple(paper_value(setting, *key)) == pytest.approx(nums, rel=1e-9)
            checked += 1
    for model in MODELS:
        for j, path in enumerate(TABLES[f"mixing-{model}"].files):
            lines = files[path].splitlines()
            head = next(line for line in lines if "Reconstruction}" in line)
            cols = [_TEX_INPUTS[c.strip().rstrip("\\").strip()] for c in head.split("&")[1:]]
            for line in lines:
                if len(c := _cells(line)) == 5:
                    train = _TEX_INPUTS[line.split("&")[0].strip()]
                    for col, pair in zip(cols, c):
                        assert tuple(paper_value("parallel", col, model, train))[2 * j : 2 * j + 2] == pair
                        checked += 1
    assert checked == 48 + 250


def test_format_mixing_comparison():
    results = {"fbp+unet": _scores(31.5, 0.95), "resesop+unet@fbp": _scores(30.25, 0.9)}
    text = format_mixing_comparison(results, "unet")
    rows = [line for line in text.splitlines() if line.startswith("| fbp |")]
    assert len(rows) == 2  # PSNR and SSIM tables
    psnr_cells = [c.strip() for c in rows[0].strip("|").split("|")]
    # trained on FBP: applied to FBP (ours 31.50, paper 33.04), to RESESOP (ours 30.25, paper 32.06)
    assert psnr_cells == ["fbp", "31.50 (33.04)", "– (31.16)", "30.25 (32.06)", "– (31.37)", "– (32.68)"]
    assert rows[1].split("|")[2].strip() == "0.950 (0.984)"
    assert "tab:parallel_perturbed_quantitative_mixing" in text
    assert "cinnres" in format_mixing_comparison({}, "cinn-res")
    with pytest.raises(NanoctError, match="unknown model"):
        format_mixing_comparison({}, "vnet")
