"""The self-contained HTML report: well-formed, tables present, images embedded, nothing external."""

from __future__ import annotations

import base64
import shutil
from html.parser import HTMLParser

import numpy as np
import pytest
from matplotlib.image import imsave

from nanoct.core.errors import NanoctError
from nanoct.evaluation.conclusions import format_conclusions, paper_conclusions
from nanoct.evaluation.paper import format_comparison
from nanoct.study.report_html import markdown_to_html, write_html_report

_VOID = {"img", "meta", "br", "hr", "link", "input"}


class _Checker(HTMLParser):
    """Records tags and attributes, and every nesting error."""

    def __init__(self):
        super().__init__()
        self.stack, self.errors, self.tags, self.text = [], [], [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        if tag not in _VOID:
            self.stack.append(tag)

    def handle_startendtag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_endtag(self, tag):
        if not self.stack or self.stack.pop() != tag:
            self.errors.append(f"unexpected </{tag}>")

    def handle_data(self, data):
        self.text.append(data)


def parse(document):
    checker = _Checker()
    checker.feed(document)
    checker.close()
    assert checker.errors == [] and checker.stack == [], (checker.errors, checker.stack)
    return checker


def report_dir(tmp_path):
    imsave(tmp_path / "figure one.png", np.arange(64, dtype=float).reshape(8, 8))
    imsave(tmp_path / "b.png", np.eye(5))
    results = {"fbp": {"psnr_mean": 28.0, "psnr_std": 1.0, "ssim_mean": 0.6, "ssim_std": 0.01, "n": 20}}
    text = "\n".join(
        [
            "# nanoct study: tiny",
            "",
            "Some *text* with <script>alert(1)</script> and a [link](other.md).",
            "",
            format_comparison(results, "fan", "Perturbed fan beam"),
            "## Conclusions",
            "",
            format_conclusions(paper_conclusions("fan")),
            "## Figure",
            "",
            "![First reconstructions](figure%20one.png)",
            "",
            "![second](b.png)",
        ]
    )
    (tmp_path / "report.md").write_text(text, encoding="utf-8")
    return tmp_path


def test_html_report_is_self_contained(tmp_path):
    path = write_html_report(report_dir(tmp_path) / "report.md")
    assert path == tmp_path / "report.html"
    document = path.read_text(encoding="utf-8")
    assert document.startswith("<!DOCTYPE html>")
    doc = parse(document)
    tags = [t for t, _ in doc.tags]
    assert tags.count("table") == 2 and tags.count("img") == 2
    table_lines = [line for line in (tmp_path / "report.md").read_text().splitlines() if line.startswith("|")]
    assert tags.count("tr") == len(table_lines) - 2 > 20  # every row of both tables (not the separator lines)
    images = [a for t, a in doc.tags if t == "img"]
    for attrs, name in zip(images, ("figure one.png", "b.png")):
        prefix = "data:image/png;base64,"
        assert attrs["src"].startswith(prefix)
        assert base64.b64decode(attrs["src"][len(prefix) :]) == (tmp_path / name).read_bytes()
    assert images[0]["alt"] == "First reconstructions"
    for _, attrs in doc.tags:  # nothing loaded from elsewhere
        for key in ("src", "href"):
            value = attrs.get(key, "")
            assert "://" not in value and not value.startswith("//"), (key, value)
    assert "script" not in tags and "<script>alert(1)</script>" in "".join(doc.text)  # escaped, shown as text
    assert dict(doc.tags)["title"] == {} and "nanoct study: tiny" in "".join(doc.text)
    # moved elsewhere without its figures, the HTML still has them
    moved = tmp_path.parent / "moved.html"
    shutil.copy(path, moved)
    shutil.rmtree(tmp_path)
    assert moved.read_text(encoding="utf-8") == document


def test_missing_and_external_images(tmp_path):
    with pytest.raises(NanoctError, match="not found"):
        markdown_to_html("![x](missing.png)", tmp_path)
    with pytest.raises(NanoctError, match="external image"):
        markdown_to_html("![x](https://example.org/a.png)", tmp_path)
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(NanoctError, match="not one"):
        markdown_to_html("![x](notes.txt)", tmp_path)
    with pytest.raises(NanoctError, match="no Markdown report"):
        write_html_report(tmp_path / "report.md")
    assert not (tmp_path / "report.html").exists()


def test_title():
    assert "<title>My &amp; title</title>" in markdown_to_html("text", title="My & title")
    assert "<title>nanoct report</title>" in markdown_to_html("just text")
    assert "<title>Heading</title>" in markdown_to_html("para\n\n## Heading\n")
