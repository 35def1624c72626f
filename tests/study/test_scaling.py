"""The data-scaling study: its units, plan and, at toy size, the whole run with resume and report."""

import json
from dataclasses import replace

import pytest

from nanoct.core.errors import NanoctError
from nanoct.learn.data import ReconDataset
from nanoct.learn.train import resolve_precision
from nanoct.study import scaling as scaling_module
from nanoct.study.config import STUDIES
from nanoct.study.scaling import plan_scaling, run_scaling
from nanoct.study.scaling_config import ScalingStudy, scaling_units

TOY = ScalingStudy(
    sizes=(4, 8),
    seeds=(2, 1),
    steps=2,
    long_factor=2,
    n_val=2,
    n_test=3,
    inputs=("fbp", "dremel"),
    base=replace(
        STUDIES["tiny"],
        model_kwargs={
            "unet": {"channels": (4, 4, 4, 4, 4), "skip_channels": 4, "out_bias": -7.0},
            "ciunet-res": {"n_scales": 3, "blocks_per_scale": 1, "cond_channels": [4, 4, 4]},
        },
        n_samples=2,
    ),
)


def test_default_units_cover_the_curve_seed_by_seed():
    study = ScalingStudy()
    units = scaling_units(study)
    assert len(units) == 2 * 3 * (3 + 2 + 2) + 2 * 3  # sizes x seeds, plus one seed at 4x the steps
    assert len({u.name for u in units}) == len({u.run for u in units}) == len(units)
    first = units[: 2 * 3 * 3]  # seed 0 of every size comes first
    assert {u.seed for u in first} == {0} and {u.n_train for u in first} == {160, 640, 2560}
    assert [u.steps for u in units[-6:]] == [2560] * 6 and {u.n_train for u in units[-6:]} == {2560}
    assert {(u.n_train, u.seed) for u in units if u.steps == 640} == {
        (160, 0),
        (160, 1),
        (160, 2),
        (640, 0),
        (640, 1),
        (2560, 0),
        (2560, 1),
    }
    # the same number of steps at every size: 64, 16 and 4 epochs of batch 16
    assert [u.epochs(16) for u in units[:18:6]] == [64, 16, 4]
    assert units[0].name == "fbp+unet%n160x640" and units[-1].name == "resesop+ciunet-res%n2560x2560"
    assert study.n == 2680 and study.split_fractions[0] == pytest.approx(2560 / 2680)


def test_bad_definitions_are_refused():
    with pytest.raises(NanoctError, match="same length"):
        ScalingStudy(sizes=(160, 640), seeds=(3,))
    with pytest.raises(NanoctError, match="unknown input"):
        ScalingStudy(inputs=("kaczmarz",))
    with pytest.raises(NanoctError, match="must be positive"):
        ScalingStudy(steps=0)


def test_plan_adds_the_measured_costs():
    study = ScalingStudy(sizes=(16, 32), seeds=(1, 1), steps=4, long_seeds=0, n_val=2, n_test=3, models=("unet",))
    costs = {"generate": 0.5, "recon/fbp": 0.1, "recon/dremel": 1.0, "recon/resesop": 0.2}
    costs |= {"step/unet": 2.0, "forward/unet": 0.01}
    plan = plan_scaling(study, None, costs)
    rows = {r["stage"]: r for r in plan["rows"]}
    assert rows["data"]["seconds"] == pytest.approx(37 * 0.5)
    assert rows["reconstruction dremel"]["seconds"] == pytest.approx(37 * 1.0)
    # 3 inputs x 2 sizes, 4 steps each, 4 and 2 epochs of validation (2 images) and 3 test images
    epochs = 4 + 2
    expected = 3 * (2 * 4 * 2.0 + epochs * 2 * 0.01 + 2 * 3 * 0.01)
    assert rows["units at 4 steps"]["seconds"] == pytest.approx(expected)
    assert plan["total"] == pytest.approx(sum(r["seconds"] for r in plan["rows"]))


def test_plan_prices_remaining_units_by_finished_ones(tmp_path):
    study = ScalingStudy(sizes=(16, 32), seeds=(1, 1), steps=4, long_seeds=0, n_val=2, n_test=3, models=("unet",))
    costs = {"generate": 0.5, "recon/fbp": 0.1, "recon/dremel": 1.0, "recon/resesop": 0.2}
    costs |= {"step/unet": 2.0, "forward/unet": 0.01}
    (tmp_path / "seconds.json").write_text(json.dumps({"unit/unet-fbp-n16x4": 40.0, "data": 3.0}))
    plan = plan_scaling(study, tmp_path, costs)
    assert plan["unit_step"] == {"unet": 10.0}
    assert next(r for r in plan["rows"] if r["stage"] == "units at 4 steps")["seconds"] == pytest.approx(6 * 4 * 10.0)


@pytest.mark.slow
def test_toy_study_runs_resumes_and_reports(tmp_path, monkeypatch):
    out = tmp_path / "scaling"
    units = scaling_units(TOY)
    real = scaling_module._run_unit
    calls = []

    def killed_after_three(*args, **kwargs):
        if len(calls) == 3:
            raise KeyboardInterrupt  # a kill in the middle of the curve
        calls.append(args[3])
        return real(*args, **kwargs)

    monkeypatch.setattr(scaling_module, "_run_unit", killed_after_three)
    with pytest.raises(KeyboardInterrupt):
        run_scaling(out, TOY, workers=0, progress=False)
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.pt")}
    assert calls == units[:3]
    assert f"unit/{units[3].run}" in json.loads((out / "seconds.json").read_text())  # interrupted: timed too
    monkeypatch.setattr(scaling_module, "_run_unit", real)
    report = run_scaling(out, TOY, workers=0, progress=False)
    # the three finished units were skipped, the rest ran
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    for unit in units:
        config = json.loads((out / "runs" / unit.run / "config.json").read_text())
        assert config["data"]["train"] == unit.n_train and config["max_steps"] == unit.steps
        assert config["scheduler"] == "cosine" and config["precision"] == resolve_precision("auto", "cpu")
        log = (out / "runs" / unit.run / "log.csv").read_text().splitlines()
        assert log[-1].split(",")[0] == str(unit.epochs(16))  # every run ends at its step budget
    # nested training sets: the 4 images are the first 4 of the 8
    small, big = (ReconDataset(out / "data", "fbp", "train", limit=k) for k in (4, 8))
    assert list(small.indices) == list(big.indices[:4])
    summary = json.loads((out / "report.json").read_text())
    assert summary["complete"] and [(p["n_train"], p["steps"]) for p in summary["points"]] == [(4, 2), (8, 2), (8, 4)]
    first = summary["points"][0]
    assert len(first["gains"]["fbp+unet"]["psnr"]) == 2 and first["gains"]["fbp+unet"]["psnr_paper"] > 0
    assert any(c["claim"] == "unet_largest_gain" for c in first["checks"])
    text = report.read_text()
    assert "complete" in text and "| FBP + UNet | PSNR gain dB |" in text and "![PSNR gain" in text
    assert "| Dremel + CiUNetRes |" in text and "(epoch " in text  # the training diagnostics
    assert (out / "scaling.png").read_bytes()[:4] == b"\x89PNG"
    # a rerun trains nothing; another definition in the same folder is refused
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.pt")}
    run_scaling(out, TOY, workers=0, progress=False)
    assert {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.pt")} == stamps
    with pytest.raises(NanoctError, match="another definition"):
        run_scaling(out, replace(TOY, steps=3), workers=0, progress=False)
