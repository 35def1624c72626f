"""RESESOP's eta in a batch run: the store's (true), estimated from a first reconstruction or a reference store."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from nanoct.cli import main
from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset
from nanoct.io.store import DataStore, create_scan
from nanoct.recon.batch import reconstruct_dataset
from nanoct.recon.eta import eta_from_reference, eta_from_residual
from nanoct.recon.eta_source import EtaSourceParams
from nanoct.recon.resesop import resesop
from nanoct.sim.generate import generate_dataset

QUICK = {"n_iter": 2}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """A second tiny-parallel store (another seed) whose eta serves as reference."""
    path = tmp_path_factory.mktemp("ref") / "ref"
    return generate_dataset(path, get_preset("tiny-parallel"), 4, seed=99, workers=0, progress=False)


def test_syntax():
    assert EtaSourceParams(eta="estimate:residual").eta == "estimate:residual=dremel"
    assert EtaSourceParams(eta=" true ").eta == "true"
    for bad in ("estimate", "estimate:reference", "guess", "estimate:residual=a/b"):
        with pytest.raises(ValueError, match="eta="):
            EtaSourceParams(eta=bad)


def test_residual_estimate_needs_first_reconstruction(tiny_store):
    with pytest.raises(NanoctError, match=r"make it first: nanoct reconstruct \S+ --method .* --name firstx"):
        reconstruct_dataset(
            tiny_store.path, "resesop", params={"eta": "estimate:residual=firstx"}, workers=0, progress=False
        )
    assert "resesop_est-residual-firstx" not in DataStore.open(tiny_store.path).reconstruction_names()
    reconstruct_dataset(tiny_store.path, "fbp", split="test", name="firsty", workers=0, progress=False)
    params = {"eta": "estimate:residual=firsty"}
    with pytest.raises(NanoctError, match="--name firsty is the first reconstruction"):
        reconstruct_dataset(tiny_store.path, "resesop", split="test", params=params, name="firsty", overwrite=True)
    assert DataStore.open(tiny_store.path).reconstruction_done("firsty", tiny_store.indices("test")).all()


def test_residual_estimate(tiny_store):
    path, test = tiny_store.path, tiny_store.indices("test")
    reconstruct_dataset(path, "fbp", split="test", workers=0, progress=False)
    params = {**QUICK, "eta": "estimate:residual=fbp", "eta_scale": 0.8}
    name = reconstruct_dataset(path, "resesop", split="test", params=params, workers=0, progress=False)
    assert name == "resesop_est-residual-fbp_eta0.8"
    store = DataStore.open(path)
    assert store.reconstruction_params(name) == {"method": "resesop", **params}
    i = int(test[0])
    sample = store.read_sample(i)
    eta = eta_from_residual(store.geometry, sample.sinogram, store.read_reconstruction("fbp", [i])[0])
    direct = resesop(store.geometry, sample.sinogram, eta, eta_scale=0.8, **QUICK)
    np.testing.assert_allclose(store.read_reconstruction(name, [i])[0], direct.image, atol=1e-6)


def test_reference_estimate(tiny_store, reference):
    path, test = tiny_store.path, tiny_store.indices("test")
    params = {**QUICK, "eta": f"estimate:reference={reference.path}"}
    name = reconstruct_dataset(path, "resesop", split="test", params=params, workers=0, progress=False)
    assert name == "resesop_est-reference"
    store = DataStore.open(path)
    assert store.reconstruction_params(name)["eta"] == f"estimate:reference={reference.path.resolve()}"
    ref_eta = eta_from_reference(np.stack([reference.read_sample(i).eta for i in range(reference.n)]))
    sample = store.read_sample(int(test[0]))
    direct = resesop(store.geometry, sample.sinogram, ref_eta, **QUICK)
    np.testing.assert_allclose(store.read_reconstruction(name, test[:1])[0], direct.image, atol=1e-6)


def test_reference_of_another_geometry_refused(tiny_store, tmp_path):
    other = generate_dataset(tmp_path / "fan", get_preset("tiny-fan"), 1, seed=1, workers=0, progress=False)
    params = {"eta": f"estimate:reference={other.path}"}
    with pytest.raises(NanoctError, match="another geometry"):
        reconstruct_dataset(tiny_store.path, "resesop", params=params, name="rx", workers=0, progress=False)
    assert "rx" not in DataStore.open(tiny_store.path).reconstruction_names()


def test_imported_scan_has_no_true_eta(tiny_store, tmp_path, reference):
    g = tiny_store.geometry
    scan = create_scan(tmp_path / "scan", g, tiny_store.read_sample(0).sinogram[None], scan={"shared_motion": True})
    with pytest.raises(NanoctError, match="no true eta; estimate it with --eta estimate:residual"):
        reconstruct_dataset(scan.path, "resesop", params={"eta": "true"}, workers=0, progress=False)
    for params in ({}, {"eta": "estimate:residual"}):  # a scan's default: the residual of Dremel
        with pytest.raises(NanoctError, match=r"make it first: nanoct reconstruct \S+ --method dremel$"):
            reconstruct_dataset(scan.path, "resesop", params=params, workers=0, progress=False)
    assert DataStore.open(scan.path).reconstruction_names() == []
    params = {**QUICK, "eta": f"estimate:reference={reference.path}"}
    assert (
        reconstruct_dataset(scan.path, "resesop", params=params, workers=0, progress=False) == "resesop_est-reference"
    )


def _cli(monkeypatch, capsys, *args):
    monkeypatch.setattr(sys, "argv", ["nanoct", *map(str, args)])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code or 0
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_eta_option(monkeypatch, capsys, tiny_store):
    path = tiny_store.path
    reconstruct_dataset(path, "fbp", split="test", workers=0, progress=False)
    code, _, err = _cli(monkeypatch, capsys, "reconstruct", path, "--method", "fbp", "--eta", "estimate:residual")
    assert code == 2 and "--eta applies to --method resesop only" in err
    code, _, err = _cli(monkeypatch, capsys, "reconstruct", path, "--method", "resesop", "--eta", "guess", "-q")
    assert code == 2 and "--eta of --method resesop" in err and len(err.strip().splitlines()) == 1
    args = ("reconstruct", path, "--method", "resesop", "--eta", "estimate:residual=fbp", "--split", "test")
    code, out, _ = _cli(monkeypatch, capsys, *args, "--param", "n_iter=1", "-w", "0", "-q", "--name", "rcli")
    assert code == 0 and "reconstructions/rcli" in out
    assert DataStore.open(path).reconstruction_params("rcli")["eta"] == "estimate:residual=fbp"


def test_measured_scan_runs_resesop_after_dremels_motion(tiny_store, tmp_path):
    """On measured data RESESOP's model carries the first reconstruction's motion and eta is the residual after it."""
    g = tiny_store.geometry
    sinos = np.stack([tiny_store.read_sample(i).sinogram for i in tiny_store.indices("test")[:2]])
    scan = create_scan(tmp_path / "scan", g, sinos + np.float32(0.3 * sinos.max()), scan={"source": "test"})
    reconstruct_dataset(scan.path, "dremel", params={"n_iter": 3}, workers=0, progress=False)
    name = reconstruct_dataset(scan.path, "resesop", params=QUICK, workers=0, progress=False)
    assert name == "resesop_est-residual"  # the scan's default eta: the residual of Dremel
    store = DataStore.open(scan.path)
    sample = store.read_sample(1)
    first, motion = store.read_reconstruction("dremel", [1])[0], store.read_shifts("dremel", [1])[0]
    assert np.abs(motion).max() > 0.1
    eta = eta_from_residual(g, sample.sinogram, first, shifts=motion)
    direct = resesop(g, sample.sinogram, eta, shifts=motion, **QUICK)
    np.testing.assert_allclose(store.read_reconstruction(name, [1])[0], direct.image, atol=1e-6)
    unmoved = resesop(g, sample.sinogram, eta_from_residual(g, sample.sinogram, first), **QUICK)
    assert np.abs(unmoved.image - direct.image).max() > 1e-3  # the motion made a difference


def test_simulated_store_keeps_the_unmoved_model(tiny_store):
    """A simulation: eta from Dremel's residual before its motion, RESESOP with the paper's model, as before."""
    path, i = tiny_store.path, int(tiny_store.indices("test")[0])
    reconstruct_dataset(path, "dremel", split="test", params={"n_iter": 3}, name="d3", workers=0, progress=False)
    params = {**QUICK, "eta": "estimate:residual=d3"}
    name = reconstruct_dataset(path, "resesop", split="test", params=params, workers=0, progress=False)
    store = DataStore.open(path)
    sample = store.read_sample(i)
    eta = eta_from_residual(store.geometry, sample.sinogram, store.read_reconstruction("d3", [i])[0])
    direct = resesop(store.geometry, sample.sinogram, eta, **QUICK)
    np.testing.assert_array_equal(store.read_reconstruction(name, [i])[0], direct.image)


def test_a_moved_reference_store_resumes(tiny_store, reference, tmp_path, monkeypatch):
    """A reference store moved elsewhere gives the same eta: the reconstruction resumes, nothing redone, the new
    path recorded. One recorded before the eta's hash resumes from the same path only."""
    import shutil

    import nanoct.recon.batch as batch_mod

    def run(where):
        params = {**QUICK, "eta": f"estimate:reference={where}"}
        return reconstruct_dataset(tiny_store.path, "resesop", split="test", params=params, name="mv", workers=0,
                                   progress=False)  # fmt: skip

    moved, other = tmp_path / "moved", tmp_path / "elsewhere"
    shutil.copytree(reference.path, moved)
    name = run(moved)
    recorded = DataStore.open(tiny_store.path).reconstruction_params(name)
    moved.rename(other)
    monkeypatch.setattr(batch_mod, "_reconstruct_into", lambda *a: pytest.fail("redone"))
    run(other)
    store = DataStore.open(tiny_store.path, mode="r+")
    now = recorded | {"eta": f"estimate:reference={other.resolve()}"}
    assert store.reconstruction_params(name) == now
    unhashed = {k: v for k, v in recorded.items() if k != "eta_reference_sha256"}
    store.recons.set_params(name, unhashed)  # made at the old path by a version that recorded no hash
    with pytest.raises(NanoctError, match="differs in: eta, eta_reference_sha256"):
        run(other)
    store.recons.set_params(name, unhashed | {"eta": now["eta"]})  # ... at this path: resumed, hash added
    run(other)
    assert DataStore.open(tiny_store.path).reconstruction_params(name) == now
