"""How much the object's width-fifth coverage of a finished study moves with the network's training seed.

Usage::

    PYTHONPATH=src python benchmarks/coverage_seeds.py runs/tiny-parallel --row dremel+cinn-res --seeds 8 --work DIR

The companion of ``coverage_resplit.py``, which keeps the networks and moves the split: this keeps the
split and moves the network. The study's data set is copied to ``DIR`` (the study is not touched);
the row's network is trained again there by ``nanoct train`` with every argument of the study's run
(``runs/<model>-<input>/config.json``: epochs, batch size, learning rate and schedule, precision,
architecture), except the seed: ``--seed S`` (data order, training noise, initialisation) and, for a
model with an initialisation seed of its own (CiNN), ``--param seed=S``. Seed 0 is the study's own
run, copied. Each network predicts the test split with the study's sampling and calibrates where the
study did: on its calibration set (``<study>/calibration``, read only) where it has one, else on the
validation split (``nanoct predict --name <row>-sS [--calibrate-on]``), and ``nanoct evaluate``'s scores
are printed: PSNR, 90 % coverage of all pixels and of the object's support, and of the support's five half-width
fifths (narrowest first). Seed 0 must give the study's own numbers. With ``--fresh N`` the same
networks and intervals are also scored on N fresh test images (``--fresh-seed``, in ``DIR/fresh``),
which separates the networks from the draw of the study's 20 test images. ``DIR`` keeps everything:
run the command again to resume.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np

from cli_run import cli
from coverage_calibration_set import fresh_set
from coverage_resplit import BAND
from nanoct.evaluation.evaluate import evaluate_store
from nanoct.io.store import DataStore
from nanoct.names import parse_name
from nanoct.study.config import calibration_seed


def train_arguments(config: dict) -> list[str]:
    """The ``nanoct train`` options that repeat a run's ``config.json``, without its seed."""
    args = ["--model", config["model"], "--input", config["input"], "--epochs", config["epochs"]]
    args += ["--batch-size", config["batch_size"], "--lr", config["lr"], "--precision", config["precision"]]
    args += ["--lr-schedule", config["scheduler"] or "none"]
    for key, value in sorted(config["hparams"].items()):
        if key != "seed":
            args += ["--param", f"{key}={json.dumps(value)}"]
    return [str(a) for a in args]


def report(store: DataStore, names: list[str], level: str, title: str) -> None:
    """Print each seed's PSNR and coverage on the test split of ``store``, and the spread over the seeds."""
    scores = evaluate_store(store, "test", names)
    rows = []
    print(f"{title}, {float(level):.0%} intervals (support: object fifths, narrowest first)")
    for name in names:
        r = scores[name]["uncertainty"]
        sup, every = r["support"]["intervals"][level], r["all"]["intervals"][level]
        rows.append(sup["coverage_by_width"])
        print(f"  {name}: PSNR {scores[name]['psnr_mean']:.2f}, all {every['coverage']:.3f}, support "
              f"{sup['coverage']:.3f}, fifths " + " / ".join(f"{c:.3f}" for c in sup["coverage_by_width"]))  # fmt: skip
    cells = np.asarray(rows)
    inside = (cells >= BAND[0]) & (cells <= BAND[1])
    spread = zip(cells.min(axis=0), cells.mean(axis=0), cells.max(axis=0))
    per_fifth = "; ".join(f"{a:.3f} / {m:.3f} / {b:.3f}" for a, m, b in spread)
    print(f"  per fifth over the seeds, min / mean / max: {per_fifth}")
    print(f"  cells in {BAND[0]:.0%}-{BAND[1]:.0%}: {int(inside.sum())} of {inside.size}; seeds with all five in it: "
          f"{int(inside.all(axis=1).sum())} of {len(rows)}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", help="a finished 'nanoct reproduce --preset ...' folder (data, runs)")
    parser.add_argument("--row", default="dremel+cinn-res", help="<input>+<model> of a sampling network")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--level", default="0.9")
    parser.add_argument("--work", required=True)
    parser.add_argument("--fresh", type=int, default=0, help="also score on this many fresh test images")
    parser.add_argument("--fresh-seed", type=int, default=2_000_000, help="their data-set seed")
    args = parser.parse_args()
    study, work = Path(args.study), Path(args.work)
    source, model, _ = parse_name(args.row)
    if model is None:
        raise SystemExit(f"--row {args.row!r} must name a prediction, <input>+<model>")
    study_run = study / "runs" / f"{model}-{source}"
    config = json.loads((study_run / "config.json").read_text())
    sampling = DataStore.open(study / "data").reconstruction_params(args.row)["reconstruct"]  # the study's draws
    calibration = study / "calibration"
    calibrate = ["--calibrate-on", calibration] if (calibration / "zarr.json").is_file() else []
    data = work / "data"
    if not (data / "zarr.json").is_file():
        shutil.copytree(study / "data", data)
    flags = ["--samples", sampling["n_samples"], *calibrate] + (["--antithetic"] if sampling.get("antithetic") else [])
    start = time.perf_counter()
    names = []
    for seed in range(args.seeds):
        run_dir = work / f"run{seed}"
        if seed == 0:
            if not run_dir.is_dir():
                shutil.copytree(study_run, run_dir)
        else:  # a finished run is left as it is, an interrupted one resumes
            seeded = ["--seed", seed] + (["--param", f"seed={seed}"] if "seed" in config["hparams"] else [])
            cli("train", data, *train_arguments(config), "--out", run_dir, *seeded, "-q")
        name = f"{args.row}-s{seed}"
        cli("predict", data, "--run", run_dir, *flags, "--name", name, "-q")
        names.append(name)
    store = DataStore.open(data)
    report(store, names, args.level, f"{args.row}, test split")
    if args.fresh:
        if args.fresh_seed == calibration_seed(store.seed):
            raise SystemExit(f"--fresh-seed {args.fresh_seed} is the study's calibration-set seed; choose another")
        params = dict(store.reconstruction_params(source))
        inputs = {source: (params.pop("method"), params)}
        fresh = fresh_set(store, work / "fresh", args.fresh, args.fresh_seed, inputs, split_fractions=(0.0, 0.0, 1.0))
        for seed, name in enumerate(names):
            cli("predict", fresh.path, "--run", work / f"run{seed}", *flags, "--name", name, "-q")
        report(fresh, names, args.level, f"{args.row}, {fresh.n} fresh test images (data-set seed {args.fresh_seed})")
    print(f"total {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
