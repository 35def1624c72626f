"""The command-line interface: every command's help, user errors as one line + exit 2."""

import json
import sys

import pytest

from nanoct.cli import main
from nanoct.io.store import DataStore

COMMANDS = ["generate", "reconstruct", "train", "predict", "info", "show", "evaluate", "reproduce", "scaling"]


def run(monkeypatch, capsys, *args):
    monkeypatch.setattr(sys, "argv", ["nanoct", *map(str, args)])
    code = 0
    try:
        main()
    except SystemExit as exc:
        code = exc.code or 0
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("command", COMMANDS)
def test_help(monkeypatch, capsys, command):
    code, out, _ = run(monkeypatch, capsys, command, "--help")
    assert code == 0 and "Usage" in out


@pytest.mark.slow
def test_generate_info_show_evaluate(monkeypatch, capsys, tmp_path):
    d = tmp_path / "d"
    code, out, _ = run(
        monkeypatch,
        capsys,
        "generate",
        "--preset",
        "tiny-fan",
        "--n",
        4,
        "--out",
        d,
        "--workers",
        0,
        "-q",
        "--split-fractions",
        "0.5,0.25,0.25",
    )
    assert code == 0 and "4/4 samples" in out
    code, out, _ = run(monkeypatch, capsys, "info", d, "--json")
    info = json.loads(out)
    assert code == 0 and info["complete"] and info["geometry"]["kind"] == "fan" and info["reconstructions"] == {}
    code, out, _ = run(monkeypatch, capsys, "info", d)
    assert "fan beam" in out and "4/4" in out
    code, _, err = run(monkeypatch, capsys, "evaluate", d)
    assert code == 2 and "nanoct reconstruct" in err
    code, out, _ = run(monkeypatch, capsys, "reconstruct", d, "--method", "fbp", "--workers", 0, "-q")
    assert code == 0 and "wrote reconstructions/fbp (4 samples; 4 done)" in out
    code, out, _ = run(monkeypatch, capsys, "reconstruct", d, "--method", "fbp", "--workers", 0, "-q")
    assert code == 0 and "reconstructions/fbp was complete already (4 samples); nothing to do" in out
    code, out, _ = run(monkeypatch, capsys, "evaluate", d, "--json")
    assert code == 0 and set(json.loads(out[: out.rindex("}") + 1])["results"]["fbp"]) == {
        "psnr_mean",
        "psnr_std",
        "ssim_mean",
        "ssim_std",
        "n",
        "psnr_values",
        "ssim_values",
        "psnr_registered_mean",
        "psnr_registered_std",
        "ssim_registered_mean",
        "ssim_registered_std",
        "psnr_registered_values",
        "ssim_registered_values",
        "shift_values",
        "shift_mean",
    }
    assert (d / "report" / "evaluation.md").is_file()
    run_dir = tmp_path / "run"
    code, out, err = run(
        monkeypatch,
        capsys,
        "train",
        d,
        "--model",
        "unet",
        "--input",
        "fbp",
        "--epochs",
        1,
        "--out",
        run_dir,
        "--param",
        "channels=[4,4,4,4,4]",
        "--lr-schedule",
        "plateau",
        "-q",
    )
    assert code == 0 and (run_dir / "best.pt").is_file() and (run_dir / "log.csv").is_file(), err
    assert json.loads((run_dir / "config.json").read_text())["scheduler"] == "plateau"
    code, _, err = run(
        monkeypatch, capsys, "train", d, "--input", "fbp", "--out", tmp_path / "r3", "--lr-schedule", "step"
    )
    assert code == 2 and "'step' is unknown" in err and not (tmp_path / "r3").exists()
    code, out, _ = run(monkeypatch, capsys, "predict", d, "--run", run_dir, "-q")
    assert code == 0 and "wrote reconstructions/fbp+unet (1 sample; 1 done)" in out
    code, out, _ = run(monkeypatch, capsys, "predict", d, "--run", run_dir, "-q")
    assert code == 0 and "reconstructions/fbp+unet was complete already (1 sample); nothing to do" in out
    code, out, _ = run(monkeypatch, capsys, "predict", d, "--run", run_dir, "--name", "second", "-q")
    assert code == 0 and "reconstructions/second" in out and "second" in DataStore.open(d).reconstruction_names()
    code, _, err = run(monkeypatch, capsys, "predict", d, "--run", run_dir, "--name", "a/b", "-q")
    assert code == 2 and "a/b" in err
    code, _, err = run(monkeypatch, capsys, "predict", d, "--run", run_dir, "--samples", 0)
    assert code == 2 and "--samples 0" in err
    code, _, err = run(monkeypatch, capsys, "predict", d, "--run", tmp_path / "nope")
    assert code == 2 and "no training run" in err
    code, _, err = run(monkeypatch, capsys, "train", d, "--model", "vit", "--input", "fbp")
    assert code == 2 and "model 'vit' is unknown" in err
    code, _, err = run(
        monkeypatch, capsys, "train", d, "--model", "unet", "--input", "dremel", "--out", tmp_path / "r2"
    )
    assert code == 2 and "dremel" in err
    png = tmp_path / "fig.png"
    code, _, _ = run(monkeypatch, capsys, "show", d, "--index", 1, "--out", png)
    assert code == 0 and png.read_bytes()[:4] == b"\x89PNG"
    code, _, err = run(monkeypatch, capsys, "show", d, "--index", 9, "--out", png)
    assert code == 2 and "--index 9" in err


@pytest.mark.parametrize(
    "args, message",
    [
        (["generate", "--preset", "huge-parallel", "--n", 3, "--out", "X"], "unknown preset 'huge-parallel'"),
        (["generate", "--preset", "tiny-parallel", "--n", 0, "--out", "X"], "--n 0"),
        (
            ["generate", "--preset", "tiny-parallel", "--n", 3, "--out", "X", "--split-fractions", "1,2"],
            "three comma-separated",
        ),
        (["info", "X"], "no nanoct data set"),
        (["reconstruct", "X", "--method", "fbp"], "no nanoct data set"),
        (["reconstruct", "X", "--method", "fbp", "--eta-scale", "0.8"], "--eta-scale applies to --method resesop"),
        (["reproduce", "--preset", "medium-fan"], "unknown preset"),
    ],
)
def test_user_errors(monkeypatch, capsys, tmp_path, args, message):
    args = [str(tmp_path / "X") if a == "X" else a for a in args]
    code, _, err = run(monkeypatch, capsys, *args)
    assert code == 2
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "X").exists()  # nothing half-written


@pytest.mark.parametrize(
    ("flags", "expected"),
    [
        ((), None),
        (("--samples", 8), {"n_samples": 8}),
        (("--antithetic",), {"antithetic": True}),
        (("--samples", 8, "--antithetic"), {"n_samples": 8, "antithetic": True}),
    ],
)
def test_predict_passes_the_sampling_options(monkeypatch, capsys, tmp_path, flags, expected):
    import nanoct.learn.predict

    seen = {}

    def fake_predict(*args, **kwargs):
        seen.update(kwargs)
        return "fbp+cinn-res"

    monkeypatch.setattr(nanoct.learn.predict, "predict", fake_predict)
    code, out, err = run(monkeypatch, capsys, "predict", tmp_path, "--run", tmp_path / "run", *flags)
    assert code == 0 and "reconstructions/fbp+cinn-res" in out, err
    assert seen["reconstruct_kwargs"] == expected


def test_param_values_are_json_or_booleans_in_any_case():
    """``--param`` values: JSON where they parse, True / FALSE (Python's spelling, any case) as booleans, and other
    words, ``none`` among them (a Dremel weighting), as strings."""
    from nanoct.cli.parsing import parse_params

    items = ["a=0.2", "b=[16,32]", "c=False", "d=TRUE", "e=false", "f=none", "g=word", "h=x=y"]
    assert parse_params(items) == {
        "a": 0.2,
        "b": [16, 32],
        "c": False,
        "d": True,
        "e": False,
        "f": "none",
        "g": "word",
        "h": "x=y",
    }
