"""The README's notebook example runs as written (on a small Data Exchange file it makes)."""

from __future__ import annotations

import re
from pathlib import Path

import h5py
import matplotlib
import numpy as np

from nanoct.core.geometry import Geometry
from nanoct.core.operators import RayTransform

README = Path(__file__).resolve().parents[1] / "README.md"


def _example() -> str:
    text = README.read_text()
    section = text[text.index("## Your own scan") :]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_notebook_example_runs(tmp_path, monkeypatch):
    matplotlib.use("Agg")
    g = Geometry.from_angles(np.linspace(0, np.pi, 40, endpoint=False), 41, 41)
    x = np.zeros(g.image_shape, np.float32)
    x[12:28, 15:30] = 0.05
    line = np.stack([RayTransform(g).forward(x)] * 2, axis=1)  # (views, 2 rows, columns)
    with h5py.File(tmp_path / "scan.h5", "w") as f:
        f["exchange/data"] = 1000 * np.exp(-line)
        f["exchange/data_white"] = np.full((2, 2, 41), 1000.0)
        f["exchange/data_dark"] = np.zeros((2, 2, 41))
        f["exchange/theta"] = np.rad2deg(g.angles)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(_example(), "README example", "exec"), namespace)
    assert (tmp_path / "dremel.png").stat().st_size > 1000
    assert namespace["result"].image.shape == (41, 41)
