"""Would a calibration set apart from the validation split lift the object's width-fifth coverage?

Usage::

    PYTHONPATH=src python benchmarks/coverage_calibration_set.py runs/tiny-parallel --n 200 --work DIR

The third of the coverage benchmarks (``coverage_resplit.py`` moves the split, ``coverage_seeds.py``
the network). The study calibrates its intervals on the validation split, which also chose each
network's checkpoint (lowest validation loss), so its errors may be slightly optimistic; and it has
20 images. Here a fresh set of ``--n`` images of the study's preset and simulation, under another
data-set seed (``--seed``, never the study's), is simulated into ``DIR`` and reconstructed by each
calibrated prediction's input; it is exchangeable with the test split and unseen by training and
checkpoint choice. For every calibrated prediction of the study (Dremel/RESESOP + CiNNRes/CiUNetRes
...) the network's mean and raw std on the fresh images are made as ``predict`` makes them, and the
group-conditional intervals (:func:`nanoct.learn.calibration.fit_intervals`) are fitted on

* the validation split (as the study does; must give the study's own numbers),
* ``k`` fresh images, for ``k`` in ``--sizes``, ``--draws`` random subsets each,

and scored on the study's test split as ``nanoct evaluate`` scores them (coverage of the object's
support in five half-width fifths, narrowest first). Also printed: the validation-fitted intervals
scored on all fresh images (is the validation split optimistic, or the test split unlucky?).
``DIR`` keeps the fresh set: run the command again to reuse it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from coverage_resplit import BAND, fifths
from nanoct.io.store import DataStore
from nanoct.learn.calibration import fit_intervals, sample_outputs
from nanoct.learn.checkpoint import load_checkpoint, model_from_checkpoint
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset
from nanoct.sim.simulate import SimulationConfig


def fresh_set(
    study: DataStore,
    work: Path,
    n: int,
    seed: int,
    inputs: dict[str, tuple[str, dict]],
    split_fractions: tuple[float, float, float] = (0.0, 1.0, 0.0),
) -> DataStore:
    """``n`` samples of the study's geometry and simulation under ``seed`` (validation-only unless
    ``split_fractions`` says otherwise), reconstructed by ``inputs`` (name: method, parameters); resumable."""
    if seed == study.seed:
        raise SystemExit(f"--seed {seed} is the study's own data-set seed; choose another")
    config = SimulationConfig.from_dict(study.meta["simulation"])
    generate_dataset(work, study.geometry, n, seed=seed, config=config, split_fractions=split_fractions, workers=0)
    for name, (method, params) in inputs.items():
        reconstruct_dataset(work, method, params=params, name=name, workers=0)
    return DataStore.open(work)


def pct(values: np.ndarray) -> str:
    return " / ".join(f"{100 * v:.1f}" for v in values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("study", type=Path)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1_000_000)
    parser.add_argument("--sizes", default="20,40,100,200")
    parser.add_argument("--draws", type=int, default=10)
    parser.add_argument("--level", type=float, default=0.9)
    args = parser.parse_args()
    study = DataStore.open(args.study / "data")
    names = sorted(n for n in study.reconstruction_names() if "calibration" in study.reconstruction_params(n))
    inputs = {}
    for name in names:
        own = study.reconstruction_params(name)["input"]
        params = dict(study.reconstruction_params(own))
        inputs[own] = (params.pop("method"), params)
    fresh = fresh_set(study, args.work, args.n, args.seed, inputs)
    rng = np.random.default_rng(0)
    sizes = [k for k in (int(v) for v in args.sizes.split(",")) if k <= fresh.n]
    test, val, new = study.indices("test"), study.indices("val"), fresh.indices("val")
    tally = {"val": 0, **{k: 0 for k in sizes}}
    for name in names:
        start = time.perf_counter()
        p = study.reconstruction_params(name)
        path = Path(p["run"]) / f"{p['checkpoint']}.pt"
        model = model_from_checkpoint(load_checkpoint(path), path)
        tm, ts = study.read_reconstruction(name, test), study.read_uncertainty(name, test)
        tg = study.read_phantoms(test)
        vm, vs = sample_outputs(model, study, p["input"], val, p["reconstruct"])
        fm, fs = sample_outputs(model, fresh, p["input"], new, p["reconstruct"])
        vg, fg = study.read_phantoms(val), fresh.read_phantoms(new)
        stored = fifths(tm, ts, tg, p["calibration"], args.level)
        on_val = fit_intervals(vm, vs, vg, levels=(args.level,))
        own = fifths(tm, ts, tg, on_val, args.level)
        print(f"\n{name} ({time.perf_counter() - start:.0f} s to sample)")
        print(f"  stored (validation split, {val.size})  : {pct(stored)}")
        print(f"  refitted on the validation split    : {pct(own)}")
        print(f"  validation fit scored on the fresh {new.size}: {pct(fifths(fm, fs, fg, on_val, args.level))}")
        tally["val"] += int(np.all((own >= BAND[0]) & (own <= BAND[1])))
        for k in sizes:
            runs = []
            for _ in range(args.draws if k < new.size else 1):
                pick = rng.permutation(new.size)[:k]
                fit = fit_intervals(fm[pick], fs[pick], fg[pick], levels=(args.level,))
                runs.append(fifths(tm, ts, tg, fit, args.level))
            runs = np.array(runs)
            inside = np.all((runs >= BAND[0]) & (runs <= BAND[1]), axis=1)
            tally[k] += int(inside.mean() >= 0.5)
            print(
                f"  fresh {k:4d} (median of {len(runs):2d})         : {pct(np.median(runs, axis=0))}"
                f"   all five in {100 * BAND[0]:.0f}-{100 * BAND[1]:.0f} %: {inside.sum()} of {len(runs)}"
            )
    print(f"\nrows with all five fifths in band (median draw): validation {tally['val']} of {len(names)}; "
          + "; ".join(f"fresh {k}: {tally[k]}" for k in sizes))  # fmt: skip


if __name__ == "__main__":
    main()
