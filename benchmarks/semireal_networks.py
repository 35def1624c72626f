"""The post-processing networks on a real scan with a known added motion (semi-real evaluation).

Usage::

    PYTHONPATH=src python benchmarks/semireal_networks.py [--n 600] [--epochs-unet 8] [--epochs-ciunet 6]
        [--mix 0.3,0.1,0.3,0.3] [--hold-out] [--train-seed 1] [--slices 15,20,...,60] [--pictures docs/img]
        [--work DIR]

``--mix`` with a fourth number puts the scan's own measured pairs into the training set;
``--hold-out`` then keeps the evaluated slices and their neighbours out of it (``generate --like
--hold-out``), so that no evaluated slice's reference is trained on.

Data: Diamond I13-2 scan 24737 with the known motion of ``benchmarks/semireal_methods.py``
(its :func:`load_scan`, :func:`known_motion`, :func:`move`: horizontal drift, harmonics and jitter,
the vertical motion undone), the workflow a user with that scan would run, each step one CLI
command:

1. the moved scan as a data set (all 135 rows, 160 columns, axis given at +6.2 px), then
   ``nanoct stack`` on it (the stack's motion and axis);
2. ``nanoct generate --like MOVED --bin 2 --n N`` (80 x 80 images), ``nanoct reconstruct
   --method dremel --split all`` on it, and ``nanoct train`` of a UNet, of a residual UNet (a correction
   of its input, ``--param residual=true``) and of CiUNetRes on
   (Dremel, phantom) with the tiny study's architectures and learning rates (``docs/learn.md``) and a small budget
   (``--epochs-*``, ``--precision``: bf16 where the CPU runs it natively, as measured, else fp32);
3. the moved scan binned 2 x 2 into a data set of the matched set's geometry, ``nanoct
   reconstruct --method dremel`` (one joint motion for the stack) and ``nanoct predict`` of the three
   runs (CiUNetRes: 16 antithetic samples, intervals calibrated on the matched set's validation
   split, the out-of-distribution check of ``nanoct.learn.predict.ood_check``).

Reference: FBP of the unmoved scan, binned the same way, with the axis at +6.2 raw px (the
data's README: +6.4 by opposite views, +6.0 by algotom's ``find_center_vo``), the per-view air
level removed. Scores on the chosen binned slices (default 15 to 60, the rows with the
sample), inside the field-of-view disc (radius ``(L-1)/2 - |axis offset|``): PSNR (data range
of the reference there) and SSIM (scikit-image's map averaged over the disc), plain and after
the best sub-pixel translation onto the reference (the gauge no data fix,
:func:`nanoct.evaluation.metrics.register`; a translation of more than ``MAX_GAUGE_PX`` is not that
gauge but a failed registration, e.g. of a faint slice, and the image is then scored as it is);
90 % interval coverage of CiUNetRes against the
reference on the object (Gaussian-smoothed reference above 30 % of its 99th percentile in the
disc) and on the rest of the disc, with the same translation applied to mean and half-width; and,
since the reference is an FBP with noise of its own, also with the interval widened by that noise
(estimated from the references of the even and of the odd views, :func:`reference_noise`).

The intervals of the same CiUNetRes predictions are scored twice: calibrated on the matched set's
validation split (``predict``'s default) and on the scan's own measured pairs (``nanoct generate
--like MOVED --mix 0,0,0,1 --split-fractions 0,1,0``, then ``predict --calibrate-on``), the latter
also refitted without the pairs of the evaluated slices and, for comparison, without the
object-conditional multipliers, and checked on the pairs themselves (fitted on the even-numbered,
scored on the odd-numbered; :func:`pairs_cross_fit`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import zarr
from scipy import ndimage
from skimage.metrics import structural_similarity

from cli_run import cli
from nanoct.core.geometry import Geometry
from nanoct.evaluation.conformal import FOOTPRINT_TOLERANCE, footprint_outside, group_labels, half_width
from nanoct.evaluation.metrics import register, truth_support
from nanoct.io.store import DataStore, create_scan
from nanoct.learn.calibration import fit_intervals, reference_rule
from nanoct.recon.fbp import fbp
from nanoct.sim.matched import fov_disc, matched_source
from nanoct.sim.scan_stats import bin_sinograms, binned_offset
from semireal_methods import AXIS, air_removed, known_motion, load_scan, move

BIN = 2
UNET = ["--param", "out_bias=-7.0", "--param", "skip_channels=32"]
#: The UNet as a correction of its input (``residual=true``: linear output, starting at the input).
UNET_RES = ["--param", "skip_channels=32", "--param", "residual=true"]
CIUNET = ["--lr", "1e-3", "--param", "blocks_per_scale=1", "--param", "conditional_scale=location",
          "--param", "cond_channels=[16,16,32,32,64]", "--param", "target_noise_scale=range"]  # fmt: skip
ROWS = ("fbp", "dremel", "dremel+unet", "dremel+unet-res", "dremel+ciunet-res")
#: The same CiUNetRes predictions, their intervals calibrated on the scan's own measured pairs.
SCAN_CALIBRATED = "dremel+ciunet-res@pairs"
#: The largest translation (binned px) taken as the gauge: the added motion (drift 3 raw px, harmonics 1.2 and
#: 0.6 px, jitter) is under 3 binned px.
MAX_GAUGE_PX = 5.0


def build_stores(work: Path, proj: np.ndarray, moved: np.ndarray, angles: np.ndarray) -> tuple[Path, Path]:
    """The moved scan (full size) and, after stack + generate --like, the binned moved scan in the matched geometry."""
    full = Geometry.from_angles(angles, proj.shape[2], proj.shape[2], degrees=True, center_offset=AXIS)
    scan = {"file": "I13 24737 with added motion", "format": "tiff", "shared_motion": True}
    if not (work / "moved" / "zarr.json").is_file():  # a kept --work folder: the steps below resume
        create_scan(work / "moved", full, moved.transpose(1, 0, 2), scan)
    return work / "moved", work / "moved_bin2"


def reference(proj: np.ndarray, angles: np.ndarray, geometry: Geometry) -> tuple[np.ndarray, Geometry]:
    """FBP of every binned slice of the unmoved scan (air removed), axis +6.2 raw px; and its geometry."""
    sinos = bin_sinograms(proj.transpose(1, 0, 2), BIN)
    offset = binned_offset(AXIS, proj.shape[2], BIN)
    g = Geometry.from_dict({**geometry.to_dict(), "center_offset": offset})
    return np.stack([fbp(g, air_removed(s)).image for s in sinos]), g


def reference_noise(proj: np.ndarray, g: Geometry) -> np.ndarray:
    """Half the difference of the references from the even and from the odd views (per binned slice).

    With independent noise in the views, FBP from half the views has twice the variance of the
    reference, and the difference of the two halves four times: its half has the reference's noise
    level. The halves' own angular undersampling adds to it, so this over-states the noise.
    """
    sinos = bin_sinograms(proj.transpose(1, 0, 2), BIN)
    halves = []
    for part in (slice(0, None, 2), slice(1, None, 2)):
        angles = g.angles[part]
        gh = dataclasses.replace(g, n_angles=angles.size, view_angles=tuple(float(a) for a in angles))
        halves.append(np.stack([fbp(gh, air_removed(s[part])).image for s in sinos]))
    return (halves[0] - halves[1]) / 2


def fov(g: Geometry) -> np.ndarray:
    """The field-of-view disc of the binned images."""
    yy, xx = np.mgrid[: g.n, : g.n] - (g.n - 1) / 2
    return np.hypot(yy, xx) <= (g.n_det - 1) / 2 - abs(g.center_offset)


def object_mask(ref: np.ndarray, disc: np.ndarray) -> np.ndarray:
    """The object: the Gaussian-smoothed (1 px) reference above 30 % of its 99th percentile in the disc
    (:func:`nanoct.evaluation.metrics.truth_support`, not dilated: the object the calibration on measured
    pairs conditions on)."""
    return disc & truth_support(ref, 0, known=disc)


def score(image: np.ndarray, ref: np.ndarray, disc: np.ndarray) -> dict[str, float]:
    """PSNR and SSIM inside the disc, plain and registered; the translation."""
    span = float(ref[disc].max() - ref[disc].min())
    moved, shift = register(image, ref)
    if np.abs(shift).max() > MAX_GAUGE_PX:  # not the gauge: a failed registration
        moved, shift = image, np.zeros(2)
    out = {"shift": shift.tolist()}
    for key, x in (("plain", image), ("reg", moved)):
        out[f"psnr_{key}"] = float(10 * np.log10(span**2 / np.mean((x[disc] - ref[disc]) ** 2)))
        _, smap = structural_similarity(x, ref, data_range=span, full=True)
        out[f"ssim_{key}"] = float(smap[disc].mean())
    return out


def coverage(
    mean: np.ndarray, hw: np.ndarray, ref: np.ndarray, disc: np.ndarray, shift: list, noise: np.ndarray
) -> dict[str, float]:
    """Fraction of object and background pixels (in the disc) whose reference lies in ``mean +- hw``.

    ``*_noisy``: registered, the interval widened by the reference's own noise, ``sqrt(hw**2 + (z s)**2)``
    with z = 1.645 (90 %) and ``s`` the standard deviation of :func:`reference_noise` on the object or
    on the background of the slice: the interval an estimate of the truth gives for a reference
    that is the truth plus that noise.
    """
    obj = object_mask(ref, disc)
    out = {}
    for key, (m, h) in {
        "plain": (mean, hw),
        "reg": (ndimage.shift(mean, shift, order=1), ndimage.shift(hw, shift, order=1)),
    }.items():
        inside = np.abs(ref - m) <= h
        out[f"object_{key}"] = float(inside[obj].mean())
        out[f"background_{key}"] = float(inside[disc & ~obj].mean())
        if key == "reg":
            for part, where in (("object", obj), ("background", disc & ~obj)):
                wide = np.hypot(h, 1.645 * float(noise[where].std()))
                out[f"{part}_noisy"] = float((np.abs(ref - m) <= wide)[where].mean())
    out["object_px"] = int(obj.sum())
    out["reference_noise_object"] = float(noise[obj].std())
    return out


def matched_set(work: Path, n: int, mix: str, hold: list[str], times: dict[str, float]) -> Path:
    """``nanoct stack`` of the moved scan, ``nanoct generate --like`` it (``n`` samples, ``--mix``, ``hold``: the
    ``--hold-out`` arguments or none) and Dremel on every split of that matched set; the set's path."""
    moved, matched = work / "moved", work / "matched"
    times["stack"] = cli("stack", moved, "-w", 2, "-q")
    times["generate"] = cli("generate", "--like", moved, "--bin", BIN, "--n", n, "--out", matched,
                             "--split-fractions", "0.85,0.14,0.01", "--mix", mix, *hold, "-q")  # fmt: skip
    times["dremel (matched set)"] = cli("reconstruct", matched, "--method", "dremel", "--split", "all", "-q")
    return matched


def train_ciunet(matched: Path, run: Path, epochs: int, precision: str, seed: int) -> float:
    """``nanoct train`` of CiUNetRes on (Dremel, phantom) of the matched set with the tiny study's settings; seconds."""
    return cli("train", matched, "--model", "ciunet-res", "--input", "dremel", "--epochs", epochs, "--precision",
               precision, "--out", run, "-q", "--seed", seed, *CIUNET)  # fmt: skip


def binned_scan(work: Path, times: dict[str, float]) -> Path:
    """The moved scan binned into a data set of the matched set's geometry (made once), and its Dremel; its path."""
    real = work / "moved_bin2"
    if not (real / "zarr.json").is_file():
        g = DataStore.open(work / "matched").geometry
        sinos = bin_sinograms(DataStore.open(work / "moved").read_array("sinograms", range(135)), BIN)
        create_scan(real, g, sinos, {"file": "I13 24737 with added motion, binned 2", "format": "npy"})
    times["dremel (scan)"] = cli("reconstruct", real, "--method", "dremel", "-q")
    return real


def train_and_predict(work: Path, args: argparse.Namespace, times: dict[str, float]) -> dict[str, str]:
    """Generate the matched set, train both networks, predict the binned moved scan; the result names."""
    hold = ["--hold-out", held_out_rows(args.slices)] if args.hold_out else []
    matched = matched_set(work, args.n, args.mix, hold, times)
    runs = {"unet": work / "run_unet", "unet-res": work / "run_unet_res", "ciunet-res": work / "run_ciunet"}
    seed = ["--seed", args.train_seed]
    for key, extra in (("unet", UNET), ("unet-res", UNET_RES)):
        times[f"train {key}"] = cli("train", matched, "--model", "unet", "--input", "dremel", "--epochs",
                                     args.epochs_unet, "--precision", args.precision, "--out", runs[key], "-q", *seed,
                                     *extra)  # fmt: skip
    times["train ciunet-res"] = train_ciunet(matched, runs["ciunet-res"], args.epochs_ciunet, args.precision,
                                             args.train_seed)  # fmt: skip
    real = binned_scan(work, times)
    times["predict unet"] = cli("predict", real, "--run", runs["unet"], "-q")
    times["predict unet-res"] = cli("predict", real, "--run", runs["unet-res"], "--name", "dremel+unet-res", "-q")
    # the scan's own measured pairs (its views, the stack's motion undone, a drawn motion added; its FBP as
    # reference): a second calibration of the same predictions, on the scan itself
    pairs = work / "pairs"
    times["generate pairs"] = cli("generate", "--like", work / "moved", "--bin", BIN, "--mix", "0,0,0,1", "--n",
                                   args.n_pairs, "--split-fractions", "0,1,0", "--seed", 1, "--out", pairs,
                                   "-q")  # fmt: skip
    times["dremel (pairs)"] = cli("reconstruct", pairs, "--method", "dremel", "--split", "all", "-q")
    times["predict pairs"] = cli("predict", pairs, "--run", runs["ciunet-res"], "--split", "val", "--samples", 16,
                                  "--antithetic", "-q")  # fmt: skip
    times["predict ciunet-res (scan-calibrated)"] = cli(
        "predict", real, "--run", runs["ciunet-res"], "--samples", 16, "--antithetic", "--calibrate-on", pairs,
        "--name", SCAN_CALIBRATED, "-q")  # fmt: skip
    # the intervals' calibration is fitted on the matched set's validation split, then reused on the scan
    times["calibrate ciunet-res"] = cli("predict", matched, "--run", runs["ciunet-res"], "--split", "val",
                                         "--samples", 16, "--antithetic", "-q")  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        times["predict ciunet-res"] = cli("predict", real, "--run", runs["ciunet-res"], "--samples", 16,
                                           "--antithetic", "-q")  # fmt: skip
    for w in caught:
        print(f"warning: {w.message}")
    return {"unet": "dremel+unet", "unet-res": "dremel+unet-res", "ciunet-res": "dremel+ciunet-res"}


def held_out_rows(slices: str) -> str:
    """``--hold-out`` rows of the evaluated binned slices and their neighbours (binned slices s - 1 to s + 1)."""
    return ",".join(f"{max(0, BIN * (s - 1))}:{BIN * (s + 2)}" for s in (int(v) for v in slices.split(",")))


def evaluate(work: Path, refs: np.ndarray, noise: np.ndarray, g_ref: Geometry, slices: list[int]) -> tuple[dict, dict]:
    """Scores per slice and row, coverage of CiUNetRes, and the images for the pictures."""
    store = DataStore.open(work / "moved_bin2")
    disc = fov(g_ref)
    name = "dremel+ciunet-res"
    params = store.reconstruction_params(name)
    mean, std = store.read_reconstruction(name, slices), store.read_uncertainty(name, slices)
    hws = half_width(params, std, 0.9, mean=mean)
    images = {row: store.read_reconstruction(row, slices) for row in ROWS[1:]}
    sinos = store.read_array("sinograms", slices)
    images["fbp"] = np.stack([fbp(store.geometry, air_removed(s)).image for s in sinos])
    calibrations = {
        "matched": hws,
        "pairs": half_width(store.reconstruction_params(SCAN_CALIBRATED), std, 0.9, mean=mean),
        "pairs_other_slices": half_width({"calibration": pairs_fit_without(work, slices)}, std, 0.9, mean=mean),
        "pairs_not_object_conditional": half_width(
            {"calibration": pairs_fit_without(work, [], object_conditional=False, footprint=False)}, std, 0.9, mean=mean
        ),
        "pairs_no_footprint": half_width(
            {"calibration": pairs_fit_without(work, [], footprint=False)}, std, 0.9, mean=mean
        ),
    }
    table = {}
    for i, s in enumerate(slices):
        table[s] = {row: score(images[row][i], refs[s], disc) for row in ROWS}
        shift = table[s][name]["shift"]
        obj = object_mask(refs[s], disc)
        for key, hw in calibrations.items():
            table[s][f"coverage_{key}"] = coverage(mean[i], hw[i], refs[s], disc, shift, noise[s])
            table[s][f"width_{key}"] = float(np.median(2 * hw[i][obj]))
            table[s][f"width_background_{key}"] = float(np.median(2 * hw[i][disc & ~obj]))
    table["object_by_group_pairs"] = object_by_group(
        store.reconstruction_params(SCAN_CALIBRATED), mean, std, calibrations["pairs"], refs[slices], disc,
        [table[s][name]["shift"] for s in slices],
    )  # fmt: skip
    outside = (np.abs(refs[slices] - mean) > calibrations["pairs"]) & disc
    images.update(std=std, reference=refs[slices], outside=outside)
    table["ood"] = store.reconstruction_note(name, "ood")
    table["ood_pairs"] = store.reconstruction_note(SCAN_CALIBRATED, "ood")
    return table, images


def object_by_group(
    params: dict, mean: np.ndarray, std: np.ndarray, hw: np.ndarray, refs: np.ndarray, disc: np.ndarray, shifts: list
) -> list[list[int]]:
    """Object pixels covered and counted per prediction-time group (0: labelled background, outside the sample's
    footprint where the calibration has one, 1-5: the object's std fifths, 6: labelled background inside the
    footprint) over the evaluated slices, registered: the coverage on the object in every width fifth."""
    groups = params["calibration"]["levels"]["0.9"]["groups"]
    labels = group_labels(std, groups, mean)
    n_groups = len(groups["multipliers"])
    counts = np.zeros((n_groups, 2), np.int64)
    for i, shift in enumerate(shifts):
        m, h = ndimage.shift(mean[i], shift, order=1), ndimage.shift(hw[i], shift, order=1)
        lab = ndimage.shift(labels[i], shift, order=0, mode="nearest")
        obj, inside = object_mask(refs[i], disc), np.abs(refs[i] - m) <= h
        for g in range(n_groups):
            counts[g] += [int(inside[obj & (lab == g)].sum()), int((obj & (lab == g)).sum())]
    return counts.tolist()


def pairs_fit_without(work: Path, slices: list[int], object_conditional: bool = True, footprint: bool = True) -> dict:
    """The calibration on the measured pairs whose scan slice is none of the evaluated ``slices`` (the pairs'
    validation predictions of ``predict pairs --split val``, refitted here without those slices, as
    ``predict --calibrate-on`` fits: :func:`nanoct.learn.calibration.reference_rule`; for comparison, with
    ``footprint`` False without the background's split at the sample's footprint, with ``object_conditional``
    False with the group multipliers alone)."""
    pairs = DataStore.open(work / "pairs")
    rows = zarr.open_group(str(pairs.path), mode="r")["like_measured"].attrs["rows"]
    val = pairs.indices("val")
    keep = np.array([rows[matched_source(pairs, int(i))[1]] // BIN not in slices for i in val])
    kept = val[keep]
    print(f"pairs without the evaluated slices: {kept.size} of {val.size}")
    means, stds, gts = _pairs_outputs(pairs, kept)
    rule = reference_rule(pairs, gts) | {"object_conditional": object_conditional, "footprint": footprint}
    return fit_intervals(means, stds, gts, levels=(0.9,), **rule)


def _pairs_outputs(pairs: DataStore, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CiUNetRes's mean and std on the measured pairs ``indices`` (``predict pairs --split val``), their references."""
    name = "dremel+ciunet-res"
    return pairs.read_reconstruction(name, indices), pairs.read_uncertainty(name, indices), pairs.read_phantoms(indices)


def pairs_cross_fit(work: Path) -> None:
    """The pairs' own check: intervals fitted on the even-numbered pairs, scored on the odd ones (object and
    background of :func:`object_mask` inside the field of view), for the delivered rule and for variants."""
    pairs = DataStore.open(work / "pairs")
    val = pairs.indices("val")
    means, stds, gts = _pairs_outputs(pairs, val)
    rule = reference_rule(pairs, gts)
    disc = fov_disc(pairs.geometry) > 0
    fit_on, score_on = np.arange(val.size) % 2 == 0, np.arange(val.size) % 2 == 1
    obj = np.stack([object_mask(g, disc) for g in gts[score_on]])
    variants = {
        "delivered (relative support, field of view, object-conditional, footprint)": rule,
        "relative support, field of view, object-conditional": rule | {"footprint": False},
        "relative support, field of view": rule | {"object_conditional": False, "footprint": False},
        "relative support, field of view, not dilated": rule
        | {"support_radius": 0, "object_conditional": False, "footprint": False},
        "relative support, all pixels": {"support_source": "relative"},
        "std support, field of view": {"known": rule["known"]},
        "std support, all pixels": {},
    }
    print("\nmeasured pairs, fitted on the even ones and scored on the odd ones (90 %; object / background):")
    for label, kwargs in variants.items():
        fit = fit_intervals(means[fit_on], stds[fit_on], gts[fit_on], levels=(0.9,), **kwargs)
        hw = half_width({"calibration": fit}, stds[score_on], 0.9, mean=means[score_on])
        inside = np.abs(means[score_on] - gts[score_on]) <= hw
        print(f"  {label}: {inside[obj].mean():.3f} / {inside[~obj & disc].mean():.3f}")


def summarize(table: dict, slices: list[int]) -> None:
    """Mean scores per row, coverage means, and the OOD record."""
    print("\nrow | PSNR plain | PSNR registered | SSIM plain | SSIM registered (means over slices)")
    for row in ROWS:
        vals = {k: np.mean([table[s][row][k] for s in slices]) for k in ("psnr_plain", "psnr_reg", "ssim_plain",
                                                                          "ssim_reg")}  # fmt: skip
        print(f"{row} | {vals['psnr_plain']:.2f} | {vals['psnr_reg']:.2f} | {vals['ssim_plain']:.3f} | "
              f"{vals['ssim_reg']:.3f}")  # fmt: skip
    for row in ROWS[2:]:
        d = [table[s][row]["psnr_reg"] - table[s]["dremel"]["psnr_reg"] for s in slices]
        print(f"{row} - dremel (registered PSNR): mean {np.mean(d):+.2f} dB, worst {min(d):+.2f}, best {max(d):+.2f}")
    for key in ("matched", "pairs", "pairs_other_slices", "pairs_no_footprint", "pairs_not_object_conditional"):
        cov = {
            k: np.mean([table[s][f"coverage_{key}"][k] for s in slices]) for k in table[slices[0]]["coverage_matched"]
        }
        widths = [np.mean([table[s][f"width{part}_{key}"] for s in slices]) for part in ("", "_background")]
        print(f"CiUNetRes 90 % intervals calibrated on {key}, mean over slices: "
              + ", ".join(f"{k} {v:.3f}" for k, v in cov.items())
              + f"; median width object {widths[0]:.4f}, background {widths[1]:.4f}")  # fmt: skip
        print(
            "  per slice (object coverage registered, median interval width on the object): "
            + ", ".join(
                f"{s}: {table[s][f'coverage_{key}']['object_reg']:.2f}/{table[s][f'width_{key}']:.4f}" for s in slices
            )  # fmt: skip
        )
    by_group = table.get("object_by_group_pairs")
    if by_group:
        print("  object coverage by group, calibrated on pairs (labelled background outside the footprint, std fifths "
              "1-5, labelled background inside the footprint; covered/pixels): "
              + ", ".join(f"{c / n:.3f} ({n})" if n else "- (0)" for c, n in by_group))  # fmt: skip
    for key, against in (("ood", "matched set"), ("ood_pairs", "measured pairs")):
        ood = table.get(key) or {}
        print(
            f"OOD against the {against} ({ood.get('statistic')}, alpha {ood.get('alpha')}): flagged "
            f"{ood.get('flagged')}; by {json.dumps(ood.get('flagged_by'))}"
        )
        outside = (ood.get("footprint") or {}).get("outside")
        if outside:
            print(
                f"  support outside the pairs' footprint (field of view): largest {max(outside.values()):.4f} "
                f"(slice {max(outside, key=outside.get)}), evaluated slices "
                + ", ".join(f"{s}: {outside[str(s)]:.4f}" for s in slices)
            )


def footprint_check(work: Path) -> None:
    """What ``predict``'s footprint check (:func:`nanoct.evaluation.conformal.footprint_outside`, the field of view)
    would see on the scan's pairs-calibrated CiUNetRes predictions, all slices, moved by 3 and 5 px along the rows and
    mirrored left-right (images that are not the calibrating scan as it lay; the predictions as they are: predict's
    own record, printed with the OOD flags)."""
    store = DataStore.open(work / "moved_bin2")
    groups = store.reconstruction_params(SCAN_CALIBRATED)["calibration"]["levels"]["0.9"]["groups"]
    every = np.arange(store.n)
    mean, std = store.read_reconstruction(SCAN_CALIBRATED, every), store.read_uncertainty(SCAN_CALIBRATED, every)
    known = fov_disc(store.geometry) > 0

    def moved(d: int) -> tuple[np.ndarray, np.ndarray]:
        return ndimage.shift(mean, (0, 0, d), order=1), ndimage.shift(std, (0, 0, d), order=1)

    cases = {"moved 3 px": moved(3), "moved 5 px": moved(5)}
    cases["mirrored"] = (mean[:, :, ::-1], std[:, :, ::-1])
    print(f"footprint check (flagged: more than {FOOTPRINT_TOLERANCE:.0%} of the support outside the footprint):")
    for key, (m, s) in cases.items():
        f = footprint_outside(s, groups, m, known)
        flagged = int((f > FOOTPRINT_TOLERANCE).sum())
        print(f"  {key}: median {np.median(f):.4f}, largest {f.max():.4f}, flagged {flagged} of {f.size} slices")


def save_picture(folder: Path, table: dict, images: dict, slices: list[int], chosen: list[int]) -> None:
    """Reference, FBP, Dremel, +UNet, +residual UNet, +CiUNetRes and its std for the chosen slices."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = ("reference", *ROWS, "std", "outside")
    fig, axes = plt.subplots(len(chosen), len(cols), figsize=(2.2 * len(cols), 2.3 * len(chosen)), squeeze=False)
    for i, s in enumerate(chosen):
        j = slices.index(s)
        ref = images["reference"][j]
        lo, hi = float(np.percentile(ref, 1)), float(np.percentile(ref, 99.8))
        for k, col in enumerate(cols):
            ax = axes[i, k]
            image = images[col][j]
            scale = {"std": {}, "outside": {"vmin": 0, "vmax": 1}}.get(col, {"vmin": lo, "vmax": hi})
            ax.imshow(image, cmap={"std": "magma", "outside": "Reds"}.get(col, "gray"), **scale)
            extra = f"\n{table[s][col]['psnr_reg']:.1f} dB" if col in ROWS else ""
            title = col
            if col == "outside":
                covered = table[s]["coverage_pairs"]["object_plain"]
                title, extra = "outside the 90 % interval", f"\nobject {100 * covered:.0f} % covered (unregistered)"
            ax.set_title(f"{title} {s}{extra}", fontsize=8)
            ax.axis("off")
    fig.suptitle("I13 24737 with added motion, binned 2: networks trained on the matched set", fontsize=10)
    fig.tight_layout()
    folder.mkdir(parents=True, exist_ok=True)
    fig.savefig(folder / "semireal_networks.png", dpi=80)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=600)
    parser.add_argument("--epochs-unet", type=int, default=8)
    parser.add_argument("--epochs-ciunet", type=int, default=6)
    parser.add_argument("--n-pairs", type=int, default=300, help="measured pairs of the scan for the calibration")
    parser.add_argument("--train-seed", type=int, default=0, help="nanoct train --seed of both networks")
    parser.add_argument("--precision", default="auto", help="nanoct train --precision (the documented runs: bf16)")
    parser.add_argument(
        "--mix", default="0.4,0.2,0.4", help="the matched set's --mix (a fourth number: measured pairs)"
    )
    parser.add_argument(
        "--hold-out", action="store_true", help="keep the evaluated slices and their neighbours out of the matched set"
    )
    parser.add_argument("--json", default=None, help="write the per-slice table here")
    parser.add_argument("--slices", default=",".join(str(s) for s in range(15, 61, 5)))
    parser.add_argument("--pictures", default=None)
    parser.add_argument("--picture-slices", default="20,35,50")
    parser.add_argument("--work", default=None, help="keep the stores and runs here (default: a temporary folder)")
    args = parser.parse_args()
    slices = [int(s) for s in args.slices.split(",")]
    start = time.perf_counter()
    proj, angles = load_scan()
    h, v = known_motion(proj.shape[0])
    moved = move(proj, h, v)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        build_stores(work, proj, moved, angles)
        times: dict[str, float] = {}
        train_and_predict(work, args, times)
        refs, g_ref = reference(proj, angles, DataStore.open(work / "matched").geometry)
        table, images = evaluate(work, refs, reference_noise(proj, g_ref), g_ref, slices)
        print("\nseconds: " + ", ".join(f"{k} {v:.0f}" for k, v in times.items()))
        print(f"matched set: {json.dumps(DataStore.open(work / 'matched').meta['simulation']['like'])}")
        summarize(table, slices)
        footprint_check(work)
        pairs_cross_fit(work)
        if args.json:
            Path(args.json).write_text(json.dumps({str(k): v for k, v in table.items()}, indent=1))
        if args.pictures:
            chosen = [s for s in (int(s) for s in args.picture_slices.split(",")) if s in slices]
            save_picture(Path(args.pictures), table, images, slices, chosen)
    print(f"\ntotal {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
