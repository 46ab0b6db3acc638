"""How servofmu's objects show themselves: a short ``repr`` and a compact HTML table for notebooks.

Every public object describes itself as a :class:`Shown` (its kind, what it is, its size, its key figures with
units) and takes ``__repr__ = shown_repr`` and ``_repr_html_ = shown_html`` in its class body, so the two views
say the same.  The number and unit formats are the report pages' (``number``, ``format_interval``,
``unit_text``); only the standard library is imported, so every stage may use this module.
"""
from __future__ import annotations

import html
import math
import os
from dataclasses import dataclass, fields
from typing import Iterable, Sequence

__all__ = ["json_safe", "Figure", "Shown", "shown_repr", "shown_html", "short_repr", "html_table", "figure", "parameter_figures",
           "option_figures", "options_shown", "options_repr", "options_html", "quantity", "number", "format_interval",
           "unit_text", "gain_db", "hz", "REPR_LIMIT", "escape"]

# The longest repr: one line a reader takes in at a glance, also when a list of objects is printed.
REPR_LIMIT = 300


def escape(text) -> str:
    """Text for HTML (quotes too)."""
    return html.escape(str(text), quote=True)


def number(x, fmt: str = ".8g") -> str:
    """A number for a table cell; a dash for None, NaN or Inf."""
    try:
        return "—" if x is None or not math.isfinite(float(x)) else format(float(x), fmt)
    except (TypeError, ValueError):
        return "—"


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


def unit_text(unit: str) -> str:
    """A unit as a reader writes it: the ASCII names of servofmu.model.plant (``N.s/m``, ``m/(N.s^2)``) with a
    middle dot and superscripts."""
    sup = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
    out = unit.replace("N.s", "N·s")
    if "^" in out:
        head, _, tail = out.partition("^")
        digits = "".join(c for c in tail if c.isdigit())
        out = head + digits.translate(sup) + tail[len(digits):]
    return out


def gain_db(ratio: float) -> float:
    """A gain ratio in dB (20·log10); NaN for a ratio that is not positive."""
    if ratio == math.inf:
        return math.inf
    return 20 * math.log10(ratio) if ratio > 0 and math.isfinite(ratio) else math.nan


def hz(omega: float) -> float:
    """An angular frequency (rad/s) in Hz."""
    return omega / (2 * math.pi)


@dataclass(frozen=True)
class Figure:
    """One figure of an object: a label, its value (a number or a text), the unit (ASCII as in
    servofmu.model.plant, shown with :func:`unit_text`) and an optional 95 % interval (lo, hi)."""

    label: str
    value: object
    unit: str = ""
    interval: tuple[float, float] | None = None
    fmt: str = ".4g"

    def value_text(self) -> str:
        """The value alone, numbers to ``fmt``."""
        if isinstance(self.value, bool) or not isinstance(self.value, (int, float)):
            return str(self.value)
        if isinstance(self.value, int):  # counts as they are
            return str(self.value)
        if math.isinf(self.value):  # e.g. an unstable loop's Ms, a gain margin without a phase crossover
            return "inf" if self.value > 0 else "-inf"
        return number(self.value, self.fmt)

    def text(self) -> str:
        """``label value unit`` for a repr."""
        unit = unit_text(self.unit)
        return f"{self.label} {self.value_text()}{' ' + unit if unit else ''}"


def figure(label: str, value, unit: str = "", fmt: str = ".4g", interval=None) -> Figure:
    """A :class:`Figure` (a shorthand)."""
    return Figure(label, value, unit, interval, fmt)


def quantity(value, unit: str = "", fmt: str = ".4g") -> str:
    """A number with its unit, e.g. ``quantity(11.93, "dB", ".3g")`` → "11.9 dB"; a dash for None/NaN."""
    unit = unit_text(unit)
    return number(value, fmt) + (f" {unit}" if unit else "")


def short_repr(kind: str, head: str, figures: Iterable[Figure] = (), limit: int = REPR_LIMIT) -> str:
    """``<kind head: figure, figure, …>`` in at most ``limit`` characters: the figures that do not fit are left
    out (an ellipsis says so), and a head too long is cut."""
    start = f"<{kind} {head}" if head else f"<{kind}"
    if len(start) > limit - 2:
        start = start[:limit - 3] + "…"
    parts = [f.text() for f in figures]
    out = start
    for i, part in enumerate(parts):
        sep = ": " if i == 0 else ", "
        tail = ", …>" if i < len(parts) - 1 else ">"
        if len(out) + len(sep) + len(part) + len(tail) > limit:
            return out + (": …>" if i == 0 else ", …>") if len(out) + 4 <= limit else out[:limit - 2] + "…>"
        out += sep + part
    return out + ">"


def html_table(kind: str, head: str, figures: Sequence[Figure] = (), notes: Sequence[str] = ()) -> str:
    """A compact HTML block: the kind and head as a caption, one row per figure (quantity, value, unit and, when
    any figure has one, its 95 % interval), then the notes as small paragraphs; every text escaped."""
    with_interval = any(f.interval is not None for f in figures)
    cols = ["quantity", "value", "unit"] + (["95 % interval"] if with_interval else [])
    rows = []
    for f in figures:
        cells = [escape(f.label), escape(f.value_text()), escape(unit_text(f.unit))]
        if with_interval:
            cells.append(escape(format_interval(float(f.value), *map(float, f.interval)))
                         if f.interval is not None and isinstance(f.value, (int, float)) else "")
        rows.append("<tr>" + "".join(f'<td style="text-align:{"left" if j == 0 else "right"}">{c}</td>'
                                     for j, c in enumerate(cells)) + "</tr>")
    caption = f"<caption style=\"text-align:left\"><b>{escape(kind)}</b> {escape(head)}</caption>"
    table = (f'<table class="servofmu">{caption}<thead><tr>' + "".join(f"<th>{c}</th>" for c in map(escape, cols))
             + "</tr></thead><tbody>" + "".join(rows) + "</tbody></table>")
    return "<div>" + table + "".join(f'<p style="font-size:smaller">{escape(n)}</p>' for n in notes) + "</div>"


@dataclass(frozen=True)
class Shown:
    """What an object shows: its kind (type name), a head (what it is and its size), the key figures (in the
    repr, as many as fit) and the figures of the table (the key ones when not given), and notes for the table."""

    kind: str
    head: str
    figures: tuple[Figure, ...] = ()
    table: tuple[Figure, ...] | None = None
    notes: tuple[str, ...] = ()

    def repr(self) -> str:
        """The short repr (≤ REPR_LIMIT characters)."""
        return short_repr(self.kind, self.head, self.figures)

    def html(self) -> str:
        """The HTML table."""
        return html_table(self.kind, self.head, self.figures if self.table is None else self.table, self.notes)


def shown_repr(self) -> str:
    """``__repr__`` of a class with a ``_shown()`` method returning a :class:`Shown`."""
    return self._shown().repr()


def shown_html(self) -> str:
    """``_repr_html_`` of a class with a ``_shown()`` method returning a :class:`Shown`."""
    return self._shown().html()


def parameter_figures(names: Sequence[str], values: Sequence[float], units: Sequence[str],
                      intervals: Sequence[Sequence[float]] | None = None) -> tuple[Figure, ...]:
    """One figure per parameter (value to 6 significant digits, unit, 95 % interval when given)."""
    out = []
    for i, (name, value, unit) in enumerate(zip(names, values, units)):
        interval = None if intervals is None else (float(intervals[i][0]), float(intervals[i][1]))
        out.append(Figure(name, float(value), unit, interval, ".6g"))
    return tuple(out)


def option_figures(options, units: dict[str, str] | None = None, changed_only: bool = False) -> tuple[Figure, ...]:
    """The fields of an options dataclass as figures (with the units of ``units``); with ``changed_only``, only
    those that differ from the field's default."""
    units = units or {}
    out = []
    for f in fields(options):
        value = getattr(options, f.name)
        if changed_only and value == f.default:
            continue
        shown = value if isinstance(value, (int, float)) and not isinstance(value, bool) else \
            ", ".join(map(str, value)) if isinstance(value, tuple) else str(value)
        out.append(Figure(f.name, shown, units.get(f.name, ""), None, ".6g"))
    return tuple(out)


def options_shown(options) -> Shown:
    """An options dataclass as a :class:`Shown`: the repr lists the fields changed from their defaults, the table
    every field; the units are those of the class's ``_units`` (field -> unit), if it has one."""
    units = getattr(options, "_units", {})
    changed = option_figures(options, units, changed_only=True)
    every = option_figures(options, units)
    return Shown(type(options).__name__, f"{len(changed)} of {len(every)} fields changed from the defaults",
                 changed, every)


def options_repr(self) -> str:
    """``__repr__`` of an options dataclass (:func:`options_shown`)."""
    return options_shown(self).repr()


def options_html(self) -> str:
    """``_repr_html_`` of an options dataclass (:func:`options_shown`)."""
    return options_shown(self).html()


def json_safe(obj):
    """``obj`` as standard JSON takes it: every NaN or infinite number as None (JSON has no such values), tuples as
    lists, keys as strings, paths as strings and numpy scalars as Python numbers."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if hasattr(obj, "item") and callable(obj.item) and not isinstance(obj, (str, bytes)):  # a numpy scalar
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
