"""Adding a reconstruction method takes its solver module and one registry entry (docs/adding_a_method.md).

A Landweber iteration written as a user would (a solver and its parameter class in one module)
is registered, and every tool reaches it: the registry's check and dispatch, the batch runner,
the result names, ``nanoct methods`` and ``nanoct reconstruct``.
"""

from __future__ import annotations

import sys
import textwrap

import numpy as np
import pytest

from nanoct.cli import run
from nanoct.core.errors import NanoctError
from nanoct.io.store import DataStore
from nanoct.names import reconstruction_name
from nanoct.recon import registry
from nanoct.recon.batch import reconstruct_dataset
from nanoct.recon.registry import MethodSpec, method_spec

SOLVER = textwrap.dedent(
    '''
    from dataclasses import dataclass
    from typing import Any

    import numpy as np

    from nanoct.core.operators import system_matrix
    from nanoct.core.validation import check_array, check_float, check_int
    from nanoct.recon.params import MethodParams, resolve_geometry
    from nanoct.recon.result import ReconResult


    @dataclass(frozen=True)
    class LandweberParams(MethodParams):
        """The parameters of :func:`landweber`.

        Parameters
        ----------
        n_iter : int, default 5
            Number of iterations.
        step : float, default 0.5
            Step on the gradient, relative to 1 / ||A||^2.
        """

        n_iter: int = 5
        step: float = 0.5

        def __post_init__(self) -> None:
            self._set("n_iter", check_int(self.n_iter, "n_iter", 1))
            self._set("step", check_float(self.step, "step", low=0.0, high=2.0, low_open=True, high_open=True))


    def landweber(op, sino, *, x0=None, callback=None, matrix=None, **params: Any) -> ReconResult:
        p = LandweberParams.check(op, **params)
        geometry = resolve_geometry(op)
        y = check_array(sino, "sinogram", shape=geometry.sino_shape).ravel().astype(np.float64)
        a = system_matrix(geometry) if matrix is None else matrix
        norm2 = float(np.abs(a).sum(axis=0).max() * np.abs(a).sum(axis=1).max())  # >= ||A||^2
        x = np.zeros(a.shape[1])
        residuals = []
        for _ in range(p["n_iter"]):
            r = a @ x - y
            residuals.append(float(np.linalg.norm(r)))
            x -= p["step"] / norm2 * (a.T @ r)
        image = x.reshape(geometry.image_shape).astype(np.float32)
        return ReconResult(image, residuals, "max_iter", None, {"method": "landweber", **p})
    '''
)


@pytest.fixture
def landweber(tmp_path, monkeypatch):
    """The user's module on the path and its one registry entry."""
    (tmp_path / "my_landweber.py").write_text(SOLVER)
    monkeypatch.syspath_prepend(str(tmp_path))
    spec = MethodSpec("landweber", "my_landweber:landweber", "my_landweber:LandweberParams", "Landweber iteration")
    monkeypatch.setitem(registry.METHODS, "landweber", spec)
    yield spec
    sys.modules.pop("my_landweber", None)


def test_a_registered_method_reaches_every_tool(landweber, tiny_store, capsys):
    g = tiny_store.geometry
    sample = tiny_store.read_sample(0)
    assert method_spec("landweber").check({"n_iter": 2}, g) == {"n_iter": 2, "step": 0.5}
    with pytest.raises(NanoctError, match="--param step"):
        method_spec("landweber").check({"step": 3.0}, g)
    result = method_spec("landweber").run(g, sample.sinogram, n_iter=3)
    assert result.residuals[-1] < result.residuals[0] and result.params["method"] == "landweber"
    assert reconstruction_name("landweber", {"n_iter": 3}) == "landweber"

    written = reconstruct_dataset(tiny_store.path, "landweber", split="test", params={"n_iter": 2}, workers=0)
    store = DataStore.open(tiny_store.path)
    test = store.indices("test")
    assert written == "landweber" and store.reconstruction_done("landweber", test).all()
    np.testing.assert_array_equal(
        store.read_reconstruction("landweber", test[:1])[0],
        method_spec("landweber").run(g, store.read_sample(int(test[0])).sinogram, n_iter=2).image,
    )

    assert run(["methods", "landweber"]) == 0
    assert "step = 0.5  Step on the gradient, relative to 1 / ||A||^2" in capsys.readouterr().out
    args = ["reconstruct", str(tiny_store.path), "--method", "landweber", "--name", "lw3", "--split", "val"]
    assert run([*args, "--param", "n_iter=3", "--workers", "0", "--quiet"]) == 0
    assert run([*args, "--param", "bogus=1", "--workers", "0", "--quiet"]) == 2
    assert "not a parameter of --method landweber; accepted: n_iter, step" in capsys.readouterr().err
