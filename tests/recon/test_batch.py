"""Batch reconstruction of a store: names, stored parameters, shifts, resume."""

import numpy as np
import pytest

from nanoct.core.errors import NanoctError, StoreError
from nanoct.evaluation.metrics import psnr
from nanoct.io.store import DataStore
from nanoct.recon.batch import reconstruct_dataset


@pytest.mark.slow
def test_resesop_and_dremel_batches(tiny_store):
    path = tiny_store.path
    test = tiny_store.indices("test")
    name = reconstruct_dataset(path, "resesop", split="test", params={"eta_scale": 0.8}, workers=0, progress=False)
    assert name == "resesop_eta0.8"
    store = DataStore.open(path)
    assert store.reconstruction_params(name) == {"method": "resesop", "eta_scale": 0.8}
    assert store.reconstruction_done(name).sum() == len(test)
    reconstruct_dataset(path, "dremel", split="test", params={"n_iter": 4}, workers=0, progress=False)
    others = np.setdiff1d(np.arange(store.n), test)
    assert np.abs(store.read_shifts("dremel", test)).max() > 0 and not store.reconstruction_done("dremel", others).any()
    gt = store.read_phantoms(test)
    for n in ("resesop_eta0.8", "dremel"):
        recos = store.read_reconstruction(n, test)
        assert all(psnr(r, g) > 15 for r, g in zip(recos, gt))
    # same name, other parameters: refused unless --overwrite
    with pytest.raises(StoreError, match="other parameters"):
        reconstruct_dataset(path, "dremel", split="test", params={"n_iter": 5}, workers=0, progress=False)
    reconstruct_dataset(path, "dremel", split="val", params={"n_iter": 5}, overwrite=True, workers=0, progress=False)
    assert store.reconstruction_done("dremel").sum() == len(store.indices("val"))


def test_resume_computes_only_missing_samples(tiny_store, monkeypatch):
    import nanoct.recon.batch as batch

    path = tiny_store.path
    reconstruct_dataset(path, "fbp", split="val", name="fbp_resume", workers=0, progress=False)
    calls = []
    original = batch.reconstruct_sample
    monkeypatch.setattr(batch, "reconstruct_sample", lambda *a, **k: calls.append(1) or original(*a, **k))
    reconstruct_dataset(path, "fbp", split="all", name="fbp_resume", workers=0, progress=False)
    assert len(calls) == tiny_store.n - len(tiny_store.indices("val"))
    calls.clear()
    reconstruct_dataset(path, "fbp", split="all", name="fbp_resume", workers=0, progress=False)
    assert calls == []  # complete: a no-op


def test_bad_method_parameters_are_reported(tiny_store):
    with pytest.raises(NanoctError, match="relaxation"):
        reconstruct_dataset(
            tiny_store.path, "kaczmarz", split="test", params={"relaxation": 3.0}, name="bad", workers=0, progress=False
        )
    with pytest.raises(NanoctError, match="unknown"):
        reconstruct_dataset(tiny_store.path, "art", workers=0, progress=False)


def _snapshot(path):
    return {str(p.relative_to(path)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(path.rglob("*"))}


@pytest.mark.parametrize(
    ("method", "params", "match"),
    [
        ("kaczmarz", {"bogus": 1}, r"--param bogus: not a parameter of --method kaczmarz; accepted: n_iter, "),
        ("kaczmarz", {"relaxation": float("nan")}, r"--param relaxation .*\(0, 2\)"),
        ("fbp", {"filter": "gauss"}, r"--param filter .*ram-lak, hann"),
        ("resesop", {"eta_scale": -1.0}, r"--eta-scale .*\[0, inf\)"),
        ("dremel", {"n_iter": "many"}, "--param n_iter"),
        ("sirt", {}, "--method 'sirt' is unknown; use one of fbp, gridrec, kaczmarz, dremel, resesop"),
    ],
)
def test_bad_parameters_fail_before_any_work(tiny_store, monkeypatch, method, params, match):
    """Checked before an array is created, deleted (even with overwrite) or a worker starts."""
    import nanoct.recon.batch as batch

    path = tiny_store.path
    reconstruct_dataset(path, "fbp", split="test", name="keep", workers=0, progress=False)
    monkeypatch.setattr(batch, "run_tasks", lambda *a, **k: pytest.fail("a worker was started"))
    before = _snapshot(path)
    for name in ("keep", None):
        with pytest.raises(NanoctError, match=match):
            reconstruct_dataset(path, method, params=params, name=name, overwrite=True, workers=2, progress=False)
    assert _snapshot(path) == before


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--method", "resesop", "--eta-scale", "-1"], "error: --eta-scale of --method resesop: eta_scale=-1.0"),
        (["--method", "fbp", "--param", "filter=gauss"], "error: --param filter of --method fbp: filter='gauss'"),
        (["--method", "kaczmarz", "--param", "relaxation=NaN"], "error: --param relaxation of --method kaczmarz"),
        (["--method", "kaczmarz", "--param", "sweeps=3"], "error: --param sweeps: not a parameter"),
        (["--method", "fbp", "--eta-scale", "0.8"], "error: --eta-scale applies to --method resesop only"),
        (["--method", "sirt"], "error: --method 'sirt' is unknown"),
    ],
)
def test_cli_reports_bad_parameters_in_one_line(tiny_store, monkeypatch, capsys, args, message):
    import sys

    from nanoct.cli import main

    before = _snapshot(tiny_store.path)
    monkeypatch.setattr(sys, "argv", ["nanoct", "reconstruct", str(tiny_store.path), "--workers", "2", *args])
    with pytest.raises(SystemExit) as exc:
        main()
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.startswith(message) and err.count("\n") == 1 and "Traceback" not in err
    assert _snapshot(tiny_store.path) == before
