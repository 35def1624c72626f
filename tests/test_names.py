"""The name grammar of results and settings (nanoct.names): built and parsed in one place."""

from __future__ import annotations

import pytest

from nanoct.core.errors import NanoctError
from nanoct.names import (
    SETTINGS,
    ResultName,
    eta_label,
    is_prediction,
    parse_name,
    predict_command,
    prediction_name,
    reconstruct_command,
    reconstruction_name,
    seed_name,
    setting_key,
    strip_seed,
)


def test_reconstruction_names():
    assert reconstruction_name("resesop", {"eta_scale": 1.0}) == "resesop"
    assert reconstruction_name("resesop") == "resesop"
    assert reconstruction_name("resesop", {"eta_scale": 0.8}) == "resesop_eta0.8"
    assert reconstruction_name("resesop", {"eta_scale": 1.2}) == "resesop_eta1.2"
    assert reconstruction_name("dremel") == "dremel"
    assert reconstruction_name("fbp", {"filter": "hann"}) == "fbp"
    assert (
        reconstruction_name("resesop", {"eta": "estimate:residual", "eta_scale": 0.8}) == "resesop_est-residual_eta0.8"
    )
    assert reconstruction_name("resesop", {"eta": "estimate:reference=x", "eta_scale": 1.0}) == "resesop_est-reference"
    assert reconstruction_name("resesop", {"eta": "estimate:residual=fbp"}) == "resesop_est-residual-fbp"
    assert reconstruction_name("resesop", {"eta": "true", "eta_scale": 1.2}) == "resesop_eta1.2"
    with pytest.raises(NanoctError, match="sirt"):
        reconstruction_name("sirt")


def test_eta_labels():
    assert eta_label("true") == ""
    assert eta_label("estimate:residual=dremel") == "est-residual"
    assert eta_label("estimate:residual") == "est-residual"
    assert eta_label("estimate:residual=fbp") == "est-residual-fbp"
    assert eta_label("estimate:reference=/a/b") == "est-reference"


def test_reconstruct_command_hints_only_registered_methods():
    assert reconstruct_command("d", "fbp") == "nanoct reconstruct d --method fbp"
    assert reconstruct_command("d", "resesop_eta0.8") == "nanoct reconstruct d --method resesop --eta-scale 0.8"
    assert reconstruct_command("D", "resesop_est-residual_eta0.8") == (
        "nanoct reconstruct D --method resesop --eta estimate:residual --eta-scale 0.8"
    )
    assert (
        reconstruct_command("d", "sirt")
        == "nanoct reconstruct d --method <fbp|gridrec|kaczmarz|dremel|resesop> --name sirt"
    )
    assert reconstruct_command("d", "resesop_etaX").endswith("--name resesop_etaX")
    assert predict_command("d", "fbp+unet").startswith("'nanoct predict d --run RUN'")
    assert predict_command("d", "fbp") == "'nanoct reconstruct d --method fbp'"


@pytest.mark.parametrize(
    ("name", "parts"),
    [
        ("resesop_eta0.8", ("resesop_eta0.8", None, "resesop_eta0.8", 0)),
        ("resesop+unet", ("resesop", "unet", "resesop", 0)),
        ("fbp+ciunet-res@resesop", ("fbp", "ciunet-res", "resesop", 0)),
        ("dremel+unet%seed2", ("dremel", "unet", "dremel", 2)),
        ("fbp+cinn@dremel%seed1", ("fbp", "cinn", "dremel", 1)),
    ],
)
def test_result_names_round_trip(name, parts):
    parsed = ResultName.parse(name)
    assert (parsed.input, parsed.model, parsed.train_input, parsed.seed) == parts
    assert str(parsed) == name
    if parts[1] is not None:
        assert prediction_name(*parts) == name
    assert strip_seed(name) == parsed.base
    assert is_prediction(name) == (parts[1] is not None)


def test_prediction_and_seed_names():
    assert prediction_name("fbp", "unet") == "fbp+unet"
    assert prediction_name("fbp", "unet", "fbp") == "fbp+unet"
    assert prediction_name("dremel", "unet", "fbp") == "dremel+unet@fbp"
    assert prediction_name("dremel", "unet", "fbp", seed=3) == "dremel+unet@fbp%seed3"
    assert seed_name("fbp+unet", 0) == "fbp+unet" and seed_name("fbp+unet", 1) == "fbp+unet%seed1"
    assert parse_name("fbp+ciunet-res@resesop") == ("fbp", "ciunet-res", "resesop")
    assert parse_name("resesop_eta0.8") == ("resesop_eta0.8", None, "resesop_eta0.8")


def test_settings():
    assert tuple(SETTINGS) == ("parallel", "fan", "unperturbed")
    assert setting_key("parallel", True) == "parallel"
    assert setting_key("fan", True) == "fan"
    assert setting_key("parallel", False) == "unperturbed"
    assert setting_key("fan", False) is None


def test_stack_names_and_their_command():
    from nanoct.names import reconstruct_command, stack_name

    assert stack_name("fbp") == "fbp_stack"
    assert reconstruct_command("d", "fbp_stack") == "nanoct stack d --method fbp"
    assert reconstruct_command("d", "dremel_stack") == "nanoct stack d --method dremel"
