"""Batch reconstruction of a store: names, stored parameters, shifts, resume."""

import numpy as np
import pytest

from nanoct.errors import NanoctError, StoreError
from nanoct.metrics import psnr
from nanoct.recon.batch import output_name, reconstruct_dataset
from nanoct.store import DataStore


def test_output_names():
    assert output_name("resesop", 1.0) == "resesop"
    assert output_name("resesop", 0.8) == "resesop_eta0.8"
    assert output_name("resesop", 1.2) == "resesop_eta1.2"
    assert output_name("dremel") == "dremel"


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
    with pytest.raises(ValueError, match="relaxation"):
        reconstruct_dataset(
            tiny_store.path, "kaczmarz", split="test", params={"relaxation": 3.0}, name="bad", workers=0, progress=False
        )
    with pytest.raises(NanoctError, match="unknown"):
        reconstruct_dataset(tiny_store.path, "art", workers=0, progress=False)
