"""The whole study on a toy scale: every stage runs, the report is complete, a rerun is a no-op."""

import json
import time

import pytest

from nanoct.reproduce import Study, reproduce_study

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
)


def test_reproduce_toy_study(tmp_path):
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
    for i in inputs:  # predict calibrated each invertible run on its validation split
        r = results[f"{i}+cinn-res"]
        assert (
            r["uncertainty"]["all"]["scale"]
            == json.loads((out / "runs" / f"cinn-res-{i}" / "calibration.json").read_text())["best"]["scale"]
        )
        assert r["edge_baseline"]["all"]["coverage"]["calibrated"] is not None
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
    t = time.perf_counter()
    reproduce_study("tiny-parallel", out=out, models=("unet", "cinn-res"), study=TOY, workers=0, progress=False)
    assert {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.pt")} == stamps
    assert time.perf_counter() - t < 30
    assert not [p.name for p in (out / "report").iterdir() if p.name.startswith(".")]


def test_jobs_restore_torch_threads():
    """A job run with one thread (fanned-out mode) leaves the process's thread count as it was."""
    import torch

    from nanoct.reproduce import _with_threads

    before = torch.get_num_threads()
    seen: list[int] = []
    _with_threads(1, lambda: seen.append(torch.get_num_threads()))
    _with_threads(2, lambda: seen.append(torch.get_num_threads()))
    assert seen == [1, 2] and torch.get_num_threads() == before
    with pytest.raises(ZeroDivisionError):
        _with_threads(1, lambda: 1 / 0)
    assert torch.get_num_threads() == before


def test_dask_client_leaves_environment_as_it_was():
    """Dask's worker settings (OMP_NUM_THREADS=1, ...) do not stay in the calling process."""
    import os

    from nanoct.fanout import run_tasks

    before = dict(os.environ)
    assert run_tasks(abs, [0, 1], workers=1, progress=False) == 2
    assert dict(os.environ) == before
