"""The study's configuration: scales, settings and the jobs of each setting.

:class:`Study` is the scale of a reproduction (samples, epochs, learning rates, architectures,
sampling); :data:`STUDIES` holds the scales of ``nanoct reproduce --preset`` and
:data:`SCALE_STUDIES` those of ``--scale`` where they differ. :class:`Setting` is one of the
paper's settings at a scale (geometry, motion, the rows it has) and :func:`setting_jobs` lists
every job of a setting, which the runner (:mod:`nanoct.study.runner`) runs and the planner
(:mod:`nanoct.study.plan`) prices. Why the tiny scale is set as it is: ``docs/study.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from ..core.errors import NanoctError
from ..core.geometry import get_preset, preset_names
from ..core.names import setting_key
from ..learn.models import model_class, table_order
from ..recon.names import reconstruction_name
from ..recon.registry import method_spec

__all__ = [
    "CALIBRATION_SEED_OFFSET",
    "CONCLUSION_K",
    "DEFAULT_SEED",
    "SCALE_STUDIES",
    "STUDIES",
    "STUDY_PRESETS",
    "Jobs",
    "Setting",
    "Study",
    "StudyPreset",
    "calibration_seed",
    "check_models",
    "preset_models",
    "preset_names_all",
    "preset_setting",
    "preset_study",
    "scale_settings",
    "scale_study",
    "setting_jobs",
]

#: Seed of the study's data sets unless ``--seed`` says otherwise.
DEFAULT_SEED = 0
#: Standard errors a paired difference must exceed for a conclusion check to hold.
CONCLUSION_K = 2.0
#: The calibration set of a study with data-set seed ``s`` is simulated under seed ``s`` + this.
CALIBRATION_SEED_OFFSET = 1_000_000


def calibration_seed(seed: int) -> int:
    """Data-set seed of the calibration set of a study whose data set has ``seed``: another stream of
    samples (sample i depends only on (seed, i)), never one the study trains, validates or tests on."""
    return int(seed) + CALIBRATION_SEED_OFFSET


@dataclass(frozen=True)
class Study:
    """Scale of a reproduction.

    Attributes
    ----------
    n, split_fractions
        Number of samples and train/val/test proportions.
    epochs : dict
        Training epochs per model.
    lr : dict
        Learning rates that differ from the paper's (model registry) defaults.
    scheduler : dict
        Learning-rate schedules (``"none"``, ``"plateau"``, ``"cosine"``) that differ from the
        model registry's, per model (:func:`nanoct.learn.train.train`'s ``scheduler``).
    model_kwargs : dict
        Architecture arguments that differ from the paper's defaults, per model.
    n_samples : int
        Latent samples per image for the invertible networks (paper: 100).
    mixing : tuple of str
        Models also applied to every input they were not trained on (input-mixing tables).
    precision : {"fp32", "bf16", "auto"}
        Arithmetic of the training steps (:func:`nanoct.learn.train.train`); ``"auto"``: bfloat16
        where the device runs it natively, else float32 (:func:`nanoct.learn.train.resolve_precision`).
    antithetic : bool
        Draw the invertible networks' latent samples in antithetic pairs (z, -z) (the paper:
        independent draws; ``reconstruct``'s ``antithetic``).
    n_calibration : int
        Images of a calibration set apart from the data set (simulated alike under
        :func:`calibration_seed`, all in its validation split, reconstructed by the networks' inputs)
        on which the invertible networks' intervals are fitted (``predict --calibrate-on``); 0: on
        the data set's validation split, which also chose each network's checkpoint.
    """

    n: int
    split_fractions: tuple[float, float, float]
    epochs: dict[str, int] = field(default_factory=lambda: dict.fromkeys(table_order(), 500))
    lr: dict[str, float] = field(default_factory=dict)
    scheduler: dict[str, str] = field(default_factory=dict)
    model_kwargs: dict[str, dict[str, Any]] = field(default_factory=dict)
    n_samples: int = 100
    mixing: tuple[str, ...] = table_order()
    precision: str = "fp32"
    antithetic: bool = False
    n_calibration: int = 0

    @property
    def sampling(self) -> dict[str, Any]:
        """``reconstruct`` arguments of the invertible networks (:attr:`n_samples`, :attr:`antithetic`)."""
        return {"n_samples": self.n_samples} | ({"antithetic": True} if self.antithetic else {})


def _flow_kwargs(model: str, form: str, location_weight: float = 0.0) -> dict[str, Any]:
    """The tiny study's architecture arguments of an invertible network with conditional-scale
    ``form`` and, if positive, the location term's weight (docs/learn.md)."""
    kwargs: dict[str, Any] = {"blocks_per_scale": 2, "conditional_scale": form}
    if not model.startswith("cinn"):
        kwargs = {"blocks_per_scale": 1, "conditional_scale": form, "cond_channels": [16, 16, 32, 32, 64]}
    return kwargs | ({"location_weight": location_weight} if location_weight else {})


# The tiny study's choices (budget, learning rates, architectures, schedules) and the validation
# measurements behind them: docs/study.md.
STUDIES: dict[str, Study] = {
    "tiny": Study(
        n=200,
        split_fractions=(0.8, 0.1, 0.1),
        epochs={"unet": 40, "cinn": 24, "cinn-res": 32, "ciunet": 24, "ciunet-res": 32},
        lr={"cinn": 1e-3, "cinn-res": 1e-3, "ciunet": 1e-3, "ciunet-res": 1e-3},
        scheduler={"ciunet": "cosine"},
        model_kwargs={"unet": {"out_bias": -7.0, "skip_channels": 32}}
        | {
            m: _flow_kwargs(m, "location", 0.0 if m.endswith("-res") else 1000.0)
            for m in ("cinn", "cinn-res", "ciunet", "ciunet-res")
        },
        n_samples=32,
        mixing=("unet",),
        precision="auto",
        antithetic=True,
        n_calibration=100,
    ),
    "small": Study(n=2000, split_fractions=(0.9, 0.05, 0.05), epochs=dict.fromkeys(table_order(), 100)),
    "paper": Study(n=32095, split_fractions=(0.95, 0.04, 0.01)),
}


@dataclass(frozen=True)
class StudyPreset:
    """A one-setting study of ``reproduce --preset NAME`` whose NAME is not a geometry preset.

    Attributes
    ----------
    geometry : str
        The geometry preset it simulates (its data set is that preset's at :attr:`Study.n` and the
        seed, so its rows without post-processing equal that study's).
    study : Study
        Its scale.
    inputs : tuple of str
        Its first reconstructions (output names of :func:`_recons`), each an input of every network.
    models : tuple of str
        The networks it trains unless ``--models`` says otherwise.
    note : str
        A paragraph under the report's title that says what the preset is (and is not).
    """

    geometry: str
    study: Study
    inputs: tuple[str, ...]
    models: tuple[str, ...]
    note: str


#: ``nanoct reproduce --preset tiny-quick``: a first result in minutes on any 2-core CPU, float32
#: included (docs/study.md, "tiny-quick"). The tiny-parallel data set (same n, splits and seed:
#: the FBP, Dremel and RESESOP rows are the tiny study's), three inputs instead of five, two networks
#: (UNet and CiUNetRes, the tiny study's architectures and learning rates) at a fraction of the
#: tiny study's epochs, intervals fitted on the validation split (no calibration set).
STUDY_PRESETS: dict[str, StudyPreset] = {
    "tiny-quick": StudyPreset(
        geometry="tiny-parallel",
        study=replace(
            STUDIES["tiny"],
            epochs={"unet": 20, "cinn": 8, "cinn-res": 8, "ciunet": 8, "ciunet-res": 8},
            n_calibration=0,
        ),
        inputs=("fbp", "dremel", "resesop"),
        models=("unet", "ciunet-res"),
        note=(
            "**Quick first-run scale (`tiny-quick`)**, not the reproducible reference: the tiny-parallel data "
            "set (its FBP, Dremel and RESESOP rows are the tiny study's), three inputs, UNet 20 and CiUNetRes 8 "
            "epochs (the tiny study: 40 and 32), intervals fitted on the validation split. The learned rows are "
            "far below the tiny study's (the UNet below Dremel and RESESOP, docs/results.md); the reference "
            "tables: `nanoct reproduce --preset tiny-parallel` (docs/study.md)."
        ),
    ),
}

#: Studies of ``reproduce --scale`` where they differ from the one-setting study of the same size
#: (:data:`STUDIES`): at tiny scale the three settings share 45 minutes, so the residual invertible
#: networks train 24 epochs instead of 32, and the non-residual ones 12 instead of 24, without the
#: location term, CiUNet in the shift form and on the plateau schedule (docs/learn.md).
SCALE_STUDIES: dict[str, Study] = {
    "tiny": replace(
        STUDIES["tiny"],
        epochs={**STUDIES["tiny"].epochs, "cinn": 12, "cinn-res": 24, "ciunet": 12, "ciunet-res": 24},
        scheduler={},
        model_kwargs={
            **STUDIES["tiny"].model_kwargs,
            "cinn": _flow_kwargs("cinn", "location"),
            "ciunet": _flow_kwargs("ciunet", "shift"),
        },
    ),
}


def scale_study(scale: str) -> Study:
    """The :class:`Study` of ``reproduce --scale scale`` (:data:`SCALE_STUDIES`, else :data:`STUDIES`).

    Raises
    ------
    NanoctError
        If ``scale`` is not one of :data:`STUDIES`.
    """
    _check_scale(scale)
    return SCALE_STUDIES.get(scale) or STUDIES[scale]


def _check_scale(scale: str) -> None:
    if scale not in STUDIES:
        raise NanoctError(f"unknown scale {scale!r}; choose one of: {', '.join(STUDIES)}")


#: The paper's reconstructions (method, parameters), in its table order.
_PAPER_RECONS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("fbp", {}),
    ("dremel", {}),
    ("resesop", {"eta_scale": 1.0}),
    ("resesop", {"eta_scale": 0.8}),
    ("resesop", {"eta_scale": 1.2}),
)


def _recons(perturbed: bool = True) -> dict[str, tuple[str, dict[str, Any]]]:
    """Output name -> (method, parameters) of the study's reconstructions."""
    if not perturbed:  # the paper's unperturbed table: each method once, eta = 0 where a method uses eta
        methods = dict.fromkeys(m for m, _ in _PAPER_RECONS)
        return {m: (m, {"eta_scale": 0.0} if method_spec(m).needs_eta else {}) for m in methods}
    return {reconstruction_name(m, p): (m, p) for m, p in _PAPER_RECONS}


@dataclass(frozen=True)
class Setting:
    """One setting of a study: its geometry, data directory and the rows it has.

    Attributes
    ----------
    preset : str
        Geometry preset.
    perturbed : bool
        Motion in the data (False: the unperturbed case).
    out : Path
        Directory of the setting: ``data``, ``runs``, ``report`` below it.
    recons : dict
        Output name -> (method, parameters) of the first reconstructions.
    train_inputs : tuple of str
        Inputs the networks are trained on.
    mixing : tuple of str
        Networks also applied to every training input they were not trained on.
    paper : str or None
        Key of the paper's table this setting corresponds to (``parallel``, ``fan``,
        ``unperturbed``), None for a setting the paper does not have.
    name : str or None
        The study preset's name where it is not :attr:`preset` (:data:`STUDY_PRESETS`).
    note : str
        What the report says under its title about the study (:attr:`StudyPreset.note`).
    """

    preset: str
    perturbed: bool
    out: Path
    recons: dict[str, tuple[str, dict[str, Any]]]
    train_inputs: tuple[str, ...]
    mixing: tuple[str, ...]
    paper: str | None
    name: str | None = None
    note: str = ""

    @property
    def calibration(self) -> Path:
        """Directory of the setting's calibration set (:attr:`Study.n_calibration`)."""
        return self.out / "calibration"


def preset_names_all() -> list[str]:
    """The names ``reproduce --preset`` takes: the geometry presets and :data:`STUDY_PRESETS`."""
    return preset_names() + sorted(STUDY_PRESETS)


def preset_study(preset: str) -> Study:
    """The study of ``reproduce --preset``: a :data:`STUDY_PRESETS` entry's, else the :data:`STUDIES`
    entry of a geometry preset (its size prefix).

    Raises
    ------
    NanoctError
        If ``preset`` is neither a geometry preset nor a study preset.
    """
    if preset in STUDY_PRESETS:
        return STUDY_PRESETS[preset].study
    if preset not in preset_names():
        raise NanoctError(f"unknown preset {preset!r}; choose one of: {', '.join(preset_names_all())}")
    return STUDIES[preset.split("-")[0]]


def preset_models(preset: str) -> tuple[str, ...]:
    """The networks ``reproduce --preset`` trains without ``--models``: a study preset's, else all of them."""
    preset_study(preset)  # rejects an unknown preset
    return STUDY_PRESETS[preset].models if preset in STUDY_PRESETS else table_order()


def preset_setting(
    preset: str, perturbed: bool, out: Path | None, mixing: tuple[str, ...], seed: int = DEFAULT_SEED
) -> Setting:
    """The setting of ``nanoct reproduce --preset``: every first reconstruction is an input of every network.

    A study preset (:data:`STUDY_PRESETS`) simulates its geometry preset with its inputs only; its
    default directory is ``runs/<study preset>``.
    """
    preset_study(preset)  # rejects an unknown preset
    suffix = ("" if perturbed else "-nomotion") + ("" if seed == DEFAULT_SEED else f"-seed{seed}")
    recons = _recons(perturbed)
    named = STUDY_PRESETS.get(preset)
    geometry = preset if named is None else named.geometry
    if named is not None:
        recons = {k: v for k, v in recons.items() if k in named.inputs}
    out = Path(out or Path("runs") / f"{preset}{suffix}")
    return Setting(
        geometry,
        perturbed,
        out,
        recons,
        tuple(recons),
        mixing,
        setting_key(get_preset(geometry).kind, perturbed),
        name=None if named is None else preset,
        note="" if named is None else named.note,
    )


def scale_settings(scale: str, out: Path | None = None, seed: int = DEFAULT_SEED) -> list[Setting]:
    """The paper's three settings at a scale, with the paper's rows (see :func:`reproduce_scale`).

    Raises
    ------
    NanoctError
        If ``scale`` is not one of :data:`STUDIES`.
    """
    _check_scale(scale)
    root = Path(out or Path("runs") / (scale if seed == DEFAULT_SEED else f"{scale}-seed{seed}"))
    perturbed = _recons(True)
    fan = {k: v for k, v in perturbed.items() if k in ("fbp", "dremel", "resesop")}
    return [
        Setting(f"{scale}-parallel", True, root / "parallel", perturbed, tuple(perturbed), table_order(), "parallel"),
        Setting(f"{scale}-fan", True, root / "fan", fan, tuple(fan), (), "fan"),
        Setting(f"{scale}-parallel", False, root / "unperturbed", _recons(False), ("fbp",), (), "unperturbed"),
    ]


def check_models(models: tuple[str, ...] | None, default: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """The networks of a study (``None``: ``default``, else all, in the paper's order).

    Raises
    ------
    NanoctError
        For an unknown network name.
    """
    models = (table_order() if default is None else default) if models is None else tuple(models)
    unknown = [m for m in models if m not in table_order()]
    if unknown:
        raise NanoctError(f"unknown model(s) {unknown}; choose from {', '.join(table_order())}")
    return models


@dataclass(frozen=True)
class Jobs:
    """The jobs of one setting, per stage; the runner and :func:`nanoct.study.plan.plan_study` both use them.

    Attributes
    ----------
    samples : int
        Samples to simulate.
    recons : list of str
        First reconstructions (each over every sample).
    train : list of (model, input, seed)
        Training runs.
    predict : list of (model, train_input, input, seed)
        Predictions on the test split.
    calibration : int
        Samples of the calibration set (:attr:`Study.n_calibration` where an invertible network is
        trained, else 0).
    """

    samples: int
    recons: list[str]
    train: list[tuple[str, str, int]]
    predict: list[tuple[str, str, str, int]]
    calibration: int = 0


def setting_jobs(setting: Setting, study: Study, models: tuple[str, ...], n: int | None, seeds: int = 1) -> Jobs:
    """Every job of a setting: samples, reconstructions, training runs and predictions.

    With ``seeds > 1`` each network is trained on each of its inputs with training seeds
    ``0 .. seeds - 1`` (the rows that decide the paper's conclusions); input mixing uses seed 0.
    """
    if seeds < 1:
        raise NanoctError(f"seeds = {seeds} must be >= 1 (training seeds per network row)")
    train = [(m, i, s) for m in models for i in setting.train_inputs for s in range(seeds)]
    predict = [(m, i, i, s) for m, i, s in train]
    mixed = [m for m in models if m in setting.mixing]
    predict += [(m, t, i, 0) for m in mixed for t in setting.train_inputs for i in setting.train_inputs if i != t]
    calibration = study.n_calibration if any(model_class(m).has_uncertainty for m in models) else 0
    return Jobs(study.n if n is None else n, list(setting.recons), train, predict, calibration)
