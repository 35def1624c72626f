"""The paper's stated conclusions as checks on our per-image results, with their spread.

Each conclusion of the paper (results section and discussion) is turned into a list of
comparisons between rows; a comparison is a contrast of rows, e.g. ``dremel - fbp`` or the
difference of two gains ``(resesop+unet - resesop) - (fbp+unet - fbp)``, in PSNR or SSIM.

Statistics
----------
Every row holds one value per test image (the same images, in the same order, for every
row), so a contrast is computed per image and then averaged: ``diff`` is the paired mean
difference and ``se`` its standard error, ``std(per-image contrast, ddof=1) / sqrt(n)``.
A row may also hold values for several training seeds (an ``(S, n)`` array); its per-image
values are then averaged over the seeds first, and the variance of its per-seed means over
the images divided by ``S`` is added to ``se**2`` (weighted by the squared coefficient of the
row in the contrast). That adds the run-to-run spread of training, which pairing over images
does not see; it counts some of the seed noise twice, so it errs on the cautious side.

A comparison **holds** when ``diff > k * se``, **does not hold** when ``diff < -k * se`` and
is **undecided** otherwise (within the noise; also when ``n < 2``). A conclusion holds when
every comparison that could be made holds, does not hold when at least one does not hold,
is undecided otherwise, and is **not applicable** when none of its rows are there. Missing
rows are listed with each conclusion.

The same checks run on the paper's published means (:func:`paper_conclusions`, with
``se = 0``: a comparison holds when the paper's mean difference is positive), which shows
which conclusions the paper's own tables support in the form checked here.

Input format
------------
``{name: {"psnr": per-image values, "ssim": per-image values}}``, names as
:mod:`nanoct.evaluation.evaluate` gives them (``fbp``, ``resesop_eta0.8``, ``resesop+unet``,
``resesop+unet@fbp``); values are 1-D arrays of length n (the test images), or 2-D arrays
``(S, n)`` for S training seeds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.names import SETTINGS, parse_name, prediction_name
from .paper import INPUTS, MODELS, paper_mixing, paper_rows

__all__ = [
    "CLAIMS",
    "VERDICTS",
    "check_conclusions",
    "format_conclusions",
    "paper_conclusions",
]

#: Possible verdicts, of a comparison and of a conclusion.
VERDICTS = ("holds", "does not hold", "undecided", "not applicable")
_METRICS = ("psnr", "ssim")
_INNS = ("cinn", "cinn-res", "ciunet", "ciunet-res")
_RESIDUAL_PAIRS = (("cinn-res", "cinn"), ("ciunet-res", "ciunet"))


@dataclass(frozen=True)
class _Contrast:
    """``sum(coef * row)`` in one metric; positive means the claim's direction."""

    label: str
    metric: str
    terms: tuple[tuple[str, float], ...]


def _beats(a: str, b: str, metric: str) -> _Contrast:
    return _Contrast(f"{a} > {b}", metric, ((a, 1.0), (b, -1.0)))


def _gain_beats(a: str, a0: str, b: str, b0: str, metric: str) -> _Contrast:
    label = f"gain {a} over {a0} > gain {b} over {b0}"
    return _Contrast(label, metric, ((a, 1.0), (a0, -1.0), (b, -1.0), (b0, 1.0)))


class _Rows:
    """Per-image values of every row: contrasts with their paired standard error."""

    def __init__(self, values: Mapping[str, Mapping[str, Any]], exact: bool = False):
        self.exact = exact  # published means: one value per row, no spread
        self.values: dict[str, dict[str, np.ndarray]] = {}
        lengths = set()
        for name, scores in values.items():
            row = {}
            for metric in _METRICS:
                if metric not in scores:
                    raise NanoctError(f"row {name!r} has no {metric!r} values; give per-image 'psnr' and 'ssim'")
                arr = np.asarray(scores[metric], dtype=np.float64)
                arr = arr[None] if arr.ndim == 1 else arr
                if arr.ndim != 2 or arr.size == 0 or not np.isfinite(arr).all():
                    raise NanoctError(
                        f"row {name!r}, {metric}: expected finite per-image values, shape (n,) or (seeds, n); "
                        f"got shape {np.shape(scores[metric])} (non-finite values are not allowed)"
                    )
                row[metric] = arr
                lengths.add(arr.shape[1])
            self.values[name] = row
        if len(lengths) > 1:
            raise NanoctError(
                f"rows have different numbers of test images {sorted(lengths)}; paired comparisons need the "
                "same images in the same order for every row"
            )

    @property
    def names(self) -> set[str]:
        return set(self.values)

    def mean(self, name: str, metric: str) -> float:
        return float(self.values[name][metric].mean())

    def contrast(self, c: _Contrast) -> dict[str, Any]:
        per_image = sum(coef * self.values[name][c.metric].mean(axis=0) for name, coef in c.terms)
        n = per_image.size
        diff = float(per_image.mean())
        if self.exact:
            se = 0.0
        else:
            var = per_image.var(ddof=1) / n if n > 1 else math.nan
            for name, coef in c.terms:
                arr = self.values[name][c.metric]
                if arr.shape[0] > 1:
                    var += coef**2 * arr.mean(axis=1).var(ddof=1) / arr.shape[0]
            se = math.sqrt(var)
        seeds = max(self.values[name][c.metric].shape[0] for name, _ in c.terms)
        se_out = None if math.isnan(se) else se  # None: no spread from a single image (JSON has no NaN)
        return {"label": c.label, "metric": c.metric, "diff": diff, "se": se_out, "n": int(n), "seeds": int(seeds)}


def _inputs(rows: _Rows, setting: str, *models: str) -> list[str]:
    """Inputs (paper order) with a row for one of ``models``; if none, those of the paper's table.

    The fallback lets a check with no rows at all name the rows it needed.
    """
    found = [i for i in INPUTS if any(prediction_name(i, m) in rows.names for m in models)]
    return found or sorted({e.input for e in paper_rows(setting) if e.model in models}, key=INPUTS.index)


def _methods_beat_fbp(rows: _Rows, setting: str) -> list[_Contrast]:
    return [_beats(t, "fbp", m) for t in ("dremel", "resesop") for m in _METRICS]


def _unet_largest_gain(rows: _Rows, setting: str) -> list[_Contrast]:
    metrics = ("psnr",) if setting == "unperturbed" else _METRICS
    return [
        _beats(prediction_name(t, "unet"), prediction_name(t, n), m)
        for t in _inputs(rows, setting, "unet")
        for n in _INNS
        for m in metrics
    ]


def _resesop_unet_best(rows: _Rows, setting: str) -> list[_Contrast]:
    names = rows.names or {e.name for e in paper_rows(setting)}  # no rows: name those needed
    best = prediction_name("resesop", "unet")
    others = sorted(n for n in names if parse_name(n)[2] == parse_name(n)[0] and n != best)
    return [_beats(best, o, m) for o in others for m in _METRICS]


def _unet_gain_largest_on_resesop(rows: _Rows, setting: str) -> list[_Contrast]:
    return [
        _gain_beats(prediction_name("resesop", "unet"), "resesop", prediction_name(t, "unet"), t, "psnr")
        for t in ("fbp", "dremel")
    ]


def _improve(models: tuple[str, ...], inputs: tuple[str, ...] | None = None) -> Callable[[_Rows, str], list]:
    def build(rows: _Rows, setting: str) -> list[_Contrast]:
        out = []
        for model in models:
            for t in inputs or _inputs(rows, setting, model):
                out += [_beats(prediction_name(t, model), t, m) for m in _METRICS]
        return out

    return build


def _residual_beats_nonresidual(rows: _Rows, setting: str) -> list[_Contrast]:
    out = []
    for res, plain in _RESIDUAL_PAIRS:
        inputs = _inputs(rows, setting, res, plain)
        out += [_beats(prediction_name(t, res), prediction_name(t, plain), m) for t in inputs for m in _METRICS]
    return out


def _nonresidual_worsen(rows: _Rows, setting: str) -> list[_Contrast]:
    pairs = [(t, n) for t in ("dremel", "resesop") for n in ("cinn", "ciunet")]
    return [
        _beats(t, prediction_name(t, n), m)
        for t, n in pairs
        for m in _METRICS
        if (t, n, m) != ("resesop", "cinn", "psnr")
    ]


def _nonresidual_lower_ssim(rows: _Rows, setting: str) -> list[_Contrast]:
    return [_beats("fbp", prediction_name("fbp", n), "ssim") for n in ("cinn", "ciunet")]


def _fbp_inns(rows: _Rows, setting: str) -> list[_Contrast]:
    out = [_beats(prediction_name("fbp", n), "fbp", "ssim") for n in _INNS]
    out += [_beats(prediction_name("fbp", n), "fbp", "psnr") for n in ("cinn", "cinn-res")]
    return out + [_beats("fbp", prediction_name("fbp", n), "psnr") for n in ("ciunet", "ciunet-res")]


def _ciunet_res_best_inn(rows: _Rows, setting: str) -> list[_Contrast]:
    candidates = [f"{t}+ciunet-res" for t in _inputs(rows, setting, "ciunet-res")]
    others = sorted(prediction_name(t, n) for n in _INNS if n != "ciunet-res" for t in _inputs(rows, setting, n))
    present = [c for c in candidates if c in rows.names]
    if not present:  # nothing to choose the best from: name the rows needed
        return [_beats(c, o, m) for c in candidates for o in others for m in _METRICS]
    out = []
    for m in _METRICS:
        best = max(present, key=lambda name: rows.mean(name, m))
        out += [_beats(best, o, m) for o in others + [c for c in candidates if c != best]]
    return out


def _family(name: str) -> str:
    return "resesop" if name.startswith("resesop") else name


def _trained_on_resesop_loses_most(model: str) -> Callable[[_Rows, str], list]:
    """Drop of a network applied to other methods' reconstructions than it was trained on.

    ``drop(t) = (t+model) - mean over i of (i+model@t)``, i over the inputs of another method
    than ``t`` (the RESESOP eta variants count as RESESOP) among FBP, Dremel, RESESOP and the
    inputs the network was run on; the claim: drop(resesop) exceeds drop(fbp) and drop(dremel).
    """

    def drop(inputs: list[str], train: str) -> list[tuple[str, float]]:
        tests = [i for i in inputs if _family(i) != _family(train)]
        return [(prediction_name(train, model), 1.0)] + [
            (prediction_name(i, model, train), -1.0 / len(tests)) for i in tests
        ]

    def build(rows: _Rows, setting: str) -> list[_Contrast]:
        inputs = _inputs(rows, setting, model)  # every input the network ran on: its mixing rows must exist
        inputs = sorted(set(inputs) | {"fbp", "dremel", "resesop"}, key=INPUTS.index)
        out = []
        for other in ("fbp", "dremel"):
            terms = tuple(drop(inputs, "resesop")) + tuple((n, -c) for n, c in drop(inputs, other))
            label = f"{model} trained on resesop loses more on other methods than trained on {other}"
            out += [_Contrast(label, m, terms) for m in _METRICS]
        return out

    return build


@dataclass(frozen=True)
class _Claim:
    id: str
    settings: tuple[str, ...]
    text: str
    source: str
    build: Callable[[_Rows, str], list[_Contrast]]


_PERTURBED = ("parallel", "fan")
_SEC = "Sec. 'Perturbed phantom case', quantitative results"
_UNP = "Sec. 'Non-perturbed phantom case'"
_CLAIMS = (
    _Claim(
        "methods_beat_fbp",
        _PERTURBED,
        "Dremel and RESESOP beat FBP in PSNR and SSIM.",
        f"{_SEC}: 'Dremel and RESESOP perform superior to FBP in terms of PSNR as well as in SSIM'",
        _methods_beat_fbp,
    ),
    _Claim(
        "unet_largest_gain",
        SETTINGS,
        "On every input the UNet beats every iNN (unperturbed: in PSNR).",
        f"{_SEC}: 'the UNet approach delivers the largest improvement when compared to all other conditional iNN "
        f"approaches'; {_UNP}: 'the UNet provides the largest improvement in terms of PSNR'",
        _unet_largest_gain,
    ),
    _Claim(
        "resesop_unet_best",
        _PERTURBED,
        "RESESOP + UNet is the best row in PSNR and SSIM.",
        f"{_SEC}: 'the UNet post-processing and in particular when combined with RESESOP provides the best "
        "performance'",
        _resesop_unet_best,
    ),
    _Claim(
        "unet_gain_largest_on_resesop",
        _PERTURBED,
        "The UNet's PSNR gain over its input is larger on RESESOP than on FBP and Dremel.",
        f"{_SEC}: 'The largest improvement can be observed for RESESOP when combined with the UNet'",
        _unet_gain_largest_on_resesop,
    ),
    _Claim(
        "unet_improves_inputs",
        _PERTURBED,
        "The UNet raises PSNR and SSIM of every input.",
        f"{_SEC}: 'Large improvements can even be observed for over and underestimated eta. But also FBP and "
        "Dremel can highly benefit from the learned UNet post-processing'",
        _improve(("unet",)),
    ),
    _Claim(
        "unet_and_residual_improve_fbp",
        ("unperturbed",),
        "UNet, CiNNRes and CiUNetRes raise PSNR and SSIM of FBP.",
        f"{_UNP}: 'The post-processing via UNet and the residual iNNs (CiNNRes, CiUNetRes) result in the largest "
        "performance improvements in terms of PSNR as well as in SSIM'",
        _improve(("unet", "cinn-res", "ciunet-res"), ("fbp",)),
    ),
    _Claim(
        "residual_beats_nonresidual",
        SETTINGS,
        "Residual iNNs beat their non-residual versions (CiNNRes > CiNN, CiUNetRes > CiUNet) on every input.",
        "Sec. 'Discussion and Conclusion': 'training with respect to the residual is superior'",
        _residual_beats_nonresidual,
    ),
    _Claim(
        "residual_inns_improve_dremel_resesop",
        _PERTURBED,
        "CiNNRes and CiUNetRes raise PSNR and SSIM of Dremel and RESESOP.",
        f"{_SEC}: 'Dremel and RESESOP perform better when combined with the residual approaches CiNNRes and CiUNetRes'",
        _improve(("cinn-res", "ciunet-res"), ("dremel", "resesop")),
    ),
    _Claim(
        "nonresidual_inns_worsen_dremel_resesop",
        ("parallel",),
        "CiNN and CiUNet lower PSNR and SSIM of Dremel and RESESOP (except RESESOP + CiNN in PSNR).",
        f"{_SEC}: 'the performance becomes worse for the non-residual approaches CiNN and CiUNet (except for "
        "RESESOP and CiNN with respect to PSNR)'",
        _nonresidual_worsen,
    ),
    _Claim(
        "fbp_inns",
        ("parallel",),
        "On FBP every iNN raises SSIM; in PSNR CiNN and CiNNRes raise it, CiUNet and CiUNetRes lower it.",
        f"{_SEC}: 'For FBP ... all iNNs are able to improve performance in terms of SSIM but for PSNR this holds "
        "true for CiNN and CiNNRes only'",
        _fbp_inns,
    ),
    _Claim(
        "nonresidual_inns_lower_ssim",
        ("unperturbed",),
        "CiNN and CiUNet lower the SSIM of FBP.",
        f"{_UNP}: 'The post-processing via non-residual invertible networks results in ... the SSIM is decreased'",
        _nonresidual_lower_ssim,
    ),
    _Claim(
        "ciunet_res_best_inn",
        _PERTURBED,
        "The best iNN row, in PSNR and in SSIM, is a CiUNetRes row.",
        f"{_SEC}: 'among all conditional iNNs the CiUNetRes provides the largest improvements'",
        _ciunet_res_best_inn,
    ),
) + tuple(
    _Claim(
        f"resesop_trained_lose_most[{model}]",
        ("parallel",),
        f"A {model} trained on RESESOP loses more, applied to the other methods' reconstructions, than one "
        "trained on FBP or Dremel.",
        "Sec. 'Perturbed phantom case' (input mixing): 'architectures trained with RESESOP reconstructions "
        "perform worse with other reconstruction algorithms, particularly in terms of PSNR'",
        _trained_on_resesop_loses_most(model),
    )
    for model in MODELS
)

#: The conclusions checked: ``{id: (settings, text, source)}``.
CLAIMS: dict[str, tuple[tuple[str, ...], str, str]] = {c.id: (c.settings, c.text, c.source) for c in _CLAIMS}


def _verdict(diff: float, se: float | None, k: float) -> str:
    if se is None:
        return "undecided"
    if diff > k * se:
        return "holds"
    if diff < -k * se:
        return "does not hold"
    return "undecided"


def _overall(verdicts: list[str]) -> str:
    if not verdicts:
        return "not applicable"
    if "does not hold" in verdicts:
        return "does not hold"
    return "holds" if all(v == "holds" for v in verdicts) else "undecided"


def _run(rows: _Rows, setting: str, k: float) -> list[dict[str, Any]]:
    if setting not in SETTINGS:
        raise NanoctError(f"unknown setting {setting!r}; choose one of: {', '.join(SETTINGS)}")
    out = []
    for claim in _CLAIMS:
        if setting not in claim.settings:
            continue
        comparisons, missing = [], set()
        for contrast in claim.build(rows, setting):
            absent = [name for name, _ in contrast.terms if name not in rows.names]
            if absent:
                missing.update(absent)
                continue
            result = rows.contrast(contrast)
            result["verdict"] = _verdict(result["diff"], result["se"], k)
            comparisons.append(result)
        out.append(
            {
                "id": f"{setting}/{claim.id}",
                "claim": claim.id,
                "setting": setting,
                "text": claim.text,
                "source": claim.source,
                "verdict": _overall([c["verdict"] for c in comparisons]),
                "counts": {v: sum(c["verdict"] == v for c in comparisons) for v in VERDICTS[:3]},
                "comparisons": comparisons,
                "missing": sorted(missing),
            }
        )
    return out


def _paper_rows(setting: str) -> _Rows:
    entries = list(paper_rows(setting))
    if setting == "parallel":
        entries += [e for m in MODELS for e in paper_mixing(m) if e.input != e.train_input]
    return _Rows({e.name: {"psnr": [e.value.psnr_mean], "ssim": [e.value.ssim_mean]} for e in entries}, exact=True)


def paper_conclusions(setting: str) -> list[dict[str, Any]]:
    """The checks of :func:`check_conclusions` on the paper's own published means (``se = 0``).

    Parameters
    ----------
    setting : {"parallel", "fan", "unperturbed"}

    Returns
    -------
    list of dict
        As :func:`check_conclusions` (without ``paper_verdict``); ``n`` is 1 and ``se`` 0.
    """
    return _run(_paper_rows(setting), setting, k=0.0)


def check_conclusions(
    results: Mapping[str, Mapping[str, Any]], setting: str, *, k: float = 2.0, with_paper: bool = True
) -> list[dict[str, Any]]:
    """Check the paper's conclusions for one setting on our per-image results.

    Parameters
    ----------
    results : mapping
        ``{name: {"psnr": values, "ssim": values}}``; values per test image, shape (n,), or
        per training seed and test image, shape (S, n); the same images in the same order in
        every row (see the module docstring).
    setting : {"parallel", "fan", "unperturbed"}
        Which of the paper's tables the results correspond to; mixing rows belong to ``parallel``.
    k : float
        A comparison holds when its paired mean difference exceeds ``k`` standard errors and
        does not hold below ``-k`` standard errors (default 2, about a 95 % two-sided level per
        comparison, not corrected for the number of comparisons).
    with_paper : bool
        Add ``paper_verdict``: the same conclusion on the paper's published means.

    Returns
    -------
    list of dict
        One per conclusion that applies to the setting, JSON-serialisable: ``id``, ``claim``,
        ``setting``, ``text``, ``source`` (where the paper says it), ``verdict`` (one of
        :data:`VERDICTS`), ``counts`` of comparison verdicts, ``comparisons`` (``label``,
        ``metric``, ``diff``, ``se``, ``n``, ``seeds``, ``verdict``), ``missing`` (rows the
        check needed but ``results`` lacks) and, with ``with_paper``, ``paper_verdict``.

    Raises
    ------
    NanoctError
        If the setting is unknown, ``k`` is negative, or the values are malformed (missing
        metric, non-finite values, rows with different numbers of images).
    """
    if not k >= 0:
        raise NanoctError(f"k = {k} must be >= 0 (the number of standard errors a difference must exceed)")
    checks = _run(_Rows(results), setting, float(k))
    if with_paper:
        paper = {c["id"]: c["verdict"] for c in paper_conclusions(setting)}
        for c in checks:
            c["paper_verdict"] = paper[c["id"]]
    return checks


def _deciding(check: dict[str, Any]) -> str:
    """The comparison that decides the verdict: the weakest that holds, else the worst."""
    comps = check["comparisons"]
    if not comps:
        return "missing: " + ", ".join(check["missing"]) if check["missing"] else ""
    pool = [c for c in comps if c["verdict"] == check["verdict"]] or comps

    def z(c: dict[str, Any]) -> float:
        if c["se"] is None:
            return 0.0
        return c["diff"] / c["se"] if c["se"] > 0 else math.copysign(math.inf, c["diff"])

    c = min(pool, key=z) if check["verdict"] in ("holds", "does not hold") else min(pool, key=lambda c: abs(z(c)))
    unit = " dB" if c["metric"] == "psnr" else ""
    digits = 2 if c["metric"] == "psnr" else 3
    se = "?" if c["se"] is None else f"{c['se']:.{digits}f}"
    return f"{c['label']} ({c['metric'].upper()}): {c['diff']:+.{digits}f} ± {se}{unit}, n = {c['n']}" + (
        f", {c['seeds']} seeds" if c["seeds"] > 1 else ""
    )


def format_conclusions(checks: list[dict[str, Any]], k: float | None = None) -> str:
    """Markdown table of conclusion checks: claim, our verdict, the paper's, the deciding numbers.

    The deciding numbers are one comparison: for a verdict that holds the weakest comparison,
    for one that does not hold the clearest failure, otherwise the one nearest zero; given as
    paired mean difference ± standard error.
    """
    lines = ["| setting | conclusion | ours | paper's table | deciding comparison (mean ± s.e.) |"]
    lines.append("|---|---|---|---|---|")
    for c in checks:
        counts = ", ".join(f"{n} {v}" for v, n in c["counts"].items() if n)
        ours = f"**{c['verdict']}**" + (f" ({counts})" if counts else "")
        lines.append(f"| {c['setting']} | {c['text']} | {ours} | {c.get('paper_verdict', '–')} | {_deciding(c)} |")
    if k is not None:
        lines += ["", f"A comparison holds when its paired mean difference exceeds {k:g} standard errors."]
    return "\n".join(lines) + "\n"
