"""Training infrastructure: loss goes down, checkpoints and log, resume after a kill, DDP on CPU."""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset
from nanoct.learn.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint
from nanoct.learn.data import ReconDataset
from nanoct.learn.models import build_model
from nanoct.learn.train import TrainConfig, cosine_lr, model_arguments, train
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset
from nanoct.sim.matched import generate_like, plan_matched
from scan_like import scan_store

SMALL = {"channels": [4, 4, 8, 8, 16]}
FAST = dict(batch_size=2, model_kwargs=SMALL)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """12 tiny-parallel samples (6 train, 3 val, 3 test) with FBP of all and a partial input."""
    path = tmp_path_factory.mktemp("learn") / "tiny"
    generate_dataset(
        path, get_preset("tiny-parallel"), 12, seed=5, workers=0, progress=False, split_fractions=(0.5, 0.25, 0.25)
    )
    reconstruct_dataset(path, "fbp", workers=0, progress=False)
    reconstruct_dataset(path, "fbp", name="partial", split="test", workers=0, progress=False)
    return path


def _log(run: Path) -> list[dict[str, str]]:
    with open(run / "log.csv") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_dataset(store):
    ds = ReconDataset(store, "fbp", "train")
    assert len(ds) == 6 and ds.in_memory and ds.image_size == 63
    x_tilde, x = ds[0]
    assert x_tilde.shape == x.shape == (1, 63, 63) and x_tilde.dtype == x.dtype == torch.float32
    lazy = ReconDataset(store, "fbp", "train", in_memory=False)
    assert not lazy.in_memory
    for a, b in zip(lazy[5], ds[5]):
        assert torch.equal(a, b)


def test_dataset_errors(store, tmp_path):
    with pytest.raises(NanoctError, match="no reconstruction 'dremel'.*nanoct reconstruct"):
        ReconDataset(store, "dremel", "train")
    with pytest.raises(NanoctError, match="missing 6 of the 6 train"):
        ReconDataset(store, "partial", "train")
    assert len(ReconDataset(store, "partial", "test")) == 3
    with pytest.raises(NanoctError, match="unknown"):
        ReconDataset(store, "fbp", "training")
    no_val = tmp_path / "noval"
    generate_dataset(no_val, get_preset("tiny-parallel"), 4, workers=0, progress=False, split_fractions=(1.0, 0.0, 0.0))
    reconstruct_dataset(no_val, "fbp", workers=0, progress=False)
    with pytest.raises(NanoctError, match="val split .* is empty"):
        ReconDataset(no_val, "fbp", "val")


def test_dataset_limit_takes_the_first_samples_of_the_split(store):
    whole = ReconDataset(store, "fbp", "train")
    first = ReconDataset(store, "fbp", "train", limit=4)
    assert len(first) == 4 and list(first.indices) == list(whole.indices[:4])
    assert torch.equal(first[3][0], whole[3][0])
    for bad in (0, 7):
        with pytest.raises(NanoctError, match=f"limit {bad} must be between 1 and the 6 samples of the train split"):
            ReconDataset(store, "fbp", "train", limit=bad)


def test_n_train_is_part_of_the_request(store, tmp_path):
    run = tmp_path / "run"
    train(store, run, TrainConfig("unet", "fbp", epochs=1, n_train=2, **FAST), progress=False)
    config = json.loads((run / "config.json").read_text())
    assert config["data"]["train"] == 2 and int(_log(run)[-1]["steps"]) == 1  # 2 images, batch 2: one step
    with pytest.raises(NanoctError, match="other settings.*data"):
        train(store, run, TrainConfig("unet", "fbp", epochs=2, n_train=4, **FAST), progress=False)


def test_the_epoch_bar_ends_where_max_steps_stops_the_run(store, tmp_path, capsys):
    """--max-steps ends the run inside epoch 1 of 3: the bar shows that epoch done and says why it stopped."""
    run = train(store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=3, max_steps=1, **FAST))
    assert [int(r["epoch"]) for r in _log(run)] == [1]
    bar = capsys.readouterr().err.split("\r")[-1]
    assert "stopped at --max-steps 1" in bar and "1/3" in bar


@pytest.mark.slow
def test_training_lowers_loss_and_writes_run(store, tmp_path):
    run = train(store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=8, lr=3e-3, **FAST))
    assert {p.name for p in run.iterdir()} >= {"last.pt", "best.pt", "log.csv", "config.json"}
    rows = _log(run)
    assert [int(r["epoch"]) for r in rows] == list(range(1, 9))
    assert {"train_loss", "val_loss", "train_mse", "val_mse", "lr", "seconds"} <= set(rows[0])
    train_losses = [float(r["train_loss"]) for r in rows]
    assert train_losses[-1] < 0.8 * train_losses[0]
    val = [float(r["val_loss"]) for r in rows]
    best = load_checkpoint(run / "best.pt", model_name="unet", image_size=63)
    assert best["epoch"] == 1 + val.index(min(val)) and best["best_val_loss"] == pytest.approx(min(val))
    last = load_checkpoint(run / "last.pt")
    assert last["epoch"] == 8 and last["step"] == 8 * 3 and last["input"] == "fbp"
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["model"] == "unet" and cfg["hparams"]["channels"] == SMALL["channels"] and cfg["batch_size"] == 2
    assert isinstance(model_from_checkpoint(best), torch.nn.Module)


def test_a_network_on_a_set_matched_to_a_scan_takes_its_target_noise_and_error_relative(store, tmp_path):
    scan = scan_store(tmp_path / "scan")
    like = generate_like(tmp_path / "matched", plan_matched(scan.path, binning=2), 4, seed=1,
                         split_fractions=(0.5, 0.5, 0.0), workers=0, progress=False)  # fmt: skip
    tiny = {"n_scales": 3, "blocks_per_scale": 1, "cond_channels": [4, 4, 8]}
    assert model_arguments(like.path, "ciunet-res", tiny) == {**tiny, "target_noise_scale": "range"}
    assert model_arguments(like.path, "cinn") == {"target_noise_scale": "range"}
    asked = {**tiny, "target_noise_scale": "absolute"}
    assert model_arguments(like.path, "ciunet-res", asked) == asked  # --param wins
    assert model_arguments(like.path, "unet", SMALL) == {**SMALL, "loss_scale": "range"}  # its MSE, relative
    assert model_arguments(like.path, "unet", {"loss_scale": "absolute"}) == {"loss_scale": "absolute"}
    assert model_arguments(store, "unet", SMALL) == SMALL
    assert model_arguments(store, "ciunet-res") == {}  # a simulated set keeps the paper's absolute noise
    assert model_arguments(tmp_path / "missing", "ciunet-res") == {}  # reported where the data are read
    reconstruct_dataset(like.path, "fbp", workers=0, progress=False)
    config = TrainConfig("ciunet-res", "fbp", epochs=1, batch_size=2, model_kwargs=tiny)
    run = train(like.path, tmp_path / "run", config)
    assert json.loads((run / "config.json").read_text())["hparams"]["target_noise_scale"] == "range"
    assert model_from_checkpoint(load_checkpoint(run / "last.pt")).target_noise_scale == "range"


@pytest.mark.slow
def test_flow_run_logs_the_validation_nll_per_epoch(store, tmp_path):
    tiny = dict(n_scales=3, blocks_per_scale=1, fc_dim=8, fc_blocks=1, cond_channels=4, cond_width=4, fc_cond_dim=8)
    kwargs = {**tiny, "conditional_scale": True}
    run = train(
        store,
        tmp_path / "flow",
        TrainConfig("cinn-res", "fbp", epochs=2, lr=1e-3, batch_size=2, model_kwargs=kwargs),
        progress=False,
    )
    rows = _log(run)
    assert [int(r["epoch"]) for r in rows] == [1, 2]
    for r in rows:
        assert float(r["val_loss"]) == pytest.approx(float(r["val_nll_bpd"]))  # the flows' loss is the NLL
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["hparams"]["conditional_scale"] is True and cfg["hparams"]["coupling"] == "additive"


@pytest.mark.slow
@pytest.mark.parametrize("sched", ["plateau", "cosine"])
def test_resume_after_kill_matches_uninterrupted(store, tmp_path, sched):
    ref = train(store, tmp_path / "ref", TrainConfig("unet", "fbp", epochs=3, scheduler=sched, **FAST))

    calls: list[int] = []

    def killer(epoch, row):
        calls.append(epoch)
        if epoch == 2:
            raise KeyboardInterrupt("simulated kill after epoch 2")

    with pytest.raises(KeyboardInterrupt):
        train(
            store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=3, scheduler=sched, **FAST), on_epoch_end=killer
        )
    assert load_checkpoint(tmp_path / "run" / "last.pt")["epoch"] == 2
    run = train(
        store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=3, scheduler=sched, **FAST), on_epoch_end=killer
    )
    assert calls == [1, 2, 3]  # epochs 1 and 2 were not repeated
    assert [int(r["epoch"]) for r in _log(run)] == [1, 2, 3]
    a, b = load_checkpoint(ref / "last.pt"), load_checkpoint(run / "last.pt")
    assert a["step"] == b["step"] == 9
    for k, v in a["model_state"].items():
        assert torch.equal(v, b["model_state"][k]), k
    assert [r["val_loss"] for r in _log(ref)] == [r["val_loss"] for r in _log(run)]
    # finished: nothing to do; more epochs extend the run
    mtime = (run / "last.pt").stat().st_mtime_ns
    train(store, run, TrainConfig("unet", "fbp", epochs=3, scheduler=sched, **FAST))
    assert (run / "last.pt").stat().st_mtime_ns == mtime
    train(store, run, TrainConfig("unet", "fbp", epochs=4, scheduler=sched, **FAST))
    assert [int(r["epoch"]) for r in _log(run)] == [1, 2, 3, 4]


def test_cosine_lr_matches_torch_scheduler():
    """The closed form equals CosineAnnealingLR(T_max=epochs, eta_min=lr/10) stepped per epoch."""
    lr, epochs = 1e-3, 7
    opt = torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=lr)
    ref = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs, eta_min=lr / 10)
    for epoch in range(1, epochs + 1):
        assert cosine_lr(lr, epoch, epochs) == pytest.approx(opt.param_groups[0]["lr"], rel=1e-12)
        opt.step()
        ref.step()
    assert cosine_lr(lr, 1, epochs) == lr and cosine_lr(lr, epochs + 1, epochs) == pytest.approx(lr / 10)


@pytest.mark.slow
def test_unet_default_schedule_is_cosine(store, tmp_path):
    run = train(store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=4, **FAST))
    assert json.loads((run / "config.json").read_text())["scheduler"] == "cosine"
    lrs = [float(r["lr"]) for r in _log(run)]
    assert lrs == pytest.approx([cosine_lr(1e-3, e, 4) for e in (1, 2, 3, 4)])
    assert lrs[0] == pytest.approx(1e-3) and all(a > b for a, b in zip(lrs, lrs[1:]))


@pytest.mark.slow
def test_resume_after_sigkill(store, tmp_path):
    """A real kill (SIGKILL) of the training process; the rerun continues at the next epoch."""
    run = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "nanoct",
        "train",
        str(store),
        "--model",
        "unet",
        "--input",
        "fbp",
        "--out",
        str(run),
        "--batch-size",
        "2",
        "--param",
        f"channels={json.dumps(SMALL['channels'])}",
        "--quiet",
    ]
    proc = subprocess.Popen([*cmd, "--epochs", "10000"], stderr=subprocess.PIPE)
    try:
        while not (run / "log.csv").exists():  # the first epoch, however long it takes (pytest-timeout bounds it)
            assert proc.poll() is None, proc.stderr.read().decode()
            time.sleep(0.05)
        time.sleep(0.3)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    done = load_checkpoint(run / "last.pt")["epoch"]
    assert 1 <= done < 10000
    subprocess.run([*cmd, "--epochs", str(done + 2)], check=True)
    assert [int(r["epoch"]) for r in _log(run)] == list(range(1, done + 3))
    assert not [p for p in run.iterdir() if p.name.startswith(".")]  # no temporary files left


@pytest.mark.slow
def test_kill_during_checkpoint_write_leaves_no_temporary(store, tmp_path, monkeypatch):
    """A kill between writing the temporary checkpoint and renaming it: the old one stays, the rerun cleans up."""
    run = train(store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=1, **FAST))
    import nanoct.io.fileio

    def killed_replace(src, dst):
        raise KeyboardInterrupt("simulated kill before the rename")

    monkeypatch.setattr(nanoct.io.fileio.os, "replace", killed_replace)
    monkeypatch.setattr(Path, "unlink", lambda self, missing_ok=False: None)  # the kill also skips the cleanup
    with pytest.raises(KeyboardInterrupt):
        train(store, run, TrainConfig("unet", "fbp", epochs=2, **FAST))
    monkeypatch.undo()
    stale = [p for p in run.iterdir() if p.name.startswith(".")]
    assert stale and load_checkpoint(run / "last.pt")["epoch"] == 1  # the old checkpoint is intact
    train(store, run, TrainConfig("unet", "fbp", epochs=2, **FAST))
    assert load_checkpoint(run / "last.pt")["epoch"] == 2
    assert not [p for p in run.iterdir() if p.name.startswith(".")]


@pytest.mark.slow
def test_mismatched_request_refused(store, tmp_path):
    run = train(store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=1, **FAST))
    with pytest.raises(NanoctError, match="differs in: lr"):
        train(store, run, TrainConfig("unet", "fbp", epochs=2, lr=1e-4, **FAST))
    with pytest.raises(NanoctError, match="architecture|hparams"):
        train(
            store,
            run,
            TrainConfig("unet", "fbp", epochs=2, batch_size=2, model_kwargs={"channels": [4, 4, 8, 8, 8]}),
            progress=False,
        )
    reconstruct_dataset(store, "fbp", name="fbp_copy", workers=0, progress=False)
    with pytest.raises(NanoctError, match="differs in: input"):
        train(store, run, TrainConfig("unet", "fbp_copy", epochs=2, **FAST))


def test_corrupt_and_mismatched_checkpoints(store, tmp_path):
    model = build_model("unet", **SMALL)
    path = tmp_path / "c.pt"
    save_checkpoint(path, model=model, input_name="fbp", image_size=63, epoch=1)
    loaded = load_checkpoint(path, model_name="unet", image_size=63, hparams=model.hparams)
    assert loaded["epoch"] == 1 and loaded["file_sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    with pytest.raises(NanoctError, match="holds a 'unet' model, not 'cinn'"):
        load_checkpoint(path, model_name="cinn")
    with pytest.raises(NanoctError, match="63x63"):
        load_checkpoint(path, image_size=127)
    with pytest.raises(NanoctError, match="architecture"):
        load_checkpoint(path, hparams={**model.hparams, "channels": [8, 8, 8, 8, 8]})
    with pytest.raises(NanoctError, match="does not exist"):
        load_checkpoint(tmp_path / "nope.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(path.read_bytes()[:100])
    with pytest.raises(NanoctError, match="corrupt"):
        load_checkpoint(bad)
    ckpt = torch.load(path, weights_only=True)
    ckpt["hparams"] = {**ckpt["hparams"], "channels": [8, 8, 8, 8, 8]}
    with pytest.raises(NanoctError, match="do not fit"):
        model_from_checkpoint(ckpt)
    # a run whose last.pt is damaged is refused with a clear message
    run = tmp_path / "run"
    run.mkdir()
    (run / "last.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(NanoctError, match="corrupt"):
        train(store, run, TrainConfig("unet", "fbp", epochs=1, **FAST))
    with pytest.raises(NanoctError, match="no reconstruction 'kaczmarz'"):
        train(store, tmp_path / "run2", TrainConfig("unet", "kaczmarz", epochs=1, **FAST))


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs a POSIX system")
def test_ddp_two_processes_gloo(store, tmp_path):
    run = tmp_path / "ddp"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "CUDA_VISIBLE_DEVICES": ""}
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node",
        "2",
        "-m",
        "nanoct",
        "train",
        str(store),
        "--model",
        "unet",
        "--input",
        "fbp",
        "--out",
        str(run),
        "--epochs",
        "5",
        "--batch-size",
        "2",
        "--max-steps",
        "3",
        "--param",
        f"channels={json.dumps(SMALL['channels'])}",
        "--quiet",
    ]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, res.stderr[-3000:]
    last = load_checkpoint(run / "last.pt")
    assert last["step"] == 3 and last["epoch"] == 1 and last["config"]["world_size"] == 2
    assert sorted(p.name for p in run.iterdir()) == ["best.pt", "config.json", "last.pt", "log.csv"]
    assert len(_log(run)) == 1


@pytest.mark.slow
def test_bf16_precision_trains_records_and_is_part_of_the_request(store, tmp_path):
    run = train(store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=2, precision="bf16", **FAST))
    config = json.loads((run / "config.json").read_text())
    assert config["precision"] == "bf16"
    rows = _log(run)
    assert len(rows) == 2 and all(math.isfinite(float(r["val_loss"])) for r in rows)
    with pytest.raises(NanoctError, match="differs in: precision"):
        train(store, run, TrainConfig("unet", "fbp", epochs=3, **FAST))
    with pytest.raises(NanoctError, match="precision 'fp16' is unknown"):
        train(store, tmp_path / "other", TrainConfig("unet", "fbp", epochs=1, precision="fp16", **FAST))
    assert not (tmp_path / "other").exists()


@pytest.mark.slow
def test_run_recorded_before_precision_existed_resumes_as_fp32(store, tmp_path):
    run = train(store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=1, **FAST))
    ckpt = torch.load(run / "last.pt", weights_only=False)
    del ckpt["config"]["precision"]  # a run directory of an earlier version
    torch.save(ckpt, run / "last.pt")
    train(store, run, TrainConfig("unet", "fbp", epochs=2, **FAST))
    assert [int(r["epoch"]) for r in _log(run)] == [1, 2]
    with pytest.raises(NanoctError, match="differs in: precision"):
        train(store, run, TrainConfig("unet", "fbp", epochs=3, precision="bf16", **FAST))


def test_auto_precision_is_bf16_only_where_the_device_runs_it_natively(monkeypatch):
    from nanoct.learn import train as train_module
    from nanoct.learn.train import check_precision, native_bf16, resolve_precision

    for native, taken in ((True, "bf16"), (False, "fp32")):
        monkeypatch.setattr(train_module, "native_bf16", lambda device, native=native: native)
        assert resolve_precision("auto", "cpu") == taken
        assert (resolve_precision("fp32", "cpu"), resolve_precision("bf16", "cpu")) == ("fp32", "bf16")
    with pytest.raises(NanoctError, match="precision 'fp16' is unknown; use one of fp32, bf16, auto"):
        resolve_precision("fp16", "cpu")
    with pytest.raises(NanoctError, match="^--precision 'half' is unknown"):  # the message names the flag given
        check_precision("half", "--precision")
    assert [check_precision(p) for p in ("fp32", "bf16", "auto")] == ["fp32", "bf16", "auto"]
    monkeypatch.undo()
    # oneDNN has bfloat16 kernels on AVX512 (and AMX) CPUs, not on AVX2-only ones
    capability = torch.backends.cpu.get_cpu_capability()
    if capability in ("AVX2", "AVX512"):
        assert native_bf16("cpu") == (capability == "AVX512")
    assert native_bf16("meta") is False


def test_auto_precision_run_records_what_it_took_and_resumes(store, tmp_path, monkeypatch):
    from nanoct.learn import train as train_module

    monkeypatch.setattr(train_module, "native_bf16", lambda device: False)
    run = train(store, tmp_path / "run", TrainConfig("unet", "fbp", epochs=1, precision="auto", **FAST))
    assert json.loads((run / "config.json").read_text())["precision"] == "fp32"
    train(store, run, TrainConfig("unet", "fbp", epochs=2, precision="auto", **FAST))  # the same request
    train(store, run, TrainConfig("unet", "fbp", epochs=3, **FAST))  # fp32 given: the same as taken
    assert [int(r["epoch"]) for r in _log(run)] == [1, 2, 3]
    monkeypatch.setattr(train_module, "native_bf16", lambda device: True)  # the run moved to a bf16 machine
    with pytest.raises(NanoctError, match="differs in: precision"):
        train(store, run, TrainConfig("unet", "fbp", epochs=4, precision="auto", **FAST))


def _kept(env: dict[str, str]) -> dict[str, object]:
    """keep_freed_memory() in a fresh process with ``env`` added, and a UNet's weights after 3 float32 steps."""
    code = (
        "import json, sys, torch\n"
        "from nanoct.learn.models import build_model\n"
        "from nanoct.learn.train import keep_freed_memory\n"
        "kept = keep_freed_memory() if sys.argv[1] == '1' else None\n"
        "torch.set_num_threads(2); torch.manual_seed(0)\n"
        "m = build_model('unet', channels=[4, 4, 8, 8, 16]); opt = torch.optim.Adam(m.parameters(), lr=1e-3)\n"
        "x = torch.rand(4, 1, 63, 63); xt = x + 0.1 * torch.randn(x.shape)\n"
        "for _ in range(3):\n"
        "    opt.zero_grad(); loss, _ = m.loss(xt, x); loss.backward(); opt.step()\n"
        "print(json.dumps({'kept': kept, 'again': keep_freed_memory() if kept is not None else None,\n"
        "                  'weights': [p.detach().flatten().tolist() for p in m.parameters()]}))\n"
    )
    runs = {}
    for keep in ("0", "1"):
        out = subprocess.run(
            [sys.executable, "-c", code, keep], env=os.environ | env, capture_output=True, text=True, check=True
        )
        runs[keep] = json.loads(out.stdout.strip().splitlines()[-1])
    return runs


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_keeping_freed_memory_leaves_the_weights_bit_identical_and_yields_to_the_user():
    runs = _kept({})
    assert runs["1"]["kept"] is True and runs["1"]["again"] is True
    assert runs["1"]["weights"] == runs["0"]["weights"]  # the same bits
    assert _kept({"MALLOC_TRIM_THRESHOLD_": "1000000"})["1"]["kept"] is False  # the user's setting wins
