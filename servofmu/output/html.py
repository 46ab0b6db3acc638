"""Self-contained HTML pages: inline style, PNG and SVG figures as data: URIs, no script (report and validate)."""
from __future__ import annotations

import base64
import html
import io
from typing import Sequence

from ..display import format_interval, number  # noqa: F401  (one format, shared with the reprs)

__all__ = ["escape", "number", "format_interval", "table", "figure", "png_bytes", "page", "DPI"]

DPI = 110
STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; } div.scroll { overflow-x: auto; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; overflow-wrap: anywhere; white-space: pre-line; }
table { max-width: 100%; } td:first-child { min-width: 7em; }
th { background: #f2f2f2; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: pre; overflow-wrap: normal; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #444; } p.note { font-size: 0.9em; color: #555; }
code { font-size: 0.95em; }
p.warning { background: #fff3cd; border-left: 4px solid #e0a800; padding: 0.5em 0.8em; }
p.verdict.passed { color: #1a6b2a; } p.verdict.failed, #failures { color: #a11; }
"""


def escape(text) -> str:
    """Text for HTML (quotes too)."""
    return html.escape(str(text), quote=True)


def table(table_id: str, head: Sequence[str], rows: Sequence[Sequence], numeric_from: int = 1) -> str:
    """An HTML table; cells from column ``numeric_from`` on are right-aligned."""
    out = [f'<div class="scroll"><table id="{table_id}">',
           "<thead><tr>" + "".join(f"<th>{escape(h)}</th>" for h in head) + "</tr></thead>", "<tbody>"]
    for row in rows:
        cells = [f'<td class="num">{escape(c)}</td>' if i >= numeric_from else f"<td>{escape(c)}</td>"
                 for i, c in enumerate(row)]
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</tbody></table></div>")
    return "\n".join(out)


def png_bytes(fig) -> bytes:
    """A finished matplotlib figure (laid out tightly) as PNG bytes, written through the figure's own canvas
    (no pyplot: the user's backend is not touched)."""
    if fig.get_layout_engine() is None:
        fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def figure(caption: str, image: bytes, alt: str) -> str:
    """A figure embedded as a data: URI (PNG, or SVG when ``image`` is SVG markup), with its caption."""
    svg = image.lstrip()[:5] in (b"<?xml", b"<svg ", b"<!DOC")
    src = f"data:image/{'svg+xml' if svg else 'png'};base64," + base64.b64encode(image).decode("ascii")
    return f'<figure><img src="{src}" alt="{escape(alt)}"><figcaption>{escape(caption)}</figcaption></figure>'


def page(title: str, parts: Sequence[str]) -> str:
    """The whole document."""
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
            "<link rel=\"icon\" href=\"data:,\">\n"
            f"<title>{escape(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n" + "\n".join(parts)
            + "\n</body>\n</html>\n")
