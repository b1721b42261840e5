"""The one HTML page builder of the reports (session report and diagnosis report).

A page is self-contained: one inline stylesheet, every figure a PNG embedded as a base64 `data:`
image, no script and no external resource (a Content-Security-Policy says so to the browser).
Figures are drawn with matplotlib's object API (`matplotlib.figure.Figure`), never through pyplot's
global state, and turned into PNG bytes by `png`. Every text from outside is escaped here (`e`);
fragments passed in as HTML are markup built by the reports themselves.
"""

import base64
import html
import io
from dataclasses import dataclass

DPI = 100
"""Resolution of the PNG figures."""

CSS = """
body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222;line-height:1.4}
h1{font-size:1.5em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:.9em}td,th{border:1px solid #ccc;padding:2px 8px;
text-align:right}th{background:#f3f3f3}td:first-child{text-align:left}
#warnings li{color:#8a1c00}#warnings li.ok{color:#1c6b00}.src{color:#666;font-size:.85em}
figure{margin:0}img{max-width:100%;border:1px solid #eee}figcaption{font-size:.9em;color:#444}
"""

e = html.escape


@dataclass(frozen=True)
class Plot:
    """One figure: `name` (id and file suffix), title, caption (plain text) and the PNG bytes."""

    name: str
    title: str
    caption: str
    png: bytes


def png(fig) -> bytes:
    """PNG bytes of a matplotlib Figure, laid out tight."""
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def figure(plot: Plot) -> str:
    """A <figure>: title, the embedded PNG, the caption."""
    data = base64.b64encode(plot.png).decode("ascii")
    return (f'<figure id="{e(plot.name)}"><h2>{e(plot.title)}</h2>'
            f'<img alt="{e(plot.title)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{e(plot.caption)}</figcaption></figure>")


def table(rows, head=None, escape_cells: bool = True) -> str:
    """An HTML table; cells escaped unless they are trusted markup built by the caller."""
    cell = e if escape_cells else str
    top = "<tr>" + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr>" if head else ""
    body = "".join("<tr>" + "".join(f"<td>{cell(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table>{top}{body}</table>"


def section(ident: str, title: str, inner: str) -> str:
    """A <section> with an id and a heading around trusted markup `inner`."""
    return f'<section id="{e(ident)}"><h2>{e(title)}</h2>{inner}</section>'


def page(title: str, source: str, body: str) -> str:
    """The whole HTML document: `title` as <title> and <h1>, the `source` path under it, then the
    trusted markup `body` (sections and figures)."""
    return (
        "<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8>"
        '<meta http-equiv="Content-Security-Policy" content="default-src \'none\'; '
        'img-src data:; style-src \'unsafe-inline\'">'
        f"<title>{e(title)}</title><style>{CSS}</style></head><body>"
        f"<h1>{e(title)}</h1><p class=src>{e(source)}</p>{body}</body></html>\n")
