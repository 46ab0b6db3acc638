"""Self-contained HTML pages: inline style, PNG and SVG figures as data: URIs, no script (report and validate)."""
from __future__ import annotations

import base64
import html
import io
import math
from typing import Sequence

import numpy as np

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


def number(x: float | None, fmt: str = ".8g") -> str:
    """A number for a table cell; a dash for None, NaN or Inf."""
    return "—" if x is None or not np.isfinite(x) else format(float(x), fmt)


def format_interval(value: float, lo: float, hi: float) -> str:
    """An interval as text whose bounds are distinct: ``value ± half-width`` (the half-width to two significant
    digits, the value to the half-width's last digit), or ``[lo, hi]`` to the same digits when the interval is
    not centred on the value; "unknown" for a NaN interval.  E.g. (−10.0000003, −10.0000005, −10.0000001) →
    "−10.00000030 ± 2.0e−07", where a fixed 6 significant digits would print [−10, −10]."""
    if not all(math.isfinite(x) for x in (value, lo, hi)):
        return "unknown" if math.isfinite(value) else "—"
    half = (hi - lo) / 2
    if half <= 0:
        return f"{value:.10g} ± 0"
    decimals = 1 - math.floor(math.log10(half))  # the half-width's second significant digit

    def fixed(x: float) -> str:
        return f"{x:.{decimals}f}" if decimals > 0 else f"{round(x, decimals):.0f}"

    if abs((lo + hi) / 2 - value) > 0.05 * half:  # not centred: both bounds
        return f"[{fixed(lo)}, {fixed(hi)}]"
    return f"{fixed(value)} ± {half:#.2g}"


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
