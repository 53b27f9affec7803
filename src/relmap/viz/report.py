"""A small HTML report writer: headings, paragraphs, tables and figures, written to a folder.

Figures are rendered to PNG when added (so their matplotlib objects can be freed) and written
beside ``index.html`` when the report is written. Every file is written by relmap's one writer
(:mod:`relmap.io.atomic`: atomically, with the mode a new file gets), the PNGs first and
``index.html`` last, so a reader never sees a page that refers to a missing or half-written image.
"""

from __future__ import annotations

import html
import io
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from relmap.errors import ParameterError
from relmap.io.atomic import make_folder, write_bytes_atomic, write_text_atomic

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = ["Report"]

_CSS = """
body { font-family: system-ui, sans-serif; max-width: 62rem; margin: 2rem auto; padding: 0 1rem;
       line-height: 1.45; color: #222; }
h1 { font-size: 1.6rem; } h2 { margin-top: 2.5rem; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.8rem 0; font-size: 0.92rem; }
th, td { padding: 0.2rem 0.6rem; border-bottom: 1px solid #e3e3e3; text-align: right; }
th { background: #f4f4f4; } td:first-child, th:first-child { text-align: left; }
caption { caption-side: top; text-align: left; font-weight: 600; padding-bottom: 0.3rem; }
figure { margin: 1rem 0; } figure img { max-width: 100%; height: auto; }
figcaption { font-size: 0.92rem; color: #444; }
code, .expr { font-family: ui-monospace, monospace; background: #f6f6f6; padding: 0 0.2rem; }
.side { display: flex; gap: 1rem; flex-wrap: wrap; } .side > div { flex: 1 1 22rem; }
"""


class Report:
    """An HTML page built piece by piece; :meth:`write` puts it into a folder.

    Text given to :meth:`paragraph`, :meth:`table` and captions is escaped; ``code`` spans
    written as backticks (`` `A ⊕ B` ``) become ``<code>``.
    """

    def __init__(self, title: str) -> None:
        self.title = title
        self._body: list[str] = []
        self._images: dict[str, bytes] = {}

    @staticmethod
    def _text(text: str) -> str:
        return re.sub(r"`([^`]+)`", r"<code>\1</code>", html.escape(text))

    def heading(self, text: str, level: int = 2, *, anchor: str | None = None) -> None:
        """A section heading (``<h2>`` by default)."""
        ident = f' id="{html.escape(anchor)}"' if anchor else ""
        self._body.append(f"<h{level}{ident}>{self._text(text)}</h{level}>")

    def paragraph(self, text: str) -> None:
        """A paragraph of text (escaped; backticks give code)."""
        self._body.append(f"<p>{self._text(text)}</p>")

    def items(self, lines: Sequence[str]) -> None:
        """A bulleted list."""
        self._body.append("<ul>" + "".join(f"<li>{self._text(t)}</li>" for t in lines) + "</ul>")

    def table(
        self, header: Sequence[str], rows: Sequence[Sequence[object]], *, caption: str = ""
    ) -> None:
        """A table; cells are shown with ``str`` (format numbers before passing them)."""
        head = "".join(f"<th>{self._text(str(h))}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(f"<td>{self._text(str(c))}</td>" for c in row) + "</tr>"
            for row in rows
        )
        cap = f"<caption>{self._text(caption)}</caption>" if caption else ""
        self._body.append(
            f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
        )

    def figure(self, fig: Figure, name: str, caption: str, *, dpi: int = 100) -> str:
        """Render ``fig`` to ``name`` (a PNG file name, unique in the report) with a caption;
        returns the file name."""
        if not re.fullmatch(r"[A-Za-z0-9_.-]+\.png", name) or name in self._images:
            raise ParameterError(f"figure names must be unique *.png file names; got {name!r}")
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi)
        self._images[name] = buf.getvalue()
        self._body.append(
            f'<figure><img src="{html.escape(name)}" alt="{html.escape(caption)}">'
            f"<figcaption>{self._text(caption)}</figcaption></figure>"
        )
        return name

    def html(self) -> str:
        """The page's HTML text."""
        return (
            '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f"<title>{html.escape(self.title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
            f"<h1>{self._text(self.title)}</h1>\n" + "\n".join(self._body) + "\n</body>\n</html>\n"
        )

    @property
    def images(self) -> list[str]:
        """File names of the figures, in order."""
        return list(self._images)

    def write(self, folder: str | os.PathLike[str]) -> Path:
        """Write the figures and ``index.html`` into ``folder`` (created if needed) by relmap's
        one writer (:mod:`relmap.io.atomic`); returns the path of ``index.html``. Raises
        :class:`relmap.errors.OutputError` when the folder cannot be written."""
        out = make_folder(folder)
        for name, data in self._images.items():
            write_bytes_atomic(out / name, data)
        index = out / "index.html"
        write_text_atomic(index, self.html())
        return index
