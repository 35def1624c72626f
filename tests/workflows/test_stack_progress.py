"""What `nanoct stack` tells the user while it estimates the motion, and when it refuses a name."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import nanoct.motion.estimate as estimate_module
import nanoct.motion.focus as focus_module
import nanoct.motion.stack as motion_stack
from nanoct.cli import run
from nanoct.core.errors import StoreError
from nanoct.core.geometry import Geometry
from nanoct.io.store import DataStore, create_scan
from nanoct.workflows import stack as stack_batch
from nanoct.workflows.stack import horizontal_motion, reconstruct_stack

L, K, S = 24, 16, 3
PARAMS = {"motion_slices": [0, 2], "center": "auto", "refine": None, "binning": 2, "coarse_iter": 1}


@pytest.fixture
def store(tmp_path):
    phi = np.arange(K) * np.pi / K
    sino = np.random.default_rng(0).uniform(0.5, 1.0, (S, K, L)).astype(np.float32)
    return create_scan(tmp_path / "scan", Geometry.from_angles(phi, L, L), sino, {"source": "test"}).path


@pytest.fixture
def no_air(monkeypatch, capsys):
    """No air seen and an autofocus that runs to its bounds (the K11 crop's path); each slow step's
    stand-in records what the user had been shown when it started."""
    shown: dict[str, str] = {}

    def at(step, value):
        def stand_in(*args, progress=None, **kwargs):
            shown[step] = capsys.readouterr().err
            for _ in range(3 + len(kwargs.get("refine", ())) if progress else 0):
                progress("stage")
            return value

        return stand_in

    monkeypatch.setattr(stack_batch, "remove_air", lambda sinos, zero_air=False: (np.asarray(sinos), False))
    monkeypatch.setattr(estimate_module, "start_axis", at("start axis", 0.0))
    monkeypatch.setattr(focus_module, "focus_smooth", at("autofocus", SimpleNamespace(accepted=False)))
    found = motion_stack.StackMotion(np.zeros(K), 0.0, 0.0, np.zeros(K), "opposite views", 0.5, [0.1])
    monkeypatch.setattr(motion_stack, "estimate_stack_motion", at("dremel", found))
    return shown


@pytest.mark.parametrize("name", ["fbp_stack", "motion"])
def test_the_motion_bar_names_each_slow_step_before_it_runs(store, no_air, capsys, name):
    shifts, info = horizontal_motion(DataStore.open(store), PARAMS, np.zeros(K), True, name)
    assert info["horizontal_method"] == "dremel+matching" and shifts.shape == (K,)
    label = "fbp_stack: motion:" if name == "fbp_stack" else "motion:"
    for step, postfix in [("start axis", "start axis"), ("autofocus", "autofocus"), ("dremel", "dremel+matching")]:
        assert label in no_air[step] and postfix in no_air[step], (step, no_air[step])
    everything = "".join(no_air.values()) + capsys.readouterr().err
    assert "motion: motion" not in everything  # the slab path's name "motion" is not repeated
    assert "11/11" in everything  # open beam, start axis, autofocus, then Dremel's 3 + 4 refinement stages


def test_quiet_motion_estimate_prints_nothing(store, no_air, capsys):
    horizontal_motion(DataStore.open(store), PARAMS, np.zeros(K), False, "fbp_stack")
    assert not "".join(no_air.values()) + capsys.readouterr().err


def test_a_name_holding_other_slices_names_the_stack_command(store, capsys, monkeypatch):
    data = DataStore.open(store, mode="r+")
    data.prepare_reconstruction("fbp_stack", {"method": "fbp"}, shifts=True)
    data.write_reconstruction("fbp_stack", 0, np.zeros((L, L), np.float32), np.zeros(K, np.float32))
    monkeypatch.setattr(stack_batch, "_estimate", lambda *a: pytest.fail("estimated before the refusal"))
    with pytest.raises(StoreError, match=r"differs in: .*method.*nanoct stack \.\.\. --name fbp_stack --overwrite"):
        reconstruct_stack(store, method="dremel", name="fbp_stack", workers=0, progress=False)
    assert run(["stack", str(store), "--method", "dremel", "--name", "fbp_stack", "-w", "0", "-q"]) == 2
    err = capsys.readouterr().err
    assert "nanoct stack ... --name fbp_stack --overwrite" in err and "--name NEW_NAME" in err
    assert "nanoct reconstruct" not in err
    assert DataStore.open(store).reconstruction_done("fbp_stack")[0]  # nothing replaced


def test_the_centroid_path_counts_its_two_stages(store, capsys, monkeypatch):
    monkeypatch.setattr(stack_batch, "remove_air", lambda sinos, zero_air=False: (np.asarray(sinos), True))
    _, info = horizontal_motion(DataStore.open(store), {**PARAMS, "center": 0.5}, np.zeros(K), True, "fbp_stack")
    err = capsys.readouterr().err
    assert info["horizontal_method"] == "centroid" and "2/2" in err and "centroids and axis" in err
