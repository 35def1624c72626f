"""A report's Markdown as one self-contained HTML file, readable offline.

The Markdown (headings, paragraphs, tables, emphasis, image links to files next to it) is
rendered with markdown-it-py (CommonMark plus tables; raw HTML in the Markdown is escaped,
not passed through), and every image is embedded as a base64 ``data:`` URI, so the one file
can be mailed or archived and opened in any browser without its figures beside it. Images
must be local files: a report that only renders online is refused.
"""

from __future__ import annotations

import base64
import html
import mimetypes
import os
from pathlib import Path
from typing import Any
from urllib.parse import unquote

from markdown_it import MarkdownIt

from ..core.errors import NanoctError
from ..io.fileio import atomic_write_text

__all__ = ["markdown_to_html", "write_html_report"]

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; max-width: 72rem; margin: 2rem auto;
       padding: 0 1rem; line-height: 1.45; color: #1b1b1b; }
table { border-collapse: collapse; margin: 1rem 0; font-size: 0.9rem; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid #c8c8c8; padding: 0.25rem 0.6rem; text-align: left; }
thead th { background: #dae8fc; }
tbody tr:nth-child(even) { background: #f6f8fa; }
img { max-width: 100%; height: auto; }
code { background: #f3f3f3; padding: 0 0.2rem; }
"""


def _data_uri(src: str, base_dir: Path) -> str:
    """The image file ``src`` (relative to ``base_dir``) as a base64 ``data:`` URI."""
    if src.startswith("data:"):
        return src
    if "://" in src or src.startswith("//"):
        raise NanoctError(
            f"the report links the external image {src!r}; a self-contained report needs local image files "
            "(save the figure next to the Markdown and link it by file name)"
        )
    path = base_dir / unquote(src)  # markdown-it percent-encodes links ("a b.png" -> "a%20b.png")
    if not path.is_file():
        raise NanoctError(f"image {src!r} of the report not found at {path}; write the figure before the HTML report")
    mime = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    if not mime.startswith("image/"):
        raise NanoctError(f"{src!r} is linked as an image but is not one (type {mime}); link PNG, JPEG, GIF or SVG")
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


def _renderer(base_dir: Path) -> MarkdownIt:
    md = MarkdownIt("commonmark", {"html": False}).enable("table")

    def image(self: Any, tokens: list, idx: int, options: Any, env: Any) -> str:
        token = tokens[idx]
        token.attrSet("src", _data_uri(str(token.attrGet("src")), base_dir))
        return self.image(tokens, idx, options, env)

    md.add_render_rule("image", image)
    return md


def markdown_to_html(text: str, base_dir: str | os.PathLike[str] = ".", title: str | None = None) -> str:
    """Render Markdown to a complete HTML document with its images embedded.

    Parameters
    ----------
    text : str
        Markdown (CommonMark with pipe tables).
    base_dir : path-like
        Directory the image links are relative to (the Markdown file's directory).
    title : str, optional
        The document's title; default the first heading's text, else "nanoct report".

    Returns
    -------
    str
        An HTML5 document with inline CSS and ``data:`` image URIs: no external references.

    Raises
    ------
    NanoctError
        If an image is external, missing, or not an image.
    """
    md = _renderer(Path(base_dir))
    body = md.render(text)
    if title is None:
        tokens = md.parse(text)
        heading = next((tokens[i + 1].content for i, t in enumerate(tokens) if t.type == "heading_open"), None)
        title = heading or "nanoct report"
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n{body}</body>\n</html>\n"
    )


def write_html_report(
    markdown_path: str | os.PathLike[str], html_path: str | os.PathLike[str] | None = None, title: str | None = None
) -> Path:
    """Write the self-contained HTML version of a Markdown report; returns its path.

    Parameters
    ----------
    markdown_path : path-like
        The Markdown report; its images are looked up relative to its directory.
    html_path : path-like, optional
        Output file (default: the Markdown's path with suffix ``.html``). Written atomically.
    title : str, optional
        See :func:`markdown_to_html`.

    Raises
    ------
    NanoctError
        If the Markdown file is missing or an image cannot be embedded (nothing is written).
    """
    md_path = Path(markdown_path)
    if not md_path.is_file():
        raise NanoctError(f"no Markdown report at {md_path}; run the study (or `nanoct evaluate`) first")
    out = Path(html_path) if html_path is not None else md_path.with_suffix(".html")
    document = markdown_to_html(md_path.read_text(encoding="utf-8"), md_path.parent, title)
    return atomic_write_text(out, document)
