"""The paper's published numbers, typed in once, keyed with nanoct's names.

Every row of the paper's three result tables and of its five input-mixing tables (PSNR and
SSIM, mean ± std over the test split) is here as data, each with the table it comes from.
Keys use nanoct's names:

* settings: ``parallel`` (perturbed parallel beam), ``fan`` (perturbed fan beam),
  ``unperturbed`` (unperturbed parallel beam);
* inputs (first reconstructions): ``fbp``, ``dremel``, ``resesop``, ``resesop_eta0.8``,
  ``resesop_eta1.2``; in the ``unperturbed`` setting ``resesop`` is the paper's "RESESOP
  (eta = 0)", the name nanoct's study gives that reconstruction;
* models: ``unet``, ``cinn``, ``cinn-res``, ``ciunet``, ``ciunet-res``;
* input mixing (``parallel`` only): a model trained on ``train_input`` and applied to
  ``input``; nanoct stores it as ``<input>+<model>@<train_input>``.

The paper's tables do not have every combination: the perturbed tables have no raw
``resesop_eta0.8`` / ``resesop_eta1.2`` rows, the fan table has no FBP rows, and the
unperturbed table has networks on FBP only. :func:`paper_rows` lists what exists.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

from ..core.errors import NanoctError
from ..core.names import SETTINGS, parse_name, prediction_name

__all__ = [
    "INPUTS",
    "MODELS",
    "TABLES",
    "PAPER_GAUGE",
    "PaperEntry",
    "PaperTable",
    "PaperValue",
    "comparison_rows",
    "format_comparison",
    "format_mixing_comparison",
    "paper_entry",
    "paper_lookup",
    "paper_mixing",
    "paper_rows",
    "paper_value",
]

#: First reconstructions, in the paper's order.
INPUTS = ("fbp", "dremel", "resesop", "resesop_eta1.2", "resesop_eta0.8")
#: Post-processing networks, in the paper's order.
MODELS = ("unet", "cinn", "cinn-res", "ciunet", "ciunet-res")


@dataclass(frozen=True)
class PaperTable:
    """Where a number comes from in the paper's LaTeX source.

    Attributes
    ----------
    key : str
        nanoct's key: a setting (``parallel``, ``fan``, ``unperturbed``) or ``mixing-<model>``.
    label : str or None
        The table's ``\\label`` in the LaTeX source; the mixing tables of the appendix have none.
    caption : str
        The start of the table's caption (enough to find it).
    files : tuple of str
        The included ``tables/*.tex`` files holding the numbers.
    """

    key: str
    label: str | None
    caption: str
    files: tuple[str, ...]

    def cite(self) -> str:
        """Short reference for a report: the label, else the caption's start and file."""
        return self.label or f"{self.caption} ({', '.join(self.files)})"


class PaperValue(NamedTuple):
    """PSNR [dB] and SSIM, mean and std over the paper's test split."""

    psnr_mean: float
    psnr_std: float
    ssim_mean: float
    ssim_std: float


@dataclass(frozen=True)
class PaperEntry:
    """One row (or mixing-table cell) of the paper with its keys and source.

    Attributes
    ----------
    setting, input, model, train_input
        nanoct's keys; ``model`` is None for a first reconstruction, ``train_input`` is None
        except in the input-mixing tables.
    value : PaperValue
    table : PaperTable
    """

    setting: str
    input: str
    model: str | None
    train_input: str | None
    value: PaperValue
    table: PaperTable

    @property
    def name(self) -> str:
        """nanoct's reconstruction name: ``fbp``, ``fbp+unet``, ``fbp+unet@dremel``."""
        return self.input if self.model is None else prediction_name(self.input, self.model, self.train_input)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (keys, the four numbers and the table's reference)."""
        return {
            "setting": self.setting,
            "name": self.name,
            "input": self.input,
            "model": self.model,
            "train_input": self.train_input,
            **self.value._asdict(),
            "table": self.table.cite(),
        }


_CAPTION_MIX = "Quantitative evaluation (PSNR (top) and SSIM (bottom)) for mixed training and testing inputs to the"
_MIX_FILES = {"unet": "unet", "cinn": "cinn", "cinn-res": "cinnres", "ciunet": "iunet", "ciunet-res": "iunetres"}
_MIX_NAMES = {"unet": "UNet", "cinn": "CiNN", "cinn-res": "CiNNRes", "ciunet": "CiUnet", "ciunet-res": "CiUnetRes"}

#: The paper's tables by nanoct key.
TABLES: dict[str, PaperTable] = {
    "parallel": PaperTable(
        "parallel",
        "tab:parallel_perturbed_quantitative",
        "Quantitative evaluation on the parallel beam test data for measurements from perturbed phantoms.",
        ("tables/perturbed_parallel_beam_test_data.tex",),
    ),
    "fan": PaperTable(
        "fan",
        "tab:fan_perturbed_quantitative",
        "Quantitative evaluation on the fan beam test data for measurements from perturbed phantoms.",
        ("tables/perturbed_fan_beam_test_data.tex",),
    ),
    "unperturbed": PaperTable(
        "unperturbed",
        "tab:parallel_unperturbed_quantitative",
        "Quantitative evaluation on the parallel beam test data for measurements from unperturbed phantoms.",
        ("tables/unperturbed_parallel_beam_test_data.tex",),
    ),
} | {
    f"mixing-{m}": PaperTable(
        f"mixing-{m}",
        "tab:parallel_perturbed_quantitative_mixing" if m == "unet" else None,
        f"{_CAPTION_MIX} post-processing {_MIX_NAMES[m]}",
        tuple(
            f"tables/input_mixing_{metric}_perturbed_parallel_beam_test_data_{_MIX_FILES[m]}.tex"
            for metric in ("psnr", "ssim")
        ),
    )
    for m in MODELS
}

# The three result tables: {setting: {model or None: [(input, psnr mean, psnr std, ssim mean, ssim std)]}},
# rows in the paper's order (note: RESESOP 1.2 eta before 0.8 eta).
_RESULTS: dict[str, dict[str | None, list[tuple[str, float, float, float, float]]]] = {
    "parallel": {
        None: [
            ("fbp", 27.94, 2.81, 0.510, 0.103),
            ("dremel", 30.98, 3.01, 0.829, 0.076),
            ("resesop", 30.65, 2.74, 0.868, 0.032),
        ],
        "unet": [
            ("fbp", 33.04, 3.87, 0.984, 0.008),
            ("dremel", 31.67, 3.79, 0.980, 0.010),
            ("resesop", 38.17, 3.36, 0.993, 0.004),
            ("resesop_eta1.2", 37.75, 3.40, 0.992, 0.004),
            ("resesop_eta0.8", 37.93, 3.44, 0.993, 0.004),
        ],
        "cinn": [
            ("fbp", 30.60, 2.31, 0.644, 0.009),
            ("dremel", 30.69, 2.69, 0.647, 0.009),
            ("resesop", 32.58, 2.16, 0.608, 0.010),
            ("resesop_eta1.2", 31.51, 2.25, 0.586, 0.011),
            ("resesop_eta0.8", 31.89, 2.16, 0.562, 0.012),
        ],
        "cinn-res": [
            ("fbp", 28.82, 2.39, 0.862, 0.032),
            ("dremel", 30.40, 2.74, 0.919, 0.018),
            ("resesop", 33.30, 2.60, 0.964, 0.011),
            ("resesop_eta1.2", 33.11, 2.65, 0.964, 0.012),
            ("resesop_eta0.8", 32.93, 2.59, 0.940, 0.017),
        ],
        "ciunet": [
            ("fbp", 22.26, 1.42, 0.761, 0.015),
            ("dremel", 21.98, 1.57, 0.686, 0.017),
            ("resesop", 22.36, 1.64, 0.737, 0.016),
            ("resesop_eta1.2", 25.47, 1.25, 0.755, 0.014),
            ("resesop_eta0.8", 27.52, 1.84, 0.768, 0.009),
        ],
        "ciunet-res": [
            ("fbp", 25.81, 1.37, 0.931, 0.016),
            ("dremel", 30.94, 2.80, 0.975, 0.009),
            ("resesop", 33.87, 2.86, 0.984, 0.006),
            ("resesop_eta1.2", 30.13, 2.49, 0.974, 0.011),
            ("resesop_eta0.8", 33.50, 2.99, 0.983, 0.007),
        ],
    },
    "fan": {
        None: [("dremel", 30.41, 3.01, 0.778, 0.117), ("resesop", 30.13, 2.87, 0.859, 0.039)],
        "unet": [("dremel", 30.37, 3.77, 0.975, 0.012), ("resesop", 37.33, 3.61, 0.992, 0.005)],
        "cinn": [("dremel", 29.83, 2.52, 0.511, 0.015), ("resesop", 31.19, 2.19, 0.506, 0.015)],
        "cinn-res": [("dremel", 29.55, 2.69, 0.896, 0.027), ("resesop", 32.34, 2.66, 0.939, 0.019)],
        "ciunet": [("dremel", 26.21, 1.77, 0.440, 0.015), ("resesop", 25.62, 1.23, 0.775, 0.017)],
        "ciunet-res": [("dremel", 31.01, 3.26, 0.974, 0.010), ("resesop", 32.03, 2.77, 0.978, 0.010)],
    },
    "unperturbed": {
        None: [
            ("fbp", 40.10, 2.60, 0.967, 0.022),
            ("dremel", 35.29, 2.81, 0.945, 0.028),
            ("resesop", 43.96, 2.34, 0.986, 0.006),  # RESESOP (eta = 0)
        ],
        "unet": [("fbp", 71.76, 3.18, 0.999, 9.027e-6)],
        "cinn": [("fbp", 43.35, 1.47, 0.869, 0.004)],
        "cinn-res": [("fbp", 55.07, 2.06, 0.997, 0.003)],
        "ciunet": [("fbp", 46.21, 0.25, 0.852, 0.005)],
        "ciunet-res": [("fbp", 63.53, 1.27, 0.999, 1.784e-5)],
    },
}

# Input mixing (perturbed parallel beam), as in the paper: rows = training input, columns =
# test input in the order of _MIX_COLUMNS; per model a PSNR block then an SSIM block of (mean, std).
_MIX_COLUMNS = ("fbp", "dremel", "resesop", "resesop_eta1.2", "resesop_eta0.8")
_Pair = tuple[float, float]
_MIXING: dict[str, dict[str, list[tuple[str, _Pair, _Pair, _Pair, _Pair, _Pair]]]] = {
    "unet": {
        "psnr": [
            ("fbp", (33.04, 3.87), (31.16, 3.64), (32.06, 2.68), (31.37, 2.79), (32.68, 2.68)),
            ("dremel", (29.53, 3.00), (31.67, 3.79), (31.12, 2.76), (30.63, 2.80), (31.59, 2.75)),
            ("resesop", (26.41, 2.21), (29.90, 2.99), (38.17, 3.36), (37.45, 3.55), (36.43, 3.71)),
            ("resesop_eta1.2", (28.00, 2.97), (30.17, 3.08), (37.74, 3.39), (37.75, 3.40), (36.03, 3.73)),
            ("resesop_eta0.8", (27.64, 3.07), (30.44, 3.13), (37.03, 3.75), (35.91, 3.79), (37.93, 3.44)),
        ],
        "ssim": [
            ("fbp", (0.984, 0.008), (0.979, 0.010), (0.978, 0.008), (0.975, 0.009), (0.981, 0.006)),
            ("dremel", (0.969, 0.012), (0.980, 0.010), (0.971, 0.012), (0.968, 0.013), (0.973, 0.011)),
            ("resesop", (0.958, 0.011), (0.975, 0.009), (0.993, 0.004), (0.992, 0.004), (0.990, 0.005)),
            ("resesop_eta1.2", (0.932, 0.038), (0.976, 0.009), (0.992, 0.004), (0.992, 0.004), (0.990, 0.005)),
            ("resesop_eta0.8", (0.958, 0.019), (0.978, 0.009), (0.991, 0.005), (0.989, 0.006), (0.993, 0.004)),
        ],
    },
    "cinn": {
        "psnr": [
            ("fbp", (30.60, 2.31), (30.54, 2.39), (31.20, 2.10), (30.86, 2.22), (31.47, 2.02)),
            ("dremel", (29.75, 2.74), (30.69, 2.69), (30.66, 2.34), (30.24, 2.43), (31.02, 2.29)),
            ("resesop", (29.02, 2.69), (30.07, 2.53), (32.58, 2.16), (32.35, 2.26), (32.57, 2.16)),
            ("resesop_eta1.2", (28.94, 2.72), (29.75, 2.52), (31.67, 2.21), (31.51, 2.25), (31.72, 2.21)),
            ("resesop_eta0.8", (29.28, 2.81), (30.14, 2.63), (31.64, 2.19), (31.33, 2.28), (31.89, 2.16)),
        ],
        "ssim": [
            ("fbp", (0.644, 0.009), (0.644, 0.010), (0.643, 0.010), (0.641, 0.010), (0.645, 0.010)),
            ("dremel", (0.637, 0.011), (0.647, 0.009), (0.643, 0.008), (0.641, 0.008), (0.645, 0.008)),
            ("resesop", (0.596, 0.011), (0.601, 0.011), (0.608, 0.010), (0.607, 0.010), (0.608, 0.011)),
            ("resesop_eta1.2", (0.576, 0.011), (0.581, 0.012), (0.587, 0.011), (0.586, 0.011), (0.587, 0.011)),
            ("resesop_eta0.8", (0.550, 0.013), (0.556, 0.013), (0.561, 0.012), (0.560, 0.012), (0.562, 0.012)),
        ],
    },
    "cinn-res": {
        "psnr": [
            ("fbp", (28.82, 2.39), (28.76, 2.37), (28.77, 2.11), (28.52, 2.19), (29.01, 2.07)),
            ("dremel", (29.09, 2.89), (30.40, 2.74), (29.92, 2.45), (29.51, 2.53), (30.32, 2.39)),
            ("resesop", (30.05, 2.96), (31.07, 2.95), (33.30, 2.60), (32.98, 2.68), (33.37, 2.59)),
            ("resesop_eta1.2", (29.26, 2.93), (30.68, 2.94), (33.30, 2.61), (33.11, 2.65), (33.29, 2.62)),
            ("resesop_eta0.8", (28.22, 2.91), (30.21, 2.89), (32.57, 2.64), (32.17, 2.71), (32.93, 2.59)),
        ],
        "ssim": [
            ("fbp", (0.862, 0.032), (0.878, 0.025), (0.880, 0.023), (0.880, 0.024), (0.872, 0.029)),
            ("dremel", (0.793, 0.082), (0.919, 0.018), (0.893, 0.027), (0.886, 0.030), (0.887, 0.034)),
            ("resesop", (0.874, 0.051), (0.955, 0.015), (0.964, 0.011), (0.962, 0.012), (0.961, 0.013)),
            ("resesop_eta1.2", (0.795, 0.067), (0.933, 0.027), (0.965, 0.011), (0.964, 0.012), (0.961, 0.014)),
            ("resesop_eta0.8", (0.584, 0.097), (0.822, 0.070), (0.935, 0.017), (0.929, 0.020), (0.940, 0.017)),
        ],
    },
    "ciunet": {
        "psnr": [
            ("fbp", (22.26, 1.42), (22.38, 1.42), (21.82, 1.49), (21.68, 1.52), (21.92, 1.47)),
            ("dremel", (21.80, 1.60), (21.98, 1.57), (21.50, 1.66), (21.38, 1.69), (21.57, 1.64)),
            ("resesop", (22.55, 1.63), (22.78, 1.66), (22.36, 1.64), (22.21, 1.66), (22.46, 1.62)),
            ("resesop_eta1.2", (25.95, 1.43), (26.39, 1.43), (25.74, 1.22), (25.47, 1.25), (25.97, 1.20)),
            ("resesop_eta0.8", (27.50, 2.22), (27.78, 2.20), (27.28, 1.83), (27.03, 1.84), (27.52, 1.84)),
        ],
        "ssim": [
            ("fbp", (0.761, 0.015), (0.762, 0.015), (0.757, 0.014), (0.756, 0.014), (0.758, 0.014)),
            ("dremel", (0.685, 0.017), (0.686, 0.017), (0.682, 0.016), (0.681, 0.017), (0.683, 0.016)),
            ("resesop", (0.736, 0.017), (0.740, 0.017), (0.737, 0.016), (0.736, 0.017), (0.738, 0.016)),
            ("resesop_eta1.2", (0.757, 0.012), (0.760, 0.013), (0.756, 0.014), (0.755, 0.014), (0.758, 0.014)),
            ("resesop_eta0.8", (0.766, 0.009), (0.768, 0.009), (0.766, 0.009), (0.765, 0.008), (0.768, 0.009)),
        ],
    },
    "ciunet-res": {
        "psnr": [
            ("fbp", (25.81, 1.37), (26.15, 1.32), (25.57, 1.28), (25.34, 1.34), (25.71, 1.23)),
            ("dremel", (30.00, 2.89), (30.94, 2.80), (30.95, 1.91), (30.64, 1.98), (31.14, 1.91)),
            ("resesop", (29.08, 3.09), (30.76, 3.18), (33.87, 2.86), (33.45, 2.90), (34.13, 2.88)),
            ("resesop_eta1.2", (28.44, 2.77), (29.78, 2.84), (30.56, 2.51), (30.13, 2.49), (31.08, 2.53)),
            ("resesop_eta0.8", (29.16, 3.14), (30.72, 3.27), (32.95, 2.95), (32.52, 2.96), (33.50, 2.99)),
        ],
        "ssim": [
            ("fbp", (0.931, 0.016), (0.936, 0.016), (0.933, 0.016), (0.931, 0.017), (0.935, 0.016)),
            ("dremel", (0.965, 0.013), (0.975, 0.009), (0.972, 0.008), (0.971, 0.010), (0.971, 0.009)),
            ("resesop", (0.891, 0.038), (0.965, 0.015), (0.984, 0.006), (0.982, 0.007), (0.984, 0.006)),
            ("resesop_eta1.2", (0.884, 0.041), (0.959, 0.016), (0.976, 0.010), (0.974, 0.011), (0.978, 0.009)),
            ("resesop_eta0.8", (0.937, 0.029), (0.975, 0.010), (0.981, 0.007), (0.980, 0.008), (0.983, 0.007)),
        ],
    },
}


def _build() -> tuple[dict[str, list[PaperEntry]], dict[str, list[PaperEntry]]]:
    rows = {
        setting: [
            PaperEntry(setting, inp, model, None, PaperValue(*nums), TABLES[setting])
            for model, block in blocks.items()
            for inp, *nums in block
        ]
        for setting, blocks in _RESULTS.items()
    }
    mixing = {}
    for model, tables in _MIXING.items():
        entries = []
        for (train, *psnr), (train_s, *ssim) in zip(tables["psnr"], tables["ssim"]):
            assert train == train_s, (model, train, train_s)
            for test, p, s in zip(_MIX_COLUMNS, psnr, ssim):
                value = PaperValue(p[0], p[1], s[0], s[1])
                entries.append(PaperEntry("parallel", test, model, train, value, TABLES[f"mixing-{model}"]))
        mixing[model] = entries
    return rows, mixing


_ROWS, _MIX = _build()


def _check_key(kind: str, value: str | None, allowed: tuple[str, ...]) -> None:
    if value is not None and value not in allowed:
        raise NanoctError(f"unknown {kind} {value!r}; the paper's {kind}s are: {', '.join(allowed)}")


def paper_rows(setting: str) -> list[PaperEntry]:
    """Every row of one of the paper's three result tables, in the paper's order.

    Parameters
    ----------
    setting : {"parallel", "fan", "unperturbed"}

    Returns
    -------
    list of PaperEntry
        First reconstructions (``model`` None) first, then one block per network.

    Raises
    ------
    NanoctError
        If ``setting`` is unknown.
    """
    if setting not in SETTINGS:
        raise NanoctError(f"unknown setting {setting!r}; the paper's settings are: {', '.join(SETTINGS)}")
    return list(_ROWS[setting])


def paper_mixing(model: str) -> list[PaperEntry]:
    """The 25 cells of one network's input-mixing table (perturbed parallel beam).

    Parameters
    ----------
    model : {"unet", "cinn", "cinn-res", "ciunet", "ciunet-res"}

    Returns
    -------
    list of PaperEntry
        Row by row (training input), each row's columns (test input) in the paper's order;
        the diagonal (``input == train_input``) repeats the main table's row.

    Raises
    ------
    NanoctError
        If ``model`` is unknown.
    """
    _check_key("model", model, MODELS)
    return list(_MIX[model])


def paper_entry(
    setting: str, input: str, model: str | None = None, train_input: str | None = None
) -> PaperEntry | None:
    """The paper's row for a setting, input and network, or None where the paper has none.

    Parameters
    ----------
    setting : {"parallel", "fan", "unperturbed"}
    input : str
        First reconstruction the row starts from (for mixing: the test input).
    model : str, optional
        Post-processing network; None for the first reconstruction itself.
    train_input : str, optional
        Input the network was trained on, from the mixing tables (``parallel`` only); None
        (or equal to ``input``) gives the main table's row.

    Raises
    ------
    NanoctError
        If a key is not one of the paper's names, or ``train_input`` comes without ``model``.
    """
    _check_key("input", input, INPUTS)
    _check_key("model", model, MODELS)
    _check_key("input", train_input, INPUTS)
    rows = paper_rows(setting)
    if train_input is not None and train_input != input:
        if model is None:
            raise NanoctError(f"train_input={train_input!r} needs a model (input mixing applies to networks)")
        rows = _MIX[model] if setting == "parallel" else []
        return next((e for e in rows if e.input == input and e.train_input == train_input), None)
    return next((e for e in rows if e.input == input and e.model == model), None)


def paper_value(
    setting: str, input: str, model: str | None = None, train_input: str | None = None
) -> PaperValue | None:
    """``(psnr_mean, psnr_std, ssim_mean, ssim_std)`` of a paper row, or None where it has none.

    Arguments as :func:`paper_entry`.
    """
    entry = paper_entry(setting, input, model, train_input)
    return None if entry is None else entry.value


def paper_lookup(setting: str, name: str) -> PaperEntry | None:
    """The paper's row for a nanoct reconstruction name (``resesop+unet@fbp``), or None.

    Names whose input or model the paper does not use (``kaczmarz``, ``resesop_eta0.9``)
    give None rather than an error, so a report can list its own extra rows.
    """
    test_input, model, train_input = _split(name)
    if test_input not in INPUTS or (model and model not in MODELS) or (train_input and train_input not in INPUTS):
        return None
    return paper_entry(setting, test_input, model, train_input)


def _split(name: str) -> tuple[str, str | None, str | None]:
    """(input, model or None, training input or None when it is the input itself)."""
    test_input, model, train_input = parse_name(name)
    return test_input, model, None if model is None or train_input == test_input else train_input


def _order(name: str) -> tuple[int, int, int, str]:
    """Sort key: first reconstructions, then one block per network, then mixing; paper order inside."""
    test_input, model, train_input = _split(name)

    def rank(value: str | None, names: tuple[str, ...]) -> int:
        return -1 if value is None else names.index(value) if value in names else len(names)

    return rank(model, MODELS), rank(train_input, INPUTS), rank(test_input, INPUTS), name


def _gain(
    values: dict[str, Any] | PaperValue | None, inputs: dict[str, Any] | PaperValue | None, key: str
) -> float | None:
    if values is None or inputs is None:
        return None
    get = (lambda v: v[key]) if isinstance(values, dict) else (lambda v: getattr(v, key))
    return float(get(values) - get(inputs))


def comparison_rows(results: dict[str, dict[str, Any]], setting: str, mixing: bool = False) -> list[dict[str, Any]]:
    """Our rows next to the paper's, with each post-processing row's gain over its input.

    Parameters
    ----------
    results : dict
        ``{name: {"psnr_mean", "psnr_std", "ssim_mean", "ssim_std", "n"}}`` as
        :func:`nanoct.evaluation.evaluate.evaluate_store` returns it, names as in :mod:`nanoct.evaluation.evaluate`.
    setting : {"parallel", "fan", "unperturbed"}
    mixing : bool
        Also list input-mixing rows (``<input>+<model>@<train_input>``).

    Returns
    -------
    list of dict
        One per row that we or the paper have, ordered like the paper (first reconstructions,
        then one block per network, then mixing): ``name``, ``ours`` (our scores or None),
        ``paper`` (:meth:`PaperEntry.to_dict` or None), and ``gain_ours`` / ``gain_paper``:
        ``{"psnr": dB, "ssim": ...}`` of the row over its (test) input, None for a first
        reconstruction or where the input row is missing. JSON-serialisable.
    """
    names = {n for n in results if mixing or "@" not in n}
    names |= {e.name for e in paper_rows(setting)}
    if mixing and setting == "parallel":
        names |= {e.name for m in MODELS for e in _MIX[m] if e.input != e.train_input}
    rows = []
    for name in sorted(names, key=_order):
        test_input, model, _ = _split(name)
        entry = paper_lookup(setting, name)
        ours = results.get(name)
        gain_ours = gain_paper = None
        if model is not None:
            ours_base = results.get(test_input)
            gain_ours = {m: _gain(ours, ours_base, f"{m}_mean") for m in ("psnr", "ssim")}
            if entry is not None:
                base = paper_value(setting, test_input)
                gain_paper = {m: _gain(entry.value, base, f"{m}_mean") for m in ("psnr", "ssim")}
        paper = None if entry is None else entry.to_dict()
        rows.append({"name": name, "ours": ours, "paper": paper, "gain_ours": gain_ours, "gain_paper": gain_paper})
    return rows


def _fmt(scores: dict[str, Any] | None, metric: str) -> str:
    if scores is None:
        return "–"
    digits = 2 if metric == "psnr" else 3
    return f"{scores[f'{metric}_mean']:.{digits}f} ± {scores[f'{metric}_std']:.{digits}f}"


def _fmt_gain(gain: dict[str, float | None] | None, metric: str) -> str:
    value = None if gain is None else gain[metric]
    return "–" if value is None else f"{value:+.{2 if metric == 'psnr' else 3}f}"


#: The convention of the comparison with the paper (said under every comparison table).
PAPER_GAUGE = (
    "Ours: the images as reconstructed, the paper's convention (no registration; `nanoct evaluate` also lists "
    "the scores after the best sub-pixel translation)."
)


def format_comparison(results: dict[str, dict[str, Any]], setting: str, title: str = "", mixing: bool = False) -> str:
    """Markdown table of :func:`comparison_rows`: ours | paper | gain ours | gain paper, per metric.

    A dash marks a value that we or the paper do not have; the paper's table is cited below.
    """
    head = (
        "| reconstruction | PSNR ours | PSNR paper | gain ours | gain paper "
        "| SSIM ours | SSIM paper | gain ours | gain paper | n |"
    )
    lines = [f"### {title}", ""] if title else []
    lines += [head, "|---" * (head.count("|") - 1) + "|"]
    sources = []
    for row in comparison_rows(results, setting, mixing):
        cells = [row["name"]]
        for metric in ("psnr", "ssim"):
            cells += [_fmt(row["ours"], metric), _fmt(row["paper"], metric)]
            cells += [_fmt_gain(row["gain_ours"], metric), _fmt_gain(row["gain_paper"], metric)]
        cells.append(str(row["ours"]["n"]) if row["ours"] and "n" in row["ours"] else "–")
        lines.append("| " + " | ".join(cells) + " |")
        if row["paper"] and row["paper"]["table"] not in sources:
            sources.append(row["paper"]["table"])
    if sources:
        lines += ["", "Paper values from: " + "; ".join(sources) + "."]
    lines += ["", PAPER_GAUGE]
    return "\n".join(lines) + "\n"


def format_mixing_comparison(results: dict[str, dict[str, Any]], model: str) -> str:
    """Markdown input-mixing tables of one network, ours next to the paper's in each cell.

    Rows are the training input, columns the test input (the paper's layout), one table for
    PSNR and one for SSIM; a cell reads ``ours (paper)`` with means only, a dash for a value
    we or the paper do not have. ``results`` as in :func:`comparison_rows`: the diagonal is
    ``<input>+<model>``, the other cells ``<input>+<model>@<train_input>``.

    Raises
    ------
    NanoctError
        If ``model`` is unknown.
    """
    _check_key("model", model, MODELS)
    blocks = []
    for metric, label, digits in (("psnr", "PSNR [dB]", 2), ("ssim", "SSIM", 3)):
        lines = [f"### {model}: {label}, ours (paper); rows = trained on, columns = applied to", ""]
        lines += ["| trained on \\ applied to | " + " | ".join(_MIX_COLUMNS) + " |", "|---" * 6 + "|"]
        for train in _MIX_COLUMNS:
            cells = []
            for test in _MIX_COLUMNS:
                name = prediction_name(test, model, train)
                ours = results.get(name)
                paper = paper_value("parallel", test, model, train)
                ours_text = "–" if ours is None else f"{ours[f'{metric}_mean']:.{digits}f}"
                paper_text = "–" if paper is None else f"{getattr(paper, f'{metric}_mean'):.{digits}f}"
                cells.append(f"{ours_text} ({paper_text})")
            lines.append(f"| {train} | " + " | ".join(cells) + " |")
        blocks.append("\n".join(lines) + "\n")
    return "\n".join(blocks) + f"\nPaper values from: {TABLES[f'mixing-{model}'].cite()}.\n"
