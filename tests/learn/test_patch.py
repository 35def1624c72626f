"""Patch training (``train --patch``): the patches are the images' pixels, drawn per epoch, a validation grid
covers every image, and a patch-trained sampling network predicts larger images in tiles with intervals fitted
on its tiled predictions of the validation images."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset
from nanoct.io.store import DataStore
from nanoct.learn.calibration import image_statistic, load_calibration
from nanoct.learn.checkpoint import load_checkpoint
from nanoct.learn.data import PatchDataset, ReconDataset, grid_starts, grid_windows
from nanoct.learn.predict import predict
from nanoct.learn.train import TrainConfig, train
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset

pytestmark = pytest.mark.usefixtures("one_thread")

SMALL = dict(
    n_scales=3, blocks_per_scale=1, fc_dim=8, fc_blocks=1, cond_channels=4, cond_width=4, fc_cond_dim=8,
    hidden_ratio=1.0,
)  # fmt: skip


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("patch") / "tiny"
    generate_dataset(
        path, get_preset("tiny-parallel"), 12, seed=7, workers=0, progress=False, split_fractions=(0.5, 0.25, 0.25)
    )
    reconstruct_dataset(path, "fbp", workers=0, progress=False)
    return path


@pytest.mark.parametrize(("n", "patch"), [(63, 16), (63, 32), (63, 63), (251, 64), (100, 33)])
def test_the_grid_covers_the_image_with_the_fewest_patches(n, patch):
    starts = grid_starts(n, patch)
    covered = np.zeros(n, bool)
    for s in starts:
        covered[s : s + patch] = True
    assert covered.all() and starts[0] == 0 and starts[-1] == n - patch
    assert len(starts) == -(-n // patch)
    hits = np.zeros((n, n), int)
    for rows, cols in grid_windows(n, patch):
        hits[rows, cols] += 1
    assert hits.min() >= 1 and len(grid_windows(n, patch)) == len(starts) ** 2


def test_patches_are_the_images_pixels_drawn_per_epoch(store):
    base = ReconDataset(store, "fbp", "train")
    patches = PatchDataset(base, 16, seed=3)
    assert len(patches) == len(base) and patches.image_size == 16
    item, r, c = patches.position(2)
    x_tilde, x = patches[2]
    full_tilde, full = base[item]
    assert x_tilde.shape == (1, 16, 16)
    np.testing.assert_array_equal(x_tilde.numpy(), full_tilde[:, r : r + 16, c : c + 16].numpy())
    np.testing.assert_array_equal(x.numpy(), full[:, r : r + 16, c : c + 16].numpy())
    first = [patches.position(i) for i in range(len(patches))]
    assert first == [patches.position(i) for i in range(len(patches))]  # the same epoch: the same patches
    patches.set_epoch(1)
    assert first != [patches.position(i) for i in range(len(patches))]
    grid = PatchDataset(ReconDataset(store, "fbp", "val"), 32, grid=True)
    assert len(grid) == 3 * 4 and {grid.position(i)[1:] for i in range(4)} == {(0, 0), (0, 31), (31, 0), (31, 31)}
    grid.set_epoch(5)
    assert grid.position(3) == (0, 31, 31)
    for bad in (7, 64, 16.0, True):
        with pytest.raises(NanoctError, match=f"--patch {bad!r} must be a whole number from 8 to the image size 63"):
            PatchDataset(base, bad)


@pytest.mark.slow
def test_a_patch_trained_network_predicts_in_tiles_calibrated_on_its_tiled_validation_images(store, tmp_path):
    """The intervals and the out-of-distribution reference are fitted on the very outputs a tiled prediction of
    each validation image gives (exchangeable with the test images' tiled predictions)."""
    config = TrainConfig("cinn-res", "fbp", epochs=2, batch_size=2, model_kwargs=SMALL, patch=32)
    run = train(store, tmp_path / "run", config, progress=False)
    ckpt = load_checkpoint(run / "best.pt")
    assert ckpt["image_size"] == 32 and ckpt["config"]["patch"] == 32
    assert train(store, tmp_path / "run", config, progress=False) == run  # resumed: nothing to do
    with pytest.raises(NanoctError, match="other settings"):  # another patch size is another run
        train(store, tmp_path / "run", TrainConfig("cinn-res", "fbp", epochs=2, batch_size=2, model_kwargs=SMALL,
                                                   patch=16), progress=False)  # fmt: skip
    with pytest.raises(NanoctError, match=r"trained on 32x32 images.*--tile 0"):
        predict(store, run, progress=False, reconstruct_kwargs={"n_samples": 4})
    name = predict(store, run, progress=False, reconstruct_kwargs={"n_samples": 4}, tile=0)
    data = DataStore.open(store)
    test = data.indices("test")
    entry = load_calibration(run)["best"]
    params = data.reconstruction_params(name)
    assert entry["patch"] == 32 and entry["n_images"] == 3  # the 3 validation images, whole
    assert params["calibration"] == entry and params["tiling"]["size"] == 32 and entry["tiling"] == params["tiling"]
    means, stds = data.read_reconstruction(name, test), data.read_uncertainty(name, test)
    assert means.shape == stds.shape == (3, 63, 63) and np.isfinite(means).all() and (stds > 0).all()
    val = predict(store, run, progress=False, reconstruct_kwargs={"n_samples": 4}, tile=0, split="val", name="v")
    levels = image_statistic(DataStore.open(store).read_uncertainty(val, data.indices("val")))
    assert entry["ood"]["val"] == sorted(levels.tolist())  # the reference is the tiled predictions' statistic
    predict(store, run, progress=False, reconstruct_kwargs={"n_samples": 4}, tile=0, overlap=8, name="o8")
    assert load_calibration(run)["best"]["tiling"]["overlap"] == 8  # another tiling: fitted again
    # another data set with its own validation split: fitted there (tiled), not on the set the run was trained on
    other = tmp_path / "other"
    generate_dataset(other, get_preset("tiny-parallel"), 4, seed=9, workers=0, progress=False,
                     split_fractions=(0.0, 0.5, 0.5))  # fmt: skip
    reconstruct_dataset(other, "fbp", workers=0, progress=False)
    there = predict(other, run, progress=False, reconstruct_kwargs={"n_samples": 4}, tile=0)
    fit = DataStore.open(other).reconstruction_params(there)["calibration"]
    assert fit["store"] == str(other.resolve()) and fit["n_images"] == 2 and fit["patch"] == 32
