"""``nanoct generate --like``: plan, generation, resume and its errors (one line, status 2, nothing written)."""

from __future__ import annotations

import pytest

from nanoct.cli import run
from nanoct.io.store import DataStore
from scan_like import N_DET, scan_store


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    return scan_store(tmp_path_factory.mktemp("scan") / "scan")


def test_plan_prints_what_would_be_made_and_writes_nothing(scan, tmp_path, capsys):
    out = tmp_path / "matched"
    assert run(["generate", "--like", str(scan.path), "--bin", "2", "--n", "4", "--out", str(out), "--plan"]) == 0
    text = capsys.readouterr().out
    assert f"{N_DET // 2} detector pixels, image {N_DET // 2}x{N_DET // 2}" in text
    assert "noise " in text and "the paper's defaults" in text and "would make 4 samples" in text and "(new)" in text
    assert not out.exists()
    assert run(["generate", "--like", str(scan.path), "--bin", "2", "--n", "4", "--out", str(out), "--plan",
                "--hold-out", "0:2"]) == 0  # fmt: skip
    assert "1 held out" in capsys.readouterr().out and not out.exists()


def test_generate_like_then_resume_is_a_no_op(scan, tmp_path, capsys):
    out = tmp_path / "matched"
    argv = ["generate", "--like", str(scan.path), "--bin", "2", "--n", "4", "--out", str(out), "-w", "0", "-q"]
    assert run(argv) == 0
    assert "4/4 samples" in capsys.readouterr().out
    store = DataStore.open(out)
    assert store.meta["simulation"]["like"]["store"] == str(scan.path.resolve())
    stamp = {p: p.stat().st_mtime_ns for p in (out / "sinograms").rglob("*") if p.is_file()}
    assert run(argv) == 0
    assert {p: p.stat().st_mtime_ns for p in (out / "sinograms").rglob("*") if p.is_file()} == stamp
    assert run([*argv[:-3], "--plan"]) == 0
    assert "(4 already made)" in capsys.readouterr().out
    assert run([*argv[:-3], "--plan", "--seed", "9"]) == 0  # another seed: the run would stop
    assert "holds ANOTHER data set" in capsys.readouterr().out


def test_a_matched_set_resumes_after_the_scan_moved(scan, tmp_path, capsys):
    """The scan's path is not part of what makes the matched set the same one again; its measurements are."""
    import shutil

    moved = tmp_path / "moved"
    shutil.copytree(scan.path, moved)
    out = tmp_path / "matched"
    argv = ["--bin", "2", "--n", "4", "--out", str(out), "-w", "0", "-q"]
    assert run(["generate", "--like", str(scan.path), *argv]) == 0
    stamp = {p: p.stat().st_mtime_ns for p in (out / "sinograms").rglob("*") if p.is_file()}
    capsys.readouterr()
    assert run(["generate", "--like", str(moved), *argv[:-3], "--plan"]) == 0
    assert "(4 already made)" in capsys.readouterr().out
    assert run(["generate", "--like", str(moved), *argv]) == 0
    assert {p: p.stat().st_mtime_ns for p in (out / "sinograms").rglob("*") if p.is_file()} == stamp
    assert run(["generate", "--like", str(moved), *argv, "--seed", "9"]) == 2  # what differs is still refused
    assert "holds a different data set (differs in: seed)" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--bin", "3"], "--bin 3 does not divide the scan's detector width"),
        (["--mix", "1,x,1"], "--mix '1,x,1' must be three or four numbers"),
        (["--preset", "tiny-parallel"], "--preset cannot be combined with --like"),
        (["--noise-std", "0.1"], "--noise-std cannot be combined with --like"),
        (["--motion-from", "nope"], "--motion-from 'nope'"),
        (["--hold-out", "5:2"], "--hold-out '5:2': '5:2' is not a row"),
        (["--hold-out", "0:999"], "--hold-out row 998 is outside the scan"),
    ],
)
def test_bad_flags_with_like_are_one_error_line(scan, tmp_path, capsys, extra, message):
    out = tmp_path / "matched"
    assert run(["generate", "--like", str(scan.path), "--n", "4", "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1
    assert not out.exists()


def test_like_must_be_a_measured_scan(tiny_store, tmp_path, capsys):
    for like, message in ((tmp_path / "none", "no data set there"), (tiny_store.path, "not a measured scan")):
        assert run(["generate", "--like", str(like), "--n", "4", "--out", str(tmp_path / "o")]) == 2
        assert message in capsys.readouterr().err
    assert run(["generate", "--preset", "tiny-parallel", "--bin", "2", "--n", "4", "--out", str(tmp_path / "o")]) == 2
    assert "--bin needs --like" in capsys.readouterr().err
    assert (
        run(["generate", "--preset", "tiny-parallel", "--hold-out", "2", "--n", "4", "--out", str(tmp_path / "o")]) == 2
    )
    assert "--hold-out needs --like" in capsys.readouterr().err
    assert run(["generate", "--n", "4", "--out", str(tmp_path / "o")]) == 2
    assert "give --preset NAME" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
