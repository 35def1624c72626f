"""Every registered reconstruction method through the one solver contract (parallel and fan beam).

A method added to :data:`nanoct.recon.registry.METHODS` is picked up here automatically; the
test of bad values fails until each of its parameters has bad values listed in ``BAD``.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset
from nanoct.core.operators import RayTransform, system_matrix
from nanoct.recon import STOP_REASONS
from nanoct.recon.registry import METHODS, check_method_params, method_spec
from nanoct.sim.phantoms import random_phantom

PRESETS = ("tiny-parallel", "tiny-fan")
NAMES = tuple(METHODS)
NAN = float("nan")

#: Bad values of every parameter any registered method has (the name must appear in the error).
BAD: dict[str, list] = {
    "n_iter": [0, 2.5, "3", True],
    "relaxation": [NAN, 0.0, 2.0, -1.0, "0.5"],
    "order": ["spiral", 1],
    "nonneg": ["yes", 2],
    "seed": [-1, 1.5],
    "residual": ["fast", None],
    "filter": ["gauss", 3],
    "eta_scale": [-1.0, NAN, "1"],
    "delta": [-0.1, float("inf")],
    "tau": [1.0, 0.5, NAN],
    "stop_rule": ["never"],
    "shift_relaxation": [0.0, 1.5, NAN],
    "correction_start": [-1, 0.5],
    "f_sr": [0, 1.5],
    "weighting": ["multiplicative"],
    "subpixel": ["no"],
    "fix_shifts": ["maybe", 2],
    "projector": ["gpu", 1],
    "measured": ["yes", 1],
    "pad": [-1, 2.5],
    "motion_slices": ["some", "-1", "1,x", ""],
    "shifts_from": ["/nonexistent/shifts.txt"],
    "eta": ["estimate", "estimate:reference", "guess", "estimate:residual=a/b"],
    "interpolation": ["cubic", 1],
    "eps": [0.0, 0.5, NAN, "1e-6"],
    "backend": ["opencl", None],
}


def _is_iterative(name: str) -> bool:
    return "n_iter" in method_spec(name).parameter_names()


def _run(name, op, y, eta=None, **params):
    spec = method_spec(name)
    if spec.parallel_only and getattr(op, "geometry", op).kind != "parallel":
        pytest.skip(f"{name} handles parallel beam only")
    if spec.needs_eta:
        eta = np.zeros(y.shape[0]) if eta is None else eta
    return spec.run(op, y, eta if spec.needs_eta else None, **params)


def _quick(name: str) -> dict:
    """Small, non-default parameters: two iterations for iterative methods, Hann for FBP."""
    return {"n_iter": 2, "seed": 3} if _is_iterative(name) else {"filter": "hann"}


@pytest.fixture(scope="module", params=PRESETS)
def problem(request):
    g = get_preset(request.param)
    x = random_phantom(np.random.default_rng(5), g.n).astype(np.float32)
    y = (system_matrix(g) @ x.ravel()).reshape(g.sino_shape)
    eta = np.full(g.n_angles, 0.01 * float(np.abs(y).max()))
    return g, x, y, eta


@pytest.mark.parametrize("name", NAMES)
def test_output_and_recorded_parameters(name, problem):
    g, _, y, eta = problem
    given = _quick(name)
    res = _run(name, g, y, eta, **given)
    assert res.image.shape == g.image_shape and res.image.dtype == np.float32
    assert np.isfinite(res.image).all() and np.abs(res.image).max() > 0
    assert res.stop_reason in STOP_REASONS
    spec = method_spec(name)
    if _is_iterative(name):
        assert len(res.residuals) == res.iterations <= given["n_iter"] and np.isfinite(res.residuals).all()
    else:
        assert res.stop_reason == "direct" and res.residuals == []
    if spec.estimates_motion:
        assert res.motion.shape == (g.n_angles,) and res.motion.dtype == np.float32
    else:
        assert res.motion is None
    # every parameter is recorded, as the check normalises it, with the method's name
    checked = check_method_params(name, given, g)
    assert set(checked) == set(spec.parameter_names())
    solver_checked = {k: checked[k] for k in spec.solver_parameter_names()}
    assert res.params["method"] == name and {k: res.params[k] for k in solver_checked} == solver_checked
    # the same result from an unperturbed RayTransform (the same first argument for all methods)
    np.testing.assert_array_equal(_run(name, RayTransform(g), y, eta, **given).image, res.image)


@pytest.mark.parametrize("name", NAMES)
def test_solver_signature_and_declared_parameters(name):
    spec = method_spec(name)
    solver = inspect.signature(spec.solver()).parameters
    assert list(solver)[:2] == ["op", "sino"] and (list(solver)[2] == "eta") == spec.needs_eta
    assert list(solver)[-1] == "params" and solver["params"].kind is inspect.Parameter.VAR_KEYWORD
    # the parameters are declared once, in the parameter class, never again in the solver's signature
    assert not set(spec.solver_parameter_names()) & set(solver)
    defaults = spec.params_class()()
    for p in spec.solver_parameter_names():
        assert spec.parameter_help()[p] != "(undocumented)", f"document {p} in the parameter class's docstring"
        assert getattr(defaults, p) == spec.params_class().__dataclass_fields__[p].default or p == "relaxation"
    if _is_iterative(name):
        assert {"x0", "callback", "matrix"} <= set(solver)


@pytest.mark.parametrize("name", [n for n in NAMES if _is_iterative(n)])
def test_callback_stops_iterative_methods(name, problem):
    g, _, y, _ = problem
    seen = []

    def callback(iteration, x, motion):
        seen.append((iteration, x.shape, None if motion is None else motion.shape))
        return iteration == 1

    res = _run(name, g, y, np.zeros(g.n_angles), n_iter=5, callback=callback)
    assert res.stop_reason == "callback" and res.iterations == 2
    motion_shape = (g.n_angles,) if method_spec(name).estimates_motion else None
    assert seen == [(0, g.image_shape, motion_shape), (1, g.image_shape, motion_shape)]


@pytest.mark.parametrize("name", [n for n in NAMES if _is_iterative(n)])
def test_start_image(name, problem):
    g, x, y, _ = problem
    zero = _run(name, g, y, n_iter=1, nonneg=False)
    start = _run(name, g, y, n_iter=1, nonneg=False, x0=x)
    assert not np.array_equal(zero.image, start.image)
    with pytest.raises(ValueError, match="x0"):
        _run(name, g, y, x0=np.zeros((3, 3)))


@pytest.mark.parametrize("name", NAMES)
def test_bad_sinograms(name, problem):
    g, _, y, _ = problem
    with pytest.raises(ValueError, match="sinogram"):
        _run(name, g, y[:, :-1])
    bad = y.copy()
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="sinogram"):
        _run(name, g, bad)


@pytest.mark.parametrize("name", NAMES)
def test_unknown_parameter(name, problem):
    g, _, y, _ = problem
    with pytest.raises(TypeError, match="bogus"):
        _run(name, g, y, bogus=1)
    with pytest.raises(NanoctError, match=r"--param bogus.*accepted"):
        check_method_params(name, {"bogus": 1}, g)


@pytest.mark.parametrize(
    ("name", "param", "value"),
    [(n, p, v) for n in NAMES for p in method_spec(n).parameter_names() for v in BAD.get(p, [])],
)
def test_bad_values(name, param, value, problem):
    g, _, y, _ = problem
    if param in method_spec(name).solver_parameter_names():  # batch parameters are not the solver's
        with pytest.raises(ValueError, match=param):
            _run(name, g, y, **{param: value})
    flag = {"eta_scale": "--eta-scale", "eta": "--eta"}.get(param, f"--param {param}")
    with pytest.raises(NanoctError, match=flag):
        check_method_params(name, {param: value}, g)


@pytest.mark.parametrize("name", NAMES)
def test_every_parameter_has_bad_values(name):
    missing = [p for p in method_spec(name).parameter_names() if not BAD.get(p)]
    assert not missing, f"add bad values of {missing} to BAD"
