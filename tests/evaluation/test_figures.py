"""Figures are written as PNG files (atomically) from a store and from training logs."""

import numpy as np
import pytest

from nanoct.evaluation.evaluate import evaluate_store
from nanoct.evaluation.figures import (
    compare_reconstructions,
    reliability_diagram,
    show_sample,
    training_curves,
    uncertainty_maps,
    uncertainty_report,
)
from nanoct.io.store import DataStore
from nanoct.recon.batch import reconstruct_dataset


def _is_png(path):
    return path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_figures(tiny_store, tmp_path):
    store = DataStore.open(tiny_store.path, mode="r+")
    reconstruct_dataset(store.path, "fbp", split="test", name="fig_fbp", workers=0, progress=False)
    test = [int(i) for i in store.indices("test")]
    rng = np.random.default_rng(0)
    entry = {"guaranteed_coverage": 0.5, "rcps_multiplier": None}
    levels = {k: {"multiplier": q, **entry} for k, q in (("0.68", 1.0), ("0.9", 1.64))}
    params = {
        "input": "fig_fbp",
        "calibration": {"delta": 0.1, "levels": levels} | {"edge_multipliers": {"0.9": 20.0}, "edge_sigma": 1.0},
    }
    store.prepare_reconstruction("fig_fbp+fake", params, uncertainty=True)
    for i, gt in zip(test, store.read_phantoms(test)):
        std = rng.uniform(0.01, 0.1, gt.shape).astype(np.float32)
        store.write_reconstruction("fig_fbp+fake", i, gt + rng.normal(0, 1, gt.shape) * std, std=std)
    runs = tmp_path / "runs"
    (runs / "fake-fig_fbp").mkdir(parents=True)
    log = "epoch,train_loss,val_loss,val_nll_bpd\n1,2.0,1.5,1.4\n2,1.2,1.1,1.0\n3,1.0,1.05,0.9\n"
    (runs / "fake-fig_fbp" / "log.csv").write_text(log)
    results = evaluate_store(store, "test", names=["fig_fbp", "fig_fbp+fake"])
    outs = [
        show_sample(store, test[0], tmp_path / "a" / "sample.png"),
        compare_reconstructions(store, ["fig_fbp", "fig_fbp+fake"], test[:2], tmp_path / "b.png"),
        uncertainty_maps(store, ["fig_fbp+fake"], test[:2], tmp_path / "c.png"),
        reliability_diagram(store, {"fake": ["fig_fbp+fake"]}, test, tmp_path / "d.png"),
        training_curves({"fake": {"fig_fbp": runs / "fake-fig_fbp", "none": runs / "missing"}}, tmp_path / "e.png"),
    ]
    assert all(_is_png(p) for p in outs)
    text = uncertainty_report(store, results, ["unet", "fake"], ["fig_fbp"], runs, tmp_path / "report")
    assert "| fig_fbp+fake | support |" in text and "uncertainty_fake.png" in text
    for png in ("uncertainty_fake.png", "reliability.png", "training_curves.png"):
        assert _is_png(tmp_path / "report" / png)
    assert uncertainty_report(store, results, ["unet"], ["fig_fbp"], runs, tmp_path / "none") == ""
    assert not list(tmp_path.rglob(".*tmp*"))  # no temporary files left


def test_show_scales_the_phantom_and_fbps_to_the_phantom(tiny_store, tmp_path, monkeypatch):
    """A set matched to a scan holds phantoms at the scan's absorbance (e.g. 0.08 at most): drawn on 0..1 they
    were black; the phantom and both FBPs are drawn on 0..the phantom's maximum."""
    from dataclasses import replace

    import nanoct.evaluation.figures as figures

    drawn = []
    monkeypatch.setattr(figures, "_save", lambda fig, out, dpi: drawn.append(fig) or out)
    read = type(tiny_store).read_sample

    def scaled(self, i):  # the data of a set made at the scan's absorbance
        s = read(self, i)
        return replace(s, phantom=s.phantom * 0.08, sinogram=s.sinogram * 0.08, sinogram_eta=s.sinogram_eta * 0.08)

    monkeypatch.setattr(type(tiny_store), "read_sample", scaled)
    index = int(tiny_store.indices("test")[0])
    show_sample(tiny_store, index, tmp_path / "s.png")
    top = float(tiny_store.read_sample(index).phantom.max())
    assert 0 < top < 0.1
    clims = [ax.images[0].get_clim() for ax in drawn[0].axes if ax.images and "sinogram" not in ax.get_title()]
    assert len(clims) == 3 and all(c == pytest.approx((0.0, top)) for c in clims)
