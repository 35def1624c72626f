"""The learned half on a CUDA device: prediction against the CPU's, training, resuming, a tiled large slice.

Two steps, because the GPU machine may lack what simulating a data set needs (astra-toolbox):

    PYTHONPATH=src python benchmarks/bench_cuda.py prepare DIR     # on a CPU machine
    PYTHONPATH=src python benchmarks/bench_cuda.py check DIR [--device cuda] [--size 2048] [--batches 16,64,256,1024]

``prepare``: a tiny-parallel data set of 40 images with Dremel reconstructions, CiUNetRes trained on it
on the CPU for 2 epochs (the semi-real benchmark's arguments) and its CPU prediction of the test split
(16 antithetic samples, ``reconstructions/cpu-pred``).

``check`` (on a copy of DIR): (1) the CPU-trained network predicts the test split on the device; its
mean and std against the CPU's (the latent samples come from a CPU generator, so they are the same);
(2) CiUNetRes and the UNet are trained on the device for 4 epochs in bf16, resumed for a fifth,
predicted and evaluated (``nanoct evaluate``); (3) a ``--size`` square slice (the first test image's
Dremel reconstruction, resized) is predicted in tiles of the trained size with 16 antithetic
samples by ``nanoct predict --tile 0``, then through :func:`nanoct.learn.predict.predict` with each
``--batches`` number of tiles per network call (twice each), with the device's peak memory; and a
512 x 512 crop of it on this machine's CPU and on the device (baseline and ratio in one run).
Prints and writes ``check.json`` to ``$OUT`` (default DIR). ``check`` calls no projector: on a GPU
machine whose astra-toolbox cannot load (its wheel needs CUDA 12's runtime and cuFFT), a stand-in
``astra`` package first on ``PYTHONPATH`` lets nanoct import.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from cli_run import cli
from nanoct.core.geometry import Geometry
from nanoct.io.store import DataStore, create_scan
from nanoct.learn.predict import predict

CIUNET = ["--lr", "1e-3", "--param", "blocks_per_scale=1", "--param", "conditional_scale=location",
          "--param", "cond_channels=[16,16,32,32,64]"]  # fmt: skip
UNET = ["--param", "out_bias=-7.0", "--param", "skip_channels=32"]
SAMPLES = {"n_samples": 16, "antithetic": True}


def _peak_gb() -> float | None:
    """The device's peak allocated memory since the last call (GB), None without CUDA."""
    if not torch.cuda.is_available():
        return None
    torch.cuda.synchronize()
    peak = torch.cuda.max_memory_allocated() / 2**30
    torch.cuda.reset_peak_memory_stats()
    return round(peak, 3)


def prepare(folder: Path) -> None:
    """The data set, the CPU-trained run and its CPU prediction."""
    store, run_dir = folder / "tiny", folder / "run_cpu"
    cli("generate", "--preset", "tiny-parallel", "--n", 40, "--out", store, "-q")
    cli("reconstruct", store, "--method", "dremel", "--split", "all", "-q")
    cli("train", store, "--model", "ciunet-res", "--input", "dremel", "--epochs", 2, "--out", run_dir, "-q", *CIUNET)
    (run_dir / "last.pt").unlink()  # best.pt is what predict reads; half the size to carry
    cli("predict", store, "--run", run_dir, "--samples", 16, "--antithetic", "--name", "cpu-pred", "-q")


def _slice_store(path: Path, image: np.ndarray) -> Path:
    """A data set holding one square slice as its Dremel reconstruction (a stand-in sinogram of 8 views)."""
    n = image.shape[0]
    geometry = Geometry.from_angles(np.linspace(0, 180, 8, endpoint=False), n, n, degrees=True)
    create_scan(path, geometry, np.zeros((1, 8, n), np.float32), {"file": "stand-in", "format": "npy"})
    store = DataStore.open(path, "r+")
    store.prepare_reconstruction("dremel", {"method": "dremel", "stand_in": True})
    store.write_reconstruction("dremel", 0, image)
    return path


def check(folder: Path, device: str, size: int, batches: list[int], out: Path) -> dict:
    """Steps (1)-(3) of the module docstring on a copy of ``folder``; the results."""
    from skimage.transform import resize

    work = Path(tempfile.mkdtemp())
    tiny, run_cpu = work / "tiny", work / "run_cpu"
    shutil.copytree(folder / "tiny", tiny)
    shutil.copytree(folder / "run_cpu", run_cpu)
    res: dict = {"device": device, "torch": torch.__version__, "cpu_threads": torch.get_num_threads()}
    if torch.cuda.is_available():
        res["gpu"] = torch.cuda.get_device_name(0)
    # (1) the CPU-trained network on the device
    res["predict_s"] = cli("predict", tiny, "--run", run_cpu, "--samples", 16, "--antithetic", "--device", device,
                            "--name", "dev-pred", "-q")  # fmt: skip
    store = DataStore.open(tiny)
    test = store.indices("test")
    cpu, dev = store.read_reconstruction("cpu-pred", test), store.read_reconstruction("dev-pred", test)
    cpu_std, dev_std = store.read_uncertainty("cpu-pred", test), store.read_uncertainty("dev-pred", test)
    res["mean_max_abs_diff"] = float(np.abs(cpu - dev).max())
    res["mean_range"] = float(cpu.max() - cpu.min())
    res["std_max_rel_diff"] = float((np.abs(cpu_std - dev_std) / np.maximum(cpu_std, 1e-6)).max())
    res["predict_peak_gb"] = _peak_gb()
    # (2) training, resuming, predicting and evaluating on the device
    for model, extra in (("ciunet-res", CIUNET), ("unet", UNET)):
        run_dir = work / f"run_{model}"
        common = ("--model", model, "--input", "dremel", "--precision", "bf16", "--device", device, "--out", run_dir)
        res[f"train_{model}_s"] = cli("train", tiny, *common, "--epochs", 4, "-q", *extra)
        res[f"train_{model}_peak_gb"] = _peak_gb()
        res[f"resume_{model}_s"] = cli("train", tiny, *common, "--epochs", 5, "-q", *extra)
        res[f"log_{model}_last"] = (run_dir / "log.csv").read_text().splitlines()[-1]
        samples = ["--samples", 16, "--antithetic"] if model != "unet" else []
        res[f"predict_{model}_s"] = cli("predict", tiny, "--run", run_dir, "--device", device, "-q", *samples)
    res["evaluate_s"] = cli("evaluate", tiny, "--out", work / "report")
    # (3) a large slice in tiles of the trained size
    image = resize(store.read_reconstruction("dremel", test[:1])[0], (size, size), order=1).astype(np.float32)
    big = _slice_store(work / "big", image)
    _peak_gb()
    res["tiled_cli_s"] = cli("predict", big, "--run", run_cpu, "--tile", 0, "--samples", 16, "--antithetic",
                              "--device", device, "--no-calibrate", "--split", "all", "-q")  # fmt: skip
    res["tiled_cli_peak_gb"] = _peak_gb()
    first = DataStore.open(big).read_reconstruction("dremel+ciunet-res", [0])[0]
    res["tiled_finite"] = bool(np.isfinite(first).all())
    for b in batches:
        for rep in range(2):
            start = time.perf_counter()
            name = f"b{b}_{rep}"
            predict(big, run_cpu, split="all", reconstruct_kwargs=SAMPLES, device=device, tile=0, batch_size=b,
                    calibrate=False, progress=False, name=name)  # fmt: skip
            res[f"tiled_batch{b}_{rep}_s"] = round(time.perf_counter() - start, 2)
            res[f"tiled_batch{b}_{rep}_peak_gb"] = _peak_gb()
    crop = image[(size - 512) // 2 : (size + 512) // 2, (size - 512) // 2 : (size + 512) // 2]
    for k, dev_name in enumerate(("cpu", device)):
        sub = _slice_store(work / f"crop{k}", crop)
        res[f"tiled512_{dev_name}_s"] = cli("predict", sub, "--run", run_cpu, "--tile", 0, "--samples", 16,
                                             "--antithetic", "--device", dev_name, "--no-calibrate", "--split", "all",
                                             "-q")  # fmt: skip
    res["max_rss_gb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 2)
    shutil.copy(work / "report" / "evaluation.md", out / "evaluation.md")
    shutil.rmtree(work, ignore_errors=True)
    return res


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("step", choices=("prepare", "check"))
    parser.add_argument("folder", type=Path)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--batches", default="16,64,256,1024")
    args = parser.parse_args()
    if args.step == "prepare":
        prepare(args.folder)
        return
    out = Path(os.environ.get("OUT", args.folder))
    res = check(args.folder, args.device, args.size, [int(b) for b in args.batches.split(",")], out)
    print(json.dumps(res, indent=1))
    (out / "check.json").write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
