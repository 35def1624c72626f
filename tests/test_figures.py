"""Figures are written as PNG files (atomically) from a store."""

import numpy as np

from nanoct.figures import compare_reconstructions, show_sample, uncertainty_maps
from nanoct.recon.batch import reconstruct_dataset
from nanoct.store import DataStore


def _is_png(path):
    return path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_figures(tiny_store, tmp_path):
    store = DataStore.open(tiny_store.path, mode="r+")
    reconstruct_dataset(store.path, "fbp", split="test", name="fig_fbp", workers=0, progress=False)
    test = [int(i) for i in store.indices("test")]
    store.prepare_reconstruction("fig_fbp+fake", {}, uncertainty=True)
    for i, gt in zip(test, store.read_phantoms(test)):
        store.write_reconstruction("fig_fbp+fake", i, gt, std=np.full_like(gt, 0.1))
    outs = [
        show_sample(store, test[0], tmp_path / "a" / "sample.png"),
        compare_reconstructions(store, ["fig_fbp", "fig_fbp+fake"], test[:2], tmp_path / "b.png"),
        uncertainty_maps(store, ["fig_fbp+fake"], test[:2], tmp_path / "c.png"),
    ]
    assert all(_is_png(p) for p in outs)
    assert not list(tmp_path.rglob(".*tmp*"))  # no temporary files left
