"""Inference: output names (incl. input mixing), stored parameters, resume, bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

import nanoct.learn.predict as predict_mod
from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset
from nanoct.io.fileio import file_sha256
from nanoct.io.store import DataStore
from nanoct.learn.checkpoint import load_checkpoint, model_from_checkpoint
from nanoct.learn.predict import GeometryWarning, geometry_difference, predict
from nanoct.learn.train import TrainConfig, train
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset

SMALL = {"channels": [4, 4, 8, 8, 16]}


def _counting(monkeypatch) -> list[int]:
    """The batch sizes the network is called on from now on (by predict)."""
    seen: list[int] = []
    real = predict_mod.model_from_checkpoint

    def counting(*a, **k):
        model = real(*a, **k)
        orig = model.reconstruct
        model.reconstruct = lambda x, **kw: (seen.append(x.shape[0]), orig(x, **kw))[1]
        return model

    monkeypatch.setattr(predict_mod, "model_from_checkpoint", counting)
    return seen


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """12 tiny samples with FBP and a two-epoch UNet run (seconds with one torch thread): every test here
    predicts with it, and some build on each other's results."""
    root = tmp_path_factory.mktemp("predict")
    path = root / "tiny"
    generate_dataset(
        path, get_preset("tiny-parallel"), 12, seed=7, workers=0, progress=False, split_fractions=(0.5, 0.25, 0.25)
    )
    reconstruct_dataset(path, "fbp", workers=0, progress=False)
    reconstruct_dataset(path, "fbp", name="other", split="test", workers=0, progress=False)  # a second "method"
    run = train(
        path, root / "run", TrainConfig("unet", "fbp", epochs=2, batch_size=2, model_kwargs=SMALL), progress=False
    )
    return path, run


def test_predict_writes_test_split(setup):
    path, run = setup
    assert predict(path, run, progress=False) == "fbp+unet"
    store = DataStore.open(path)
    test = store.indices("test")
    assert np.array_equal(np.flatnonzero(store.reconstruction_done("fbp+unet")), test)
    out = store.read_reconstruction("fbp+unet", test)
    assert out.shape == (3, 63, 63) and out.min() >= 0 and out.max() <= 1
    ckpt = load_checkpoint(run / "best.pt")
    params = store.reconstruction_params("fbp+unet")
    assert params["train_input"] == "fbp" and params["epoch"] == ckpt["epoch"] and params["checkpoint"] == "best"
    model = model_from_checkpoint(ckpt).eval()
    with torch.no_grad():
        ref = model(torch.from_numpy(store.read_reconstruction("fbp", test))[:, None])[:, 0].numpy()
    np.testing.assert_allclose(out, ref, atol=1e-5)


def test_sampling_arguments_for_the_unet_are_refused(setup):
    """--samples / --antithetic mean nothing to a UNet: a clear error, nothing written."""
    path, run = setup
    with pytest.raises(NanoctError, match=r"holds a 'unet'.*\['antithetic', 'n_samples'\].*leave them out"):
        predict(path, run, progress=False, name="sampled", reconstruct_kwargs={"n_samples": 8, "antithetic": True})
    assert "sampled" not in DataStore.open(path).reconstruction_names()


def test_predict_is_resumable_and_noop_when_complete(setup, monkeypatch):
    path, run = setup
    predict(path, run, progress=False)
    seen = _counting(monkeypatch)
    predict(path, run, progress=False)
    assert seen == []  # complete: nothing recomputed
    store = DataStore.open(path, mode="r+")
    store.invalidate_reconstruction("fbp+unet", [int(store.indices("test")[1])])
    predict(path, run, progress=False)
    assert seen == [1]
    assert store.reconstruction_done("fbp+unet")[store.indices("test")].all()


def test_input_mixing(setup):
    path, run = setup
    assert predict(path, run, "other", progress=False) == "other+unet@fbp"
    store = DataStore.open(path)
    params = store.reconstruction_params("other+unet@fbp")
    assert params["input"] == "other" and params["train_input"] == "fbp"
    # "other" is the same FBP under another name, so the mixed result equals the plain one
    np.testing.assert_allclose(
        store.read_reconstruction("other+unet@fbp", store.indices("test")),
        store.read_reconstruction("fbp+unet", store.indices("test")),
        atol=1e-6,
    )


def test_other_checkpoint_needs_overwrite(setup):
    path, run = setup
    predict(path, run, name="cmp", progress=False)
    with pytest.raises(NanoctError, match="--overwrite"):
        predict(path, run, name="cmp", checkpoint="last", progress=False)
    predict(path, run, name="cmp", checkpoint="last", overwrite=True, progress=False)
    assert DataStore.open(path).reconstruction_params("cmp")["checkpoint"] == "last"


def test_bad_input(setup, tmp_path):
    path, run = setup
    with pytest.raises(NanoctError, match="no reconstruction 'dremel'"):
        predict(path, run, "dremel", progress=False)
    with pytest.raises(NanoctError, match="missing 6 of the 6 train"):
        predict(path, run, "other", split="train", progress=False)
    with pytest.raises(NanoctError, match="no training run"):
        predict(path, tmp_path / "nope", progress=False)
    with pytest.raises(NanoctError, match="'best' or 'last'"):
        predict(path, run, checkpoint="final", progress=False)
    # corrupt checkpoint
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "best.pt").write_bytes((run / "best.pt").read_bytes()[:500])
    with pytest.raises(NanoctError, match="corrupt"):
        predict(path, bad, progress=False)
    # checkpoint of another image size
    other = tmp_path / "other"
    other.mkdir()
    ckpt = torch.load(run / "best.pt", weights_only=True)
    ckpt["image_size"] = 127
    torch.save(ckpt, other / "best.pt")
    with pytest.raises(NanoctError, match="127x127"):
        predict(path, other, progress=False)
    # a store without test samples
    no_test = tmp_path / "notest"
    generate_dataset(
        no_test, get_preset("tiny-parallel"), 4, workers=0, progress=False, split_fractions=(0.5, 0.5, 0.0)
    )
    reconstruct_dataset(no_test, "fbp", workers=0, progress=False)
    with pytest.raises(NanoctError, match="test split .* has no samples"):
        predict(no_test, run, progress=False)


def test_tiled_prediction(setup, tmp_path):
    """--tile: one tile of the trained size is the untiled prediction; a larger slice (127 px for a network
    trained on 63 px) is predicted in tiles, as predict_tiled stitches them; untiled it is refused."""
    from nanoct.learn.tiling import predict_tiled

    path, run = setup
    assert predict(path, run, progress=False, name="tiled", tile=0) == "tiled"
    store = DataStore.open(path)
    test = store.indices("test")
    np.testing.assert_allclose(
        store.read_reconstruction("tiled", test), store.read_reconstruction("fbp+unet", test), atol=1e-6
    )
    assert store.reconstruction_params("tiled")["tiling"] == {"size": 63, "overlap": 16, "margin": 2}
    big = tmp_path / "big"
    generate_dataset(big, get_preset("small-parallel"), 2, seed=1, workers=0, progress=False, split_fractions=(0, 0, 1))
    reconstruct_dataset(big, "fbp", workers=0, progress=False)
    with pytest.raises(NanoctError, match=r"trained on 63x63 images.*--tile 0"):
        predict(big, run, progress=False)
    with pytest.warns(GeometryWarning, match=r"n_angles 140 \(here 282\); n_det 91 \(here 181\)"):
        assert predict(big, run, progress=False, tile=0, overlap=20) == "fbp+unet"
    big_store = DataStore.open(big)
    out = big_store.read_reconstruction("fbp+unet", [0])[0]
    model = model_from_checkpoint(load_checkpoint(run / "best.pt")).eval()

    def network(x, seed):
        with torch.no_grad():
            return model(torch.from_numpy(x)[:, None])[:, 0].numpy(), None

    expected, _ = predict_tiled(big_store.read_reconstruction("fbp", [0])[0], network, 63, overlap=20, margin=2)
    assert out.shape == (127, 127)
    np.testing.assert_allclose(out, expected, atol=1e-5)
    with pytest.raises(NanoctError, match=r"overlap 40: .* between 5 and half the tile \(31\); e.g. --tile-overlap 16"):
        predict(big, run, progress=False, tile=0, overlap=40, name="bad")
    # a tile below 32 pixels: the default overlap is half of it
    predict(path, run, progress=False, tile=20, name="small-tiles")
    assert DataStore.open(path).reconstruction_params("small-tiles")["tiling"] == {
        "size": 20,
        "overlap": 10,
        "margin": 2,
    }


def test_a_residual_unet_is_stored_under_its_own_name(setup, tmp_path):
    """A residual UNet's prediction is ``<input>+unet-res`` by default, so the tables never count it as the
    paper's UNet; its output is the input minus the network's correction."""
    path, _ = setup
    config = TrainConfig("unet", "fbp", epochs=1, batch_size=2, model_kwargs=SMALL | {"residual": True})
    run = train(path, tmp_path / "res", config, progress=False)
    assert predict(path, run, progress=False) == "fbp+unet-res"
    store = DataStore.open(path)
    test = store.indices("test")
    model = model_from_checkpoint(load_checkpoint(run / "best.pt")).eval()
    x = torch.from_numpy(store.read_reconstruction("fbp", test))[:, None]
    with torch.no_grad():
        expected = (x - model.net(x))[:, 0].numpy()
    np.testing.assert_allclose(store.read_reconstruction("fbp+unet-res", test), expected, atol=1e-5)


def test_a_moved_folder_resumes_and_a_changed_checkpoint_is_redone(setup, tmp_path, monkeypatch):
    """The checkpoint file's hash, not the run's path, identifies the network: a data set and run moved
    elsewhere resume their prediction (nothing recomputed, the new places recorded); weights replaced under
    the same path and epoch are predicted again; a result recorded before the hash resumes in place."""
    path, run = setup
    predict(path, run, progress=False)
    shutil.copytree(path, tmp_path / "a" / "data")
    shutil.copytree(run, tmp_path / "a" / "run")
    moved = tmp_path / "b"
    (tmp_path / "a").rename(moved)
    data, new_run = moved / "data", moved / "run"
    seen = _counting(monkeypatch)
    assert predict(data, new_run, progress=False) == "fbp+unet"
    assert seen == []
    store = DataStore.open(data)
    params = store.reconstruction_params("fbp+unet")
    assert params["run"] == str(new_run.resolve()) and params["checkpoint_sha256"] == file_sha256(new_run / "best.pt")
    test = store.indices("test")
    before = store.read_reconstruction("fbp+unet", test)
    # the same path and epoch, other weights: the old result is stale and is redone
    ckpt = torch.load(new_run / "best.pt", weights_only=True)
    ckpt["model_state"] = {k: v + 0.01 if v.is_floating_point() else v for k, v in ckpt["model_state"].items()}
    torch.save(ckpt, new_run / "best.pt")
    predict(data, new_run, progress=False)
    assert sum(seen) == test.size
    assert not np.allclose(DataStore.open(data).read_reconstruction("fbp+unet", test), before)
    # a result stored without the hash (an earlier version): resumed where its run still lies, hash added
    store = DataStore.open(data, mode="r+")
    store.recons.set_params("fbp+unet", {k: v for k, v in params.items() if k != "checkpoint_sha256"})
    predict(data, new_run, progress=False)
    assert sum(seen) == test.size
    assert "checkpoint_sha256" in DataStore.open(data).reconstruction_params("fbp+unet")
    # ... but not from another run directory: nothing tells its weights from others'
    store.recons.set_params("fbp+unet", params | {"run": str(run.resolve())} | {"checkpoint_sha256": None})
    with pytest.raises(NanoctError, match=r"differs in: .*run.*--overwrite"):
        predict(data, new_run, progress=False)


def test_geometry_difference_names_what_differs_beyond_the_tolerances():
    """The axis counts beyond half a pixel and view angles beyond 1e-6 rad; each differing key is named once."""
    g = get_preset("tiny-parallel").to_dict()
    assert geometry_difference(g, g) == []
    assert geometry_difference(g, g | {"center_offset": 0.4}) == []  # two estimates of one axis
    assert geometry_difference(g, g | {"center_offset": 0.6}) == ["center_offset 0 (here 0.6)"]
    views = list(np.linspace(0, 3, 5))
    a, b = g | {"view_angles": views}, g | {"view_angles": [v + 5e-7 for v in views]}
    assert geometry_difference(a, b) == []
    assert geometry_difference(a, g | {"view_angles": [v + 1e-3 for v in views]}) == [
        "view_angles differ by up to 0.001 rad"
    ]
    assert geometry_difference(g, g | {"n_det": 181, "det_spacing": 0.5}) == [
        "det_spacing 1 (here 0.5)",
        "n_det 91 (here 181)",
    ]


def test_a_run_of_another_geometry_is_refused_naming_only_what_differs(setup, tmp_path):
    """Untiled, an axis within half a pixel of the training data's is the same geometry; beyond it the error
    names the axis alone (not two whole geometries)."""
    path, run = setup
    for offset, name in ((0.3, "near"), (0.8, "far")):
        other = tmp_path / name
        other.mkdir()
        ckpt = torch.load(run / "best.pt", weights_only=True)
        ckpt["config"]["data"]["geometry"]["center_offset"] = offset
        torch.save(ckpt, other / "best.pt")
        if offset < 0.5:
            assert predict(path, other, progress=False, name=name) == name
            continue
        with pytest.raises(
            NanoctError, match=r"another geometry than the data set .*: center_offset 0.8 \(here 0\); train"
        ):
            predict(path, other, progress=False, name=name)
