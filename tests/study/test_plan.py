"""``nanoct reproduce --plan``: stages, job counts, disk and time estimates without running anything."""

import sys

import pytest

from nanoct.cli import main
from nanoct.core.errors import NanoctError
from nanoct.study.config import STUDIES
from nanoct.study.plan import STAGES, format_plan, plan_study

# the paper's rows, counted by hand: parallel 5 inputs x 5 networks, mixing 5 networks x 5 x 4;
# fan 3 inputs (FBP added) x 5 networks; unperturbed: the 5 networks on FBP only.
EXPECTED = {
    "parallel": {"reconstructions": 5, "training": 25, "prediction": 25 + 5 * 20},
    "fan": {"reconstructions": 3, "training": 15, "prediction": 15},
    "unperturbed": {"reconstructions": 3, "training": 5, "prediction": 5},
}


@pytest.mark.parametrize("scale", ["tiny", "small", "paper"])
def test_plan_every_scale(scale):
    plan = plan_study(scale, cores=16)
    n, cal = STUDIES[scale].n, STUDIES[scale].n_calibration  # the calibration set is simulated alike
    train_inputs = {"parallel": 5, "fan": 3, "unperturbed": 1}
    assert [(p.setting, p.stage) for p in plan] == [(s, st) for s in EXPECTED for st in STAGES]
    for p in plan:
        if p.stage == "data":
            assert p.jobs == n + cal and p.disk_bytes > 0 and p.seconds > 0
        elif p.stage == "reconstructions":
            assert p.jobs == EXPECTED[p.setting]["reconstructions"] * n + train_inputs[p.setting] * cal
        elif p.stage in ("training", "prediction"):
            assert p.jobs == EXPECTED[p.setting][p.stage] and p.seconds > 0
    text = format_plan(plan)
    assert "total" in text and "benchmarks/README.md" in text


def test_plan_scales_with_cores_gpus_and_seeds():
    two, eight = plan_study("small", cores=2), plan_study("small", cores=8)
    for a, b in zip(two, eight):
        assert a.jobs == b.jobs and (a.stage == "report" or b.seconds == pytest.approx(a.seconds / 4))
    gpu = plan_study("small", cores=2, gpus=2)
    assert all((p.seconds is None) == (p.stage in ("training", "prediction")) for p in gpu)
    assert "? (no figure)" in format_plan(gpu)
    fast = plan_study("small", cores=2, gpus=2, gpu_speedup=50)
    train = [p for p in fast if p.stage == "training"][0]
    assert train.seconds == pytest.approx([p for p in two if p.stage == "training"][0].seconds * 2 / 100)
    seeded = plan_study("tiny", seeds=3)
    assert [p.jobs for p in seeded if p.stage == "training"] == [75, 45, 15]
    assert [p.jobs for p in seeded if p.stage == "prediction"] == [75 + 100, 45, 15]
    one = plan_study(None, preset="tiny-fan", n=40, models=("unet",))
    assert [p.jobs for p in one] == [40, 5 * 40, 5, 5 + 5 * 4, 1]  # the tiny study mixes the UNet


@pytest.mark.parametrize(
    "kwargs", [{"cores": 0}, {"gpus": -1}, {"gpus": 1, "gpu_speedup": 0.0}, {"scale": "huge"}, {"preset": "nope"}]
)
def test_plan_rejects_bad_input(kwargs):
    scale = kwargs.pop("scale", None if "preset" in kwargs else "tiny")
    with pytest.raises(NanoctError):
        plan_study(scale, **kwargs)


def _cli(monkeypatch, capsys, *args):
    monkeypatch.setattr(sys, "argv", ["nanoct", *args])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code or 0
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_plan_runs_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, out, err = _cli(monkeypatch, capsys, "reproduce", "--scale", "paper", "--plan", "--cores", "64")
    assert code == 0, err
    assert "parallel" in out and "reconstructions" in out and "160,475" in out
    assert list(tmp_path.iterdir()) == []


def test_cli_scale_rejects_preset_options(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, _, err = _cli(monkeypatch, capsys, "reproduce", "--scale", "tiny", "--no-motion", "--plan")
    assert code == 2 and "--no-motion" in err


def test_prediction_cost_counts_one_calibration_per_invertible_run():
    """Test images for every prediction, validation images once per invertible run (mixing reuses the fit)."""
    from nanoct.study.config import Study
    from nanoct.study.plan import _PREDICT

    study = Study(n=200, split_fractions=(0.8, 0.1, 0.1), n_samples=10, mixing=("cinn-res",))
    (pred,) = [
        p
        for p in plan_study(None, preset="tiny-parallel", models=("cinn-res",), study=study, cores=1)
        if p.stage == "prediction"
    ]
    assert pred.jobs == 25  # 5 inputs x 5 inputs
    per_image = _PREDICT[63]["inn"] * study.n_samples
    assert pred.seconds == pytest.approx(per_image * (25 * 20 + 5 * 20))


@pytest.mark.parametrize("native", [True, False])
def test_tiny_training_is_priced_in_the_precision_this_machine_takes(monkeypatch, native):
    """The tiny study's 'auto' precision is bf16 on a CPU with native bfloat16, fp32 elsewhere; the
    fp32 estimate is the bf16 figure times the measured fp32/bf16 step-time ratio."""
    from nanoct.learn import train as train_module
    from nanoct.study.plan import _FP32_OVER_BF16, _TRAIN

    monkeypatch.setattr(train_module, "native_bf16", lambda device: native)
    (training,) = [p for p in plan_study(None, preset="tiny-parallel", cores=1) if p.stage == "training"]
    study = STUDIES["tiny"]
    assert study.precision == "auto" and training.precision == ("bf16" if native else "fp32")
    family = {m: "unet" if m == "unet" else "inn" for m in study.epochs}
    per_model = {m: 5 * study.epochs[m] * 160 * _TRAIN[63][family[m]] for m in study.epochs}  # 5 inputs, 160 images
    bf16 = sum(per_model.values())
    fp32 = sum(v * _FP32_OVER_BF16[family[m]] for m, v in per_model.items())
    assert training.seconds == pytest.approx(bf16 if native else fp32)
    assert f"training ({training.precision})" in format_plan([training])
    # on a GPU 'auto' is bf16; the small study's fp32 stays fp32
    (gpu,) = [p for p in plan_study(None, preset="tiny-parallel", gpus=1, gpu_speedup=10) if p.stage == "training"]
    assert gpu.precision == "bf16"
    assert {p.precision for p in plan_study("small") if p.stage == "training"} == {"fp32"}


def test_cli_precision_option_reaches_the_plan_and_unknown_ones_are_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, out, err = _cli(monkeypatch, capsys, "reproduce", "--plan", "--precision", "fp32")
    assert code == 0, err
    assert "training (fp32)" in out and "training (bf16)" not in out
    code, out, err = _cli(monkeypatch, capsys, "reproduce", "--scale", "small", "--plan", "--precision", "bf16")
    assert code == 0 and out.count("training (bf16)") == 3, err
    code, _, err = _cli(monkeypatch, capsys, "reproduce", "--plan", "--precision", "fp16")
    assert code == 2 and "--precision 'fp16' is unknown; use one of fp32, bf16, auto" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("native", "precision", "said"),
    [
        (False, "auto", "fp32 (CPU without native bfloat16"),
        (True, "auto", "bf16\n"),
        (False, "bf16", "bf16 (emulated on this CPU"),
    ],
)
def test_reproduce_says_which_precision_its_training_takes(monkeypatch, capsys, native, precision, said):
    from nanoct.cli.study import precision_note
    from nanoct.learn import train as train_module

    monkeypatch.setattr(train_module, "native_bf16", lambda device: native)
    monkeypatch.setattr(train_module, "resolve_device", lambda *a: train_module.torch.device("cpu"))
    precision_note(precision)
    assert capsys.readouterr().err.startswith(f"note: training precision {said}")


def test_a_calibration_set_is_simulated_reconstructed_and_sampled_in_the_plan():
    """The tiny study's calibration set: simulated and reconstructed by every training input, and the
    invertible runs calibrate on it instead of the validation split; without an invertible network, none."""
    from nanoct.study.config import Study
    from nanoct.study.plan import _PREDICT

    study = Study(n=200, split_fractions=(0.8, 0.1, 0.1), n_samples=10, mixing=(), n_calibration=50)
    plan = {p.stage: p for p in plan_study(None, preset="tiny-parallel", models=("cinn-res",), study=study, cores=1)}
    assert plan["data"].jobs == 250 and plan["reconstructions"].jobs == 5 * 250
    assert plan["prediction"].seconds == pytest.approx(_PREDICT[63]["inn"] * 10 * (5 * 20 + 5 * 50))
    plain = {p.stage: p for p in plan_study(None, preset="tiny-parallel", models=("unet",), study=study, cores=1)}
    assert plain["data"].jobs == 200 and plain["reconstructions"].jobs == 5 * 200
    assert STUDIES["tiny"].n_calibration == 100


def test_cli_plan_of_tiny_quick_trains_its_two_networks_by_default(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, out, err = _cli(monkeypatch, capsys, "reproduce", "--preset", "tiny-quick", "--plan")
    assert code == 0, err
    rows = {line.split()[1]: line.split() for line in out.splitlines() if line.startswith("tiny-quick ")}
    assert rows["training"][3] == "6" and rows["prediction"][2] == "12"
    code, out, err = _cli(monkeypatch, capsys, "reproduce", "--preset", "tiny-quick", "--plan", "--models", "unet")
    assert code == 0, err
    assert next(line for line in out.splitlines() if " training " in line).split()[3] == "3"
    code, out, err = _cli(monkeypatch, capsys, "reproduce", "--preset", "tiny-parallel", "--plan")
    assert code == 0 and next(line for line in out.splitlines() if " training " in line).split()[3] == "25"
    assert list(tmp_path.iterdir()) == []
