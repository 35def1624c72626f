"""Every registered reader against one contract, on a small file of its format (``scan_files.WRITERS``).

Round trip (the frames, flats and darks as written, the rows and columns asked for), the angles, the
pixel size where the format stores one, a truncated file refused in one line naming it, and a link
outside the scan's folder refused unless allowed (the readers whose files can link). The registry
gives ``--format``'s help and the docs' table of formats.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from nanoct.cli import run
from nanoct.core.errors import NanoctError
from nanoct.io import readers
from nanoct.io.readers import READERS, Reader, ReadRequest, detect_format, register
from nanoct.io.scanio import ReaderOptions, read_scan
from scan_files import WRITERS, ScanData

K, R, L = 12, 3, 10
DOCS = Path(__file__).resolve().parents[2] / "docs" / "measured_data.md"


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(5)
    flats = rng.uniform(900, 1100, (2, R, L)).astype(np.float32)
    darks = rng.uniform(5, 10, (2, R, L)).astype(np.float32)
    line = rng.uniform(0.1, 2.0, (K, R, L))
    projections = ((flats.mean(0) - darks.mean(0)) * np.exp(-line) + darks.mean(0)).astype(np.float32)
    degrees = np.sort(rng.uniform(0, 180, K))
    return ScanData(projections, flats, darks, degrees)


def _written(name: str, tmp_path: Path, data: ScanData):
    folder = tmp_path / "scan"
    folder.mkdir()
    return WRITERS[name](folder, data)


def test_every_registered_reader_has_a_writer_and_says_what_it_takes():
    assert set(WRITERS) == set(READERS)
    for reader in READERS.values():
        assert reader.follows_links == ("allow" in reader.takes), reader
        assert reader.extensions and all(e == e.lower() and e.startswith(".") for e in reader.extensions), reader
        assert reader.title and reader.recognised_by, reader


@pytest.mark.parametrize("name", READERS)
def test_a_reader_reads_back_what_was_written(name, tmp_path, data):
    sample = _written(name, tmp_path, data)
    if sample.recognised:
        assert detect_format(sample.path) == name
    scan = read_scan(sample.path, **sample.read_kwargs())
    np.testing.assert_array_equal(scan.projections, sample.projections)
    for got, written in ((scan.flats, sample.flats), (scan.darks, sample.darks)):
        assert (got is None) == (written is None)
        if written is not None:
            np.testing.assert_array_equal(got, written)
    np.testing.assert_allclose(np.rad2deg(scan.angles), data.degrees, rtol=0, atol=1e-9)
    assert scan.source["format"] == name and scan.source["file"] == str(sample.path)
    assert scan.source["detector_shape"] == [R, L]
    if sample.pixel_size is None:
        assert "raw_pixel_size_m" not in scan.source
    else:
        assert scan.source["raw_pixel_size_m"] == pytest.approx(list(sample.pixel_size), rel=1e-6)
    part = read_scan(sample.path, rows=slice(1, 3), crop=(2, 7), **sample.read_kwargs())
    np.testing.assert_array_equal(part.projections, sample.projections[:, 1:3, 2:7])
    assert part.source["detector_shape"] == [R, L]
    # the reader itself, asked as read_scan asks it (the angles from the file where it has them)
    given = None if sample.angles_file is None else np.deg2rad(data.degrees)
    request = ReadRequest(angles=given, flats=sample.flat_file, darks=sample.dark_file, options=sample.options)
    direct = READERS[name].read(sample.path, request)
    np.testing.assert_array_equal(direct.projections, scan.projections)


@pytest.mark.parametrize("name", READERS)
def test_a_truncated_file_is_refused_in_one_line_naming_it(name, tmp_path, data):
    sample = _written(name, tmp_path, data)
    payload = sample.payload.read_bytes()
    sample.payload.write_bytes(payload[: len(payload) // 2])
    with pytest.raises(NanoctError) as refused:
        read_scan(sample.path, **sample.read_kwargs())
    message = str(refused.value)
    assert "\n" not in message and sample.payload.name in message, message


@pytest.mark.parametrize("name", [n for n, r in READERS.items() if r.follows_links])
def test_a_link_outside_the_scans_folder_is_refused_unless_allowed(name, tmp_path, data):
    sample = _written(name, tmp_path, data)
    outside = tmp_path / "elsewhere" / "frames.h5"
    outside.parent.mkdir()
    with h5py.File(sample.path, "a") as f:
        frames = f[sample.frames][()]
        del f[sample.frames]
        f[sample.frames] = h5py.ExternalLink(os.path.relpath(outside, sample.path.parent), "/frames")
    with h5py.File(outside, "w") as f:
        f["frames"] = frames
    with pytest.raises(NanoctError, match="outside the scan's folder.*--allow-outside") as refused:
        read_scan(sample.path, **sample.read_kwargs())
    assert "\n" not in str(refused.value)
    allowed = ReaderOptions(**{**sample.options.__dict__, "allow": (str(outside.parent),)})
    scan = read_scan(sample.path, **{**sample.read_kwargs(), "options": allowed})
    np.testing.assert_array_equal(scan.projections, sample.projections)


def test_format_help_lists_the_registry(capsys):
    assert run(["import", "--help"]) == 0
    assert f"{' | '.join(READERS)} (default: from the file)." in " ".join(capsys.readouterr().out.split())


def test_the_docs_table_of_formats_is_the_registry():
    """One row per reader, in the registry's order: ``--format``, what it is, its files, how it is recognised."""
    lines = DOCS.read_text().splitlines()
    header = "| `--format` | what it is | files | recognised by |"
    rows = []
    for line in lines[lines.index(header) + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(line)
    expected = [
        f"| `{r.name}` | {r.title} | {' '.join(f'`{e}`' for e in r.extensions)} | {r.recognised_by} |"
        for r in READERS.values()
    ]
    assert rows == expected, "\n".join(expected)


class _Plain(Reader):
    name, title, extensions, recognised_by, rank = "plain", "plain text", (".plain",), "the extension", 45

    def read(self, path, request):  # pragma: no cover - never read
        raise NotImplementedError


def test_register_keeps_the_rank_order_and_refuses_a_name_twice(monkeypatch, tmp_path):
    monkeypatch.setattr(readers, "READERS", dict(READERS))
    register(_Plain())
    names = list(readers.READERS)
    assert names.index("tiff") < names.index("plain") < names.index("npy")
    with pytest.raises(ValueError, match="'plain' is registered already"):
        register(_Plain())
    (tmp_path / "a.plain").write_text("")
    assert detect_format(tmp_path / "a.plain") == "plain"
    (tmp_path / "a.unknown").write_text("")
    with pytest.raises(NanoctError, match=re.escape("pass --format (nxtomo, diamond") + ".*tiff, plain, npy, mrc"):
        detect_format(tmp_path / "a.unknown")
