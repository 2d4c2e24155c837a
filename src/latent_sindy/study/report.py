"""A self-contained HTML report: tables, figures, GIFs and text in one file, no server needed.

Images are embedded as base64 data URIs, styles inline, no scripts and no external links, so
the file can be mailed, archived or opened from disk as it is. The page never scrolls
sideways: a table wider than the page scrolls inside its own box.

    from latent_sindy.study.report import Report
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
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 1em auto; padding: 0 1em;
       color: #222; line-height: 1.45; }
h1 { font-size: 1.5em; margin: 0 0 .4em; border-bottom: 2px solid #ccc; padding-bottom: .2em; }
h2 { margin-top: 2em; border-bottom: 1px solid #ddd; }
.scroll { overflow-x: auto; margin: 1em 0; }
table { border-collapse: collapse; font-size: .92em; }
th, td { border: 1px solid #ccc; padding: .3em .6em; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
table.overview { font-size: .8em; line-height: 1.25; }
table.overview th, table.overview td { padding: .15em .45em; }
table.overview td:nth-child(-n+4), table.overview th:nth-child(-n+4) { text-align: left; }
table.overview td { white-space: nowrap; } table.overview td:nth-child(2) { white-space: normal; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figure.overview { margin: .4em 0; }
figcaption { font-size: .9em; color: #555; }
.note { font-size: .85em; color: #444; }
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

    def paragraph(self, text: str, cls: str | None = None) -> Report:
        self._parts.append(f"<p{_cls(cls)}>{html.escape(text)}</p>")
        return self

    def preformatted(self, text: str) -> Report:
        self._parts.append(f"<pre>{html.escape(text)}</pre>")
        return self

    def table(self, header: Sequence[str], rows: Sequence[Sequence[object]],
              caption: str | None = None, cls: str | None = None) -> Report:
        """A table in its own box, which scrolls sideways when the table is wider than the
        page (the page itself never does)."""
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
            for row in rows)
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        self._parts.append(f'<div class="scroll"><table{_cls(cls)}>{cap}<thead><tr>{head}</tr>'
                           f"</thead><tbody>{body}</tbody></table></div>")
        return self

    def image(self, path: str | os.PathLike, caption: str = "",
              cls: str | None = None) -> Report:
        self._parts.append(f"<figure{_cls(cls)}>{_img(path, caption)}"
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


def _cls(cls: str | None) -> str:
    return f' class="{html.escape(cls)}"' if cls else ""


def _img(path: str | os.PathLike, alt: str) -> str:
    path = Path(path)
    mime = _MIME.get(path.suffix.lower())
    if mime is None:
        raise ValueError(f"{path}: cannot embed {path.suffix!r} images; use PNG, GIF or JPEG")
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img src="data:{mime};base64,{data}" alt="{html.escape(alt)}">'
