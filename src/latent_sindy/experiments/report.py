"""A self-contained HTML report: tables, figures, GIFs and text in one file, no server needed.

Images are embedded as base64 data URIs, styles inline, no scripts and no external links, so
the file can be mailed, archived or opened from disk as it is.

    from latent_sindy.experiments.report import Report
    r = Report("latent-sindy study")
    r.heading("Table I")
    r.table(["model", "test loss"], [["SINDy 1", "0.061"], ["linear", "0.22"]])
    r.image("results/loss.png", "Training and validation loss")
    r.write("results/report.html")
"""

from __future__ import annotations

import base64
import html
import os
from collections.abc import Sequence
from pathlib import Path

from latent_sindy.atomic import write_atomic

_MIME = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".jpeg": "image/jpeg",
         ".svg": "image/svg+xml"}

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em;
       color: #222; line-height: 1.45; }
h1 { border-bottom: 2px solid #ccc; padding-bottom: .2em; }
h2 { margin-top: 2em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 1em 0; font-size: .92em; }
th, td { border: 1px solid #ccc; padding: .3em .6em; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { font-size: .9em; color: #555; }
pre { background: #f7f7f7; padding: .8em; overflow-x: auto; font-size: .85em; }
.gifs { display: flex; flex-wrap: wrap; gap: 1em; }
"""


class Report:
    """Builds the report block by block; :meth:`write` saves it atomically."""

    def __init__(self, title: str) -> None:
        self.title = title
        self._parts: list[str] = []

    def heading(self, text: str, level: int = 2) -> Report:
        self._parts.append(f"<h{level}>{html.escape(text)}</h{level}>")
        return self

    def paragraph(self, text: str) -> Report:
        self._parts.append(f"<p>{html.escape(text)}</p>")
        return self

    def preformatted(self, text: str) -> Report:
        self._parts.append(f"<pre>{html.escape(text)}</pre>")
        return self

    def table(self, header: Sequence[str], rows: Sequence[Sequence[object]],
              caption: str | None = None) -> Report:
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
            for row in rows)
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        self._parts.append(f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody>"
                           "</table>")
        return self

    def image(self, path: str | os.PathLike, caption: str = "") -> Report:
        self._parts.append(f"<figure>{_img(path, caption)}"
                           f"<figcaption>{html.escape(caption)}</figcaption></figure>")
        return self

    def gallery(self, items: Sequence[tuple[str | os.PathLike, str]]) -> Report:
        """Several images (e.g. GIFs) side by side, each with its caption."""
        figs = "".join(f"<figure>{_img(p, c)}<figcaption>{html.escape(c)}</figcaption></figure>"
                       for p, c in items)
        self._parts.append(f'<div class="gifs">{figs}</div>')
        return self

    def html(self) -> str:
        return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
                f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head>"
                f"<body><h1>{html.escape(self.title)}</h1>\n" + "\n".join(self._parts)
                + "\n</body></html>\n")

    def write(self, path: str | os.PathLike) -> Path:
        write_atomic(path, lambda f: f.write(self.html()), binary=False)
        return Path(path)


def _img(path: str | os.PathLike, alt: str) -> str:
    path = Path(path)
    mime = _MIME.get(path.suffix.lower())
    if mime is None:
        raise ValueError(f"{path}: cannot embed {path.suffix!r} images; use PNG, GIF or JPEG")
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img src="data:{mime};base64,{data}" alt="{html.escape(alt)}">'
