"""The stack's vertical motion is zero, with the reason recorded and printed, where the row profiles show none."""

from __future__ import annotations

import numpy as np
import zarr

from nanoct.cli import run
from nanoct.io.store import DataStore
from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

K, R, L = 60, 24, 48


def _still_stack(folder):
    """Raw intensities of a still stack of 4 phantom slices, each over 6 rows (as the docs' scan.nxs), flats, darks."""
    phi = np.linspace(0, np.pi, K, endpoint=False)
    slices = [ellipse_sinogram(e, phi, L) for e in stack_phantom(L, 4, seed=1)]
    lines = np.stack([slices[r * 4 // R] for r in range(R)], axis=1)  # (K, R, L): nothing moves
    counts = 20 + 980 * np.exp(-lines / lines.max())
    np.save(folder / "scan.npy", np.round(counts).astype(np.uint16))  # the quantisation of a detector
    np.save(folder / "flats.npy", np.full((2, R, L), 1000, np.uint16))
    np.save(folder / "darks.npy", np.full((2, R, L), 20, np.uint16))
    return folder / "scan.npy", ["--angles", "0:180", "--flats", str(folder / "flats.npy"),
                                 "--darks", str(folder / "darks.npy")]  # fmt: skip


def test_no_vertical_motion_invented_on_a_still_phantom_stack(tmp_path, capsys):
    path, read = _still_stack(tmp_path)
    store = tmp_path / "store"
    assert run(["import", str(path), "--out", str(store), *read, "-q"]) == 0
    assert run(["stack", str(store), "--center-offset", "0", "-w", "0"]) == 0
    info = DataStore.open(store).recons.motion_info("fbp_stack")
    assert info["vertical_method"] == "none" and not np.any(info["vertical"])
    guard = info["vertical_guard"]
    assert guard["significant"] is False and guard["raw_rms"] > 1.0  # the unguarded estimate invents motion
    assert "no vertical motion estimated" in capsys.readouterr().out
    # the streaming path: the same guard
    out = tmp_path / "s.zarr"
    assert (
        run(["stack", str(path), "--out", str(out), "--block", "8", "--center-offset", "0", "-w", "0", "-q", *read])
        == 0
    )
    streamed = dict(zarr.open_group(str(out), mode="r").attrs["info"])
    assert not np.any(streamed["vertical"]) and streamed["vertical_guard"]["significant"] is False
