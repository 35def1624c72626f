"""The whole study on a toy scale: every stage runs, the report is complete, a rerun is a no-op."""

import json

import numpy as np
import pytest

import nanoct.learn.calibration as cal_mod
import nanoct.learn.predict as predict_mod
from nanoct.core.errors import NanoctError
from nanoct.io.store import DataStore
from nanoct.learn.train import resolve_precision
from nanoct.study.config import Study, calibration_seed
from nanoct.study.runner import reproduce_scale, reproduce_study

TOY = Study(
    n=12,
    split_fractions=(0.5, 0.25, 0.25),
    epochs={"unet": 1, "cinn-res": 1},
    model_kwargs={
        "unet": {"channels": (4, 4, 4, 4, 4)},
        "cinn-res": dict(
            n_scales=3,
            blocks_per_scale=1,
            fc_dim=8,
            fc_blocks=1,
            cond_channels=4,
            cond_width=4,
            fc_cond_dim=8,
            hidden_ratio=1.0,
        ),
    },
    n_samples=3,
    mixing=("unet",),
    antithetic=True,
    scheduler={"cinn-res": "cosine"},
    precision="auto",
    n_calibration=4,
)


@pytest.mark.slow
def test_reproduce_toy_study(tmp_path, monkeypatch):
    out = tmp_path / "study"
    report = reproduce_study(
        "tiny-parallel", out=out, models=("unet", "cinn-res"), study=TOY, workers=0, progress=False
    )
    text = report.read_text()
    results = json.loads((out / "report" / "evaluation.json").read_text())["results"]
    inputs = ["fbp", "dremel", "resesop", "resesop_eta0.8", "resesop_eta1.2"]
    for i in inputs:
        assert i in results and f"{i}+unet" in results and f"{i}+cinn-res" in results
        assert results[f"{i}+cinn-res"]["n"] == 3 and "uncertainty" in results[f"{i}+cinn-res"]
    assert "fbp+unet@resesop" in results and "fbp+cinn-res@resesop" not in results  # mixing for unet only
    assert "rows = trained on" in text and "| fbp+cinn-res | support |" in text
    assert "learning-rate schedule cinn-res cosine (others: their model's default)" in text
    # the calibration set: its own seed, all validation, reconstructed by every input the networks train on
    cal = DataStore.open(out / "calibration")
    assert cal.seed == calibration_seed(0) and cal.indices("val").size == 4 and cal.n == 4
    assert sorted(cal.reconstruction_names()) == sorted(inputs)
    for i in inputs:  # predict calibrated each invertible run on the calibration set, not the validation split
        r = results[f"{i}+cinn-res"]
        fits = json.loads((out / "runs" / f"cinn-res-{i}" / "calibration.json").read_text())
        (key,) = fits
        assert key == f"best@{(out / 'calibration').resolve()}"
        assert r["guarantee"]["levels"]["0.9"]["multiplier"] == fits[key]["levels"]["0.9"]["multiplier"]
        assert 0 <= r["edge_baseline"]["all"]["intervals"]["0.9"]["coverage"] <= 1
    # the study's schedule reaches the training run (the registry's for cinn-res is "plateau")
    config = json.loads((out / "runs" / "cinn-res-fbp" / "config.json").read_text())
    assert config["scheduler"] == "cosine"
    assert config["precision"] == resolve_precision("auto", "cpu")  # the study's "auto", as this CPU takes it
    fit = json.loads((out / "runs" / "cinn-res-fbp" / "calibration.json").read_text())[key]
    assert fit["reconstruct"] == {"n_samples": 3, "antithetic": True}  # the study's sampling, also in calibration
    for png in (
        "reconstructions.png",
        "reconstructions_unet.png",
        "reconstructions_cinn-res.png",
        "uncertainty_cinn-res.png",
        "reliability.png",
        "training_curves.png",
        "sample.png",
    ):
        assert f"({png})" in text
        assert (out / "report" / png).read_bytes()[:4] == b"\x89PNG"
    # everything is cached: a second run redoes no training and no prediction
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.pt")}
    (out / "report" / ".report.md.tmp-0a1b2c3d").write_text("half a report from a killed run")
    reproduce_study("tiny-parallel", out=out, models=("unet", "cinn-res"), study=TOY, workers=0, progress=False)
    assert {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.pt")} == stamps
    assert not [p.name for p in (out / "report").iterdir() if p.name.startswith(".")]
    # the study folder moved elsewhere resumes there: nothing trained, calibrated or predicted again
    before = json.loads((out / "report" / "evaluation.json").read_text())["results"]
    moved = tmp_path / "moved"
    out.rename(moved)

    def refused(*args, **kwargs):
        raise AssertionError("redone after the folder moved")

    monkeypatch.setattr(cal_mod, "sample_outputs", refused)
    monkeypatch.setattr(predict_mod, "model_from_checkpoint", refused)
    reproduce_study("tiny-parallel", out=moved, models=("unet", "cinn-res"), study=TOY, workers=0, progress=False)
    assert {p: p.stat().st_mtime_ns for p in (moved / "runs").rglob("*.pt")} == {
        moved / p.relative_to(out): t for p, t in stamps.items()
    }
    assert json.loads((moved / "report" / "evaluation.json").read_text())["results"] == before
    params = DataStore.open(moved / "data").reconstruction_params("fbp+cinn-res")
    assert params["run"] == str((moved / "runs" / "cinn-res-fbp").resolve())
    assert params["calibration"]["store"] == str((moved / "calibration").resolve())


def test_jobs_restore_torch_threads():
    """A job run with one thread (fanned-out mode) leaves the process's thread count as it was."""
    import torch

    from nanoct.study.stages import _with_threads

    before = torch.get_num_threads()
    seen: list[int] = []
    _with_threads(1, lambda: seen.append(torch.get_num_threads()))
    _with_threads(2, lambda: seen.append(torch.get_num_threads()))
    assert seen == [1, 2] and torch.get_num_threads() == before
    with pytest.raises(ZeroDivisionError):
        _with_threads(1, lambda: 1 / 0)
    assert torch.get_num_threads() == before


@pytest.mark.slow
def test_dask_client_leaves_environment_as_it_was():
    """Dask's worker settings (OMP_NUM_THREADS=1, ...) do not stay in the calling process."""
    import os

    from nanoct.core.fanout import run_tasks

    before = dict(os.environ)
    assert run_tasks(abs, [0, 1], workers=1, progress=False) == 2
    assert dict(os.environ) == before


@pytest.mark.slow
def test_reproduce_toy_scale_matches_plan(tmp_path):
    """The three settings at a toy scale: the run does the jobs the plan counts; reports in Markdown and HTML."""
    from test_report_html import parse

    from nanoct.io.store import DataStore
    from nanoct.study.plan import plan_study

    out = tmp_path / "scale"
    models = ("unet",)
    report = reproduce_scale("tiny", out=out, models=models, study=TOY, seed=3, seeds=2, workers=0, progress=False)
    plan = plan_study("tiny", models=models, study=TOY, seeds=2)
    for p in plan:
        setting = out / p.setting
        store = DataStore.open(setting / "data")
        assert store.seed == 3
        done = {
            "data": store.n,
            "reconstructions": sum(
                int(store.reconstruction_done(r, np.arange(store.n)).sum())
                for r in store.reconstruction_names()
                if "+" not in r
            ),
            "training": len([d for d in (setting / "runs").iterdir() if (d / "best.pt").exists()]),
            "prediction": len([n for n in store.reconstruction_names() if "+" in n]),
            "report": int((setting / "report" / "report.html").is_file()),
        }
        assert done[p.stage] == p.jobs, (p.setting, p.stage)
        js = json.loads((setting / "report" / "evaluation.json").read_text())
        assert js["setting"] == p.setting and js["conclusions"]
        assert all(len(r["psnr_values"]) == r["n"] for r in js["results"].values())
    seeded = json.loads((out / "parallel" / "report" / "evaluation.json").read_text())["conclusions"]
    assert any(c["seeds"] == 2 for check in seeded for c in check["comparisons"])
    summary = json.loads((out / "report.json").read_text())
    assert list(summary["settings"]) == ["parallel", "fan", "unperturbed"] and summary["environment"]["packages"]
    stages = ["data", "reconstructions", "training", "prediction", "report"]
    for entry in summary["settings"].values():  # every stage timed; the whole run takes at least their sum
        assert list(entry["stage_seconds"]) == stages and all(v >= 0 for v in entry["stage_seconds"].values())
    assert summary["seconds"] >= sum(sum(e["stage_seconds"].values()) for e in summary["settings"].values())
    assert (
        summary["settings"]["fan"]["conclusions"]
        == json.loads((out / "fan" / "report" / "evaluation.json").read_text())["conclusions"]
    )
    text = report.read_text()
    assert "Environment: Python" in text and "torch" in text
    assert "Wall time of this run: " in text and text.count("Wall time of the stages in this run: data ") == 3
    for heading in ("## tiny-parallel", "## tiny-fan", "## tiny-parallel (no motion)", "unet: PSNR [dB], ours (paper)"):
        assert heading in text
    assert "| resesop+unet | " in text and "38.17 ± 3.36" in text  # the paper's RESESOP + UNet next to ours
    assert "The paper's conclusions" in text and "does not hold" in text
    for html in (out / "report.html", out / "parallel" / "report" / "report.html"):
        page = parse(html.read_text())
        tags = [t for t, _ in page.tags]
        assert tags.count("table") >= 3
        assert all(a["src"].startswith("data:image/png;base64,") for t, a in page.tags if t == "img")
    assert "img" in [t for t, _ in parse((out / "parallel" / "report" / "report.html").read_text()).tags]


def test_study_sampling_arguments_are_its_samples_and_antithetic_draws():
    assert TOY.sampling == {"n_samples": 3, "antithetic": True}
    assert Study(n=4, split_fractions=(0.5, 0.25, 0.25)).sampling == {"n_samples": 100}  # the paper's draws


def test_scale_study_differs_from_the_one_setting_study_only_where_declared():
    from dataclasses import replace

    from nanoct.study.config import SCALE_STUDIES, STUDIES, scale_study

    tiny = scale_study("tiny")
    assert tiny is SCALE_STUDIES["tiny"] and scale_study("paper") is STUDIES["paper"]
    one = STUDIES["tiny"]
    assert tiny.epochs["cinn-res"] < one.epochs["cinn-res"] and tiny.epochs["cinn"] < one.epochs["cinn"]
    # only the non-residual networks' architecture arguments differ: no location term, CiUNet in the shift form
    assert {m for m in one.model_kwargs if tiny.model_kwargs[m] != one.model_kwargs[m]} == {"cinn", "ciunet"}
    assert one.model_kwargs["cinn"]["location_weight"] > 0 and "location_weight" not in tiny.model_kwargs["cinn"]
    assert tiny.model_kwargs["ciunet"]["conditional_scale"] == "shift"
    assert one.scheduler == {"ciunet": "cosine"} and tiny.scheduler == {}  # the scale study keeps the registry's
    assert replace(tiny, epochs=one.epochs, scheduler=one.scheduler, model_kwargs=one.model_kwargs) == one
    with pytest.raises(NanoctError, match="unknown scale 'huge'"):
        scale_study("huge")
