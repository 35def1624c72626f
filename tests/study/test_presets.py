"""The study presets of ``nanoct reproduce --preset``: the tiny study pinned, ``tiny-quick`` beside it."""

import json
from dataclasses import replace
from pathlib import Path

import pytest

from nanoct.core.errors import NanoctError
from nanoct.learn.models import table_order
from nanoct.study.config import (
    STUDIES,
    STUDY_PRESETS,
    Study,
    preset_models,
    preset_names_all,
    preset_setting,
    preset_study,
)
from nanoct.study.plan import plan_study

#: The tiny study as its tables in docs/results.md were made: any change here changes those tables.
TINY = Study(
    n=200,
    split_fractions=(0.8, 0.1, 0.1),
    epochs={"unet": 40, "cinn": 24, "cinn-res": 32, "ciunet": 24, "ciunet-res": 32},
    lr={"cinn": 1e-3, "cinn-res": 1e-3, "ciunet": 1e-3, "ciunet-res": 1e-3},
    scheduler={"ciunet": "cosine"},
    model_kwargs={
        "unet": {"out_bias": -7.0, "skip_channels": 32},
        "cinn": {"blocks_per_scale": 2, "conditional_scale": "location", "location_weight": 1000.0},
        "cinn-res": {"blocks_per_scale": 2, "conditional_scale": "location"},
        "ciunet": {
            "blocks_per_scale": 1,
            "conditional_scale": "location",
            "cond_channels": [16, 16, 32, 32, 64],
            "location_weight": 1000.0,
        },
        "ciunet-res": {"blocks_per_scale": 1, "conditional_scale": "location", "cond_channels": [16, 16, 32, 32, 64]},
    },
    n_samples=32,
    mixing=("unet",),
    precision="auto",
    antithetic=True,
    n_calibration=100,
)


def test_the_tiny_study_is_pinned():
    assert STUDIES["tiny"] == TINY
    assert preset_study("tiny-parallel") is STUDIES["tiny"] and preset_models("tiny-parallel") == table_order()
    setting = preset_setting("tiny-parallel", True, None, TINY.mixing)
    assert setting.preset == "tiny-parallel" and setting.out == Path("runs/tiny-parallel")
    assert list(setting.recons) == ["fbp", "dremel", "resesop", "resesop_eta0.8", "resesop_eta1.2"]
    assert setting.train_inputs == tuple(setting.recons) and setting.name is None and setting.note == ""


def test_tiny_quick_differs_from_the_tiny_study_only_where_declared():
    quick = STUDY_PRESETS["tiny-quick"]
    assert "tiny-quick" in preset_names_all() and preset_study("tiny-quick") is quick.study
    # the same data set (n, splits, seed), architectures, learning rates, schedules, sampling and precision
    assert replace(quick.study, epochs=TINY.epochs, n_calibration=TINY.n_calibration) == TINY
    assert quick.study.n_calibration == 0  # intervals fitted on the validation split
    assert quick.study.epochs == {"unet": 20, "cinn": 8, "cinn-res": 8, "ciunet": 8, "ciunet-res": 8}
    assert all(quick.study.epochs[m] < TINY.epochs[m] for m in table_order())
    assert preset_models("tiny-quick") == quick.models == ("unet", "ciunet-res")
    tiny = preset_setting("tiny-parallel", True, None, TINY.mixing)
    setting = preset_setting("tiny-quick", True, None, quick.study.mixing)
    assert setting.preset == "tiny-parallel" and setting.paper == tiny.paper == "parallel"
    assert setting.out == Path("runs/tiny-quick") and setting.name == "tiny-quick"
    assert setting.recons == {k: tiny.recons[k] for k in ("fbp", "dremel", "resesop")}
    assert setting.train_inputs == ("fbp", "dremel", "resesop")
    assert "Quick first-run scale" in setting.note and "not the reproducible reference" in setting.note
    assert preset_setting("tiny-quick", False, None, ()).out == Path("runs/tiny-quick-nomotion")
    with pytest.raises(NanoctError, match="tiny-quick"):
        preset_study("tiny-slow")


def test_tiny_quick_plan_counts_its_jobs_and_is_a_fraction_of_the_tiny_study():
    quick = plan_study(None, preset="tiny-quick", study=replace(STUDY_PRESETS["tiny-quick"].study, precision="fp32"))
    tiny = plan_study(None, preset="tiny-parallel", study=replace(TINY, precision="fp32"))
    # no calibration set; 3 first reconstructions; UNet and CiUNetRes on each; the UNet mixed over the 3 inputs
    assert [p.jobs for p in quick] == [200, 3 * 200, 6, 6 + 3 * 2, 1]
    assert [p.jobs for p in tiny] == [300, 5 * 200 + 5 * 100, 25, 25 + 5 * 4, 1]
    seconds = {p.stage: p.seconds for p in quick}
    assert seconds["training"] < 0.2 * next(p.seconds for p in tiny if p.stage == "training")
    assert sum(seconds.values()) < 10 * 60


@pytest.mark.slow
def test_reproduce_tiny_quick_at_a_toy_scale_says_what_it_is(tmp_path):
    from nanoct.study.runner import reproduce_study

    toy = replace(
        STUDY_PRESETS["tiny-quick"].study,
        n=12,
        split_fractions=(0.5, 0.25, 0.25),
        epochs={"unet": 1},
        model_kwargs={"unet": {"channels": (4, 4, 4, 4, 4)}},
    )
    out = tmp_path / "quick"
    report = reproduce_study("tiny-quick", out=out, models=("unet",), study=toy, workers=0, progress=False)
    text = report.read_text()
    assert text.startswith("# nanoct study: tiny-quick (tiny-parallel geometry)")
    assert "Quick first-run scale (`tiny-quick`)" in text
    results = json.loads((out / "report" / "evaluation.json").read_text())["results"]
    assert set(results) == {f"{i}{m}" for i in ("fbp", "dremel", "resesop") for m in ("", "+unet")} | {
        f"{i}+unet@{t}" for i in ("fbp", "dremel", "resesop") for t in ("fbp", "dremel", "resesop") if i != t
    }
    assert not (out / "calibration").exists()
