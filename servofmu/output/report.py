"""`servofmu report`: one self-contained HTML page of an identification — tables and figures to send to a colleague.

The page has no external resources: figures are PNG images embedded as data: URIs, the style sheet is inline and
there is no script.  It is built from a list of labelled results that share one data file, so that a comparison
of several methods renders the same way (one column per result in the tables, the results overlaid in the
friction and convergence figures); a result file gives a list of one.

What it shows (docs/report.md): the identified parameters with their 95 % intervals (and, with a true plant,
its values and the relative errors), the paper's table layout (beside the paper's published numbers when the
structure is one of the paper's plants), the fit at every experiment, the stages, the provenance; figures of the
measured against the identified first-harmonic response at each excitation magnitude, of the measured responses
against the identified linear G(jω), of the friction force against velocity, and of the PSO convergence.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import UserError
from ..fileio import atomic_write, claim_output, output_mode
from ..identification.criterion import POLISH_RTOL, SineData, sine_residuals
from ..identification.results import paper_rows, read_identified_data
from ..measurement.datafile import DataFile, read_data_file
from ..model.plant import Plant, load_plant, parameter_info
from ..display import unit_text
from ..runtime import utc_now
from ..version import __version__
from .html import escape, figure, format_interval, number, page, table
from .paper import COLUMNS as PAPER_COLUMNS
from .paper import PAPER
from .paper import REFERENCES as PAPER_REFERENCES
from .paper import TABLES as PAPER_TABLES
from ..validation.replay import Validation
from ..validation.replay import validate as validate_model
from .report_entries import Entry, compute_entries, loop_controller, read_entries, used_sine_data, velocity_range
from .report_figures import bla_report_figure, bode_figures, convergence_figure, friction_figure, records_figure
from .validation_report import validation_html

__all__ = ["make_report", "report_html", "transfer_function_html", "unit_text", "compared_parameter_table"]

# ---------------------------------------------------------------------------
# HTML
# ---------------------------------------------------------------------------
def relative_error(value: float, true: float) -> float:
    return abs(value - true) / abs(true) if true != 0 else float("nan")


def parameter_unit(name: str, structure: Plant) -> str:
    """The unit of a parameter of ``structure`` for the page (the numerator constant's for its relative degree)."""
    return unit_text(parameter_info(name, structure)[0])


def parameter_table(entries: Sequence[Entry], truth: Plant | None) -> str:
    """Each identified parameter, its unit, value and 95 % interval (value ± half-width, to as many digits as
    make the bounds distinct); with ``truth`` the true value and the relative error."""
    names = list(dict.fromkeys(n for e in entries for n in e.result.names))
    true = truth.parameters() if truth is not None else {}
    head = ["parameter", "unit"]
    for e in entries:
        suffix = f" ({e.label})" if len(entries) > 1 else ""
        head += [f"identified{suffix}", f"95 % interval{suffix}"]
    if truth is not None:
        head.append("true")
        head += [f"relative error{f' ({e.label})' if len(entries) > 1 else ''}" for e in entries]
    rows = []
    for n in names:
        row = [n, parameter_unit(n, entries[0].result.structure)]
        values = []
        for e in entries:
            if n in e.result.names:
                i = e.result.names.index(n)
                values.append(e.result.theta[i])
                row += [number(e.result.theta[i]), format_interval(float(e.result.theta[i]),
                                                                   *map(float, e.result.intervals[i]))]
            else:
                values.append(None)
                row += ["—"] * 2
        if truth is not None:
            t = true.get(n)
            row.append(number(t) if t is not None else "—")
            row += [number(relative_error(v, t), ".3e") if v is not None and t is not None else "—" for v in values]
        rows.append(row)
    return table("parameters", head, rows, numeric_from=2)


def compared_parameter_table(entries: Sequence[Entry], truth: Plant | None) -> str:
    """A comparison's parameters, one row per result (and one for the truth), one column per parameter: the
    value, its 95 % interval beneath and, with ``truth``, the relative error; as wide as the parameters however
    many results are compared."""
    names = list(dict.fromkeys(n for e in entries for n in e.result.names))
    structure = entries[0].result.structure
    head = ["result"] + [f"{n} [{u}]" if (u := parameter_unit(n, structure)) else n for n in names]
    true = truth.parameters() if truth is not None else {}
    rows = []
    for e in entries:
        row = [e.label]
        for n in names:
            if n not in e.result.names:
                row.append("—")
                continue
            i = e.result.names.index(n)
            value = float(e.result.theta[i])
            interval = format_interval(value, *map(float, e.result.intervals[i]))
            lines = [number(value), "± " + interval.split(" ± ")[1] if " ± " in interval else interval]
            if n in true:
                lines.append(f"rel. error {number(relative_error(value, true[n]), '.3e')}")
            row.append("\n".join(lines))
        rows.append(row)
    if truth is not None:
        rows.append([f"true ({truth.name})"] + [number(true[n]) if n in true else "—" for n in names])
    return table("parameters", head, rows)


def separation_html(entries: Sequence[Entry]) -> list[str]:
    """A paragraph per group of parameters the data does not separate (Result.confounded), with what it
    determines; nothing for results without a covariance (older files) or whose data separates every parameter."""
    out = []
    for e in entries:
        who = f" ({escape(e.label)})" if len(entries) > 1 else ""
        for g in e.result.confounded():
            out.append(f"<p><b>Not separated by the data{who}</b>: {escape(g.line().split(': ', 1)[1])}. Each of "
                       "these parameters alone is only known to its wide interval; the combinations listed are what "
                       "the data determines (docs/identification.md, “Parameters the data does not separate”).</p>")
    return out


def _factors(roots: Sequence[complex]) -> list[str]:
    """The factors of a polynomial with these roots, as HTML: s, (s + a), (s² + b·s + c) for a conjugate pair."""
    out = []
    for r in roots:
        if r.imag < 0:
            continue  # its conjugate gives the quadratic
        if r.imag > 0:
            b, c = -2 * r.real, abs(r) ** 2
            out.append(f"(s<sup>2</sup> {'+' if b >= 0 else '−'} {abs(b):.8g}·s + {c:.8g})")
        elif r.real == 0:
            out.append("s")
        else:
            out.append(f"(s {'+' if r.real < 0 else '−'} {abs(r.real):.8g})")
    return out


def _roots_text(roots: Sequence[complex]) -> str:
    """Roots as text: −10, −2.5 ± 31.52j."""
    parts = []
    for r in roots:
        if r.imag < 0:
            continue
        parts.append(f"{r.real:.8g} ± {r.imag:.8g}j" if r.imag > 0 else f"{r.real:.8g}")
    return ", ".join(parts) or "none"


def _polynomial(coefficients: np.ndarray) -> str:
    """A polynomial in s (highest power first) as HTML."""
    n = len(coefficients) - 1
    terms = []
    for k, c in enumerate(coefficients):
        power = n - k
        if c == 0:
            continue
        s_part = "" if power == 0 else "s" if power == 1 else f"s<sup>{power}</sup>"
        magnitude = "" if abs(c) == 1 and power > 0 else f"{abs(c):.8g}" + ("·" if power > 0 else "")
        sign = "−" if c < 0 else "+"
        terms.append((sign, magnitude + s_part))
    if not terms:
        return "0"
    text = ("−" if terms[0][0] == "−" else "") + terms[0][1]
    return text + "".join(f" {sign} {t}" for sign, t in terms[1:])


def transfer_function_html(plant: Plant, label: str = "") -> str:
    """G(s) of ``plant`` written out: factored (K·Π(s − z)/Π(s − p)) and as polynomials, its poles, zeros,
    numerator constant K and DC gain G(0) with their units."""
    num, den = plant.transfer_function()
    k = plant.numerator_gain()
    zeros, poles = plant.all_zeros(), plant.all_poles()
    factored_num = " · ".join([f"{k:.8g}", *_factors(zeros)])
    factored_den = " · ".join(_factors(poles)) or "1"
    has_integrator = any(p == 0 for p in poles)
    dc = "∞ (a pole at s = 0)" if has_integrator else f"{float(np.real(plant.frequency_response(np.array([0.0]))[0])):.8g} " \
                                                      f"{unit_text('m/(N.s)')}"
    name = f" ({escape(label)})" if label else ""
    return (f'<div class="formula"><p><strong>G(s){name}</strong> = {factored_num} / {factored_den}'
            f" = ({_polynomial(num)}) / ({_polynomial(den)})</p>"
            f"<p>poles: {escape(_roots_text(poles))} rad/s; zeros: {escape(_roots_text(zeros))}"
            f"{' rad/s' if zeros else ''}; numerator constant K = {k:.8g} {escape(unit_text(parameter_info('gain', plant)[0]))}; "
            f"DC gain G(0) = {escape(dc)}. G is the velocity v (m/s) per force w = u − F(v) (N).</p></div>")


def paper_table(entries: Sequence[Entry], truth: Plant | None) -> str:
    """The paper's layout (Table II for a first-order G, III otherwise); the paper's published columns beside ours
    when the structure is the paper's plant."""
    ours = [dict(paper_rows(e.result.plant)) for e in entries]
    labels = list(dict.fromkeys(label for e in entries for label, _ in paper_rows(e.result.plant)))
    structure = entries[0].result.structure
    published = PAPER_TABLES.get(structure.name)
    if published is not None and not _is_packaged(structure):
        published = None
    head = ["parameter"] + [f"servofmu {e.label}" for e in entries]
    if truth is not None:
        truth_rows = dict(paper_rows(truth))
        head.append(f"true ({truth.name})")
    if published is not None:
        head += [f"paper: {c}" for c in PAPER_COLUMNS]
    rows = []
    for label in labels:
        row = [label] + [o.get(label, "—") for o in ours]
        if truth is not None:
            row.append(truth_rows.get(label, "—"))
        if published is not None:
            row += list(published.get(label, ("—",) * len(PAPER_COLUMNS)))
        rows.append(row)
    note = ""
    if published is not None:
        refs = "".join(f"<li>[{escape(key)}] {escape(text)}</li>" for key, text in PAPER_REFERENCES.items())
        note = (f'<p class="note">The paper\'s columns are its published Tables II/III for {escape(structure.name)}; '
                "its target is the plant the data was measured on. The paper is "
                f"{escape(PAPER)}; the comparators it cites:</p>"
                f'<ul id="references" class="note">{refs}</ul>')
    return table("paper", head, rows) + note


def _is_packaged(structure: Plant) -> bool:
    """Whether ``structure`` is the packaged plant of its name (the paper's g1/g2), not a namesake."""
    try:
        packaged = load_plant(structure.name)
    except UserError:
        return False
    return (packaged.parameter_names() == structure.parameter_names()
            and np.allclose(packaged.parameter_vector(), structure.parameter_vector()))


def recomputed_fitness(entry: Entry, data: SineData) -> float:
    """The fitness of the identified plant from the report's own simulations (the identification's criterion)."""
    r = sine_residuals(data, *entry.sine)
    return float(np.sqrt(np.mean(np.square(r))))


def experiment_table(entries: Sequence[Entry], data: SineData) -> str:
    """Measured (as fitted) against identified response at each used experiment."""
    what = "measured (noisy)" if data.noisy else "measured"
    head = ["amplitude [N]", "frequency [Hz]", f"|H| {what} [m/(N·s)]", f"∠H {what} [deg]", f"dc {what} [m/s]"]
    if len(entries) > 1:  # a comparison: one column per result, the relative error (the page stays narrow)
        head += [f"|ΔH|/|H| ({e.label})" for e in entries]
        rows = [[number(data.amplitudes[k], "g"), number(data.frequencies[k], "g"), number(abs(data.H[k])),
                 number(np.degrees(np.angle(data.H[k])), ".6f"), number(data.dc[k], ".6g")]
                + [number(abs(e.sine[0][k] - data.H[k]) / abs(data.H[k]), ".3e") for e in entries]
                for k in range(data.H.size)]
        return table("experiments", head, rows, numeric_from=0)
    for e in entries:
        suffix = f" ({e.label})" if len(entries) > 1 else ""
        head += [f"|H| model{suffix}", f"∠H model{suffix} [deg]", f"dc model{suffix} [m/s]", f"|ΔH|/|H|{suffix}"]
    rows = []
    for k in range(data.H.size):
        row = [number(data.amplitudes[k], "g"), number(data.frequencies[k], "g"), number(abs(data.H[k])),
               number(np.degrees(np.angle(data.H[k])), ".6f"), number(data.dc[k], ".6g")]
        for e in entries:
            H, dc = e.sine[0][k], e.sine[1][k]
            row += [number(abs(H)), number(np.degrees(np.angle(H)), ".6f"), number(dc, ".6g"),
                    number(abs(H - data.H[k]) / abs(data.H[k]), ".3e")]
        rows.append(row)
    return table("experiments", head, rows, numeric_from=0)


def records_table(entries: Sequence[Entry]) -> str:
    """Per record the fit (%) of every result and whether its residuals pass the tests of `servofmu validate`."""
    first = entries[0].records.records
    several = len(entries) > 1
    head = ["record", "output", "input", "samples"]
    # a comparison: one column per result (fit and verdict in one cell), else two
    head += [f"fit %, residual tests ({e.label})" for e in entries] if several else ["fit %", "residual tests"]
    rows = []
    for k, r in enumerate(first):
        row = [r.name, r.output, r.hold, str(r.y.size)]
        for e in entries:
            check = e.records.records[k]
            tests = ("n/a (noise-free)" if not check.residuals_apply else
                     "passed" if check.residuals_passed else "failed")
            row += [f"{number(check.fit, '.6f')} ({tests})"] if several else [number(check.fit, ".6f"), tests]
        rows.append(row)
    return table("records", head, rows, numeric_from=3)


def stage_table(entries: Sequence[Entry]) -> str:
    head = (["result"] if len(entries) > 1 else []) + ["stage", "fitness", "seconds", "model evaluations"]
    rows = []
    for e in entries:
        for s in e.result.stages:
            rows.append(([e.label] if len(entries) > 1 else []) + [s.name, number(s.fitness, ".3e"),
                                                                   number(s.seconds, ".3f"), str(s.evaluations)])
        rows.append(([e.label] if len(entries) > 1 else []) + ["total", number(e.result.fitness, ".3e"),
                                                               number(e.result.seconds, ".3f"),
                                                               str(e.result.evaluations)])
    return table("stages", head, rows, numeric_from=len(head) - 3)


def provenance_table(entries: Sequence[Entry], data_path: Path, source: Path) -> str:
    keys = ["method", "data_file", "data_sha256", "structure_file", "ann_file", "command", "date"]
    head = ["item"] + [e.label for e in entries]
    rows = [["report source", *[str(source)] * len(entries)], ["data file read", *[str(data_path)] * len(entries)],
            ["structure", *[e.result.structure.name for e in entries]]]
    for k in keys:
        values = [e.result.method if k == "method" else e.result.provenance.get(k, "") for e in entries]
        if any(values):
            rows.append([k, *[v or "—" for v in values]])
    return table("provenance", head, rows, numeric_from=len(head))


def report_html(entries: Sequence[Entry], data_file: DataFile, truth: Plant | None = None,
                source: Path = Path("RESULT.h5"), title: str | None = None,
                validation: Sequence[tuple[str, Validation]] | None = None) -> str:
    """The whole page for ``entries`` (simulated against ``data_file`` by compute_entries)."""

    if not entries:
        raise UserError(f"{source}: holds no result to report")
    data = used_sine_data(data_file)
    structure = entries[0].result.structure
    title = title or f"Identification of {structure.name}"
    parts = [f"<h1>{escape(title)}</h1>"]
    summary = "; ".join(f"{e.label}: fitness {e.result.fitness:.3e} in {e.result.seconds:.2f} s "
                        f"({e.result.evaluations} model evaluations)" for e in entries)
    parts.append(f'<p>Structure <code>{escape(structure.name)}</code> ({escape(structure.friction.model)} friction, '
                 f"order {structure.order}) identified from <code>{escape(Path(data_file.path).name)}</code> "
                 f"({len(data_file.experiments)} experiments, {len(data_file.records)} records). {escape(summary)}. "
                 "Fitness: RMS of the relative output-error residuals.</p>")
    for e in entries:
        if e.result.plant.load.keys():  # the force on the load besides friction (docs/model.md)
            who = f" ({escape(e.label)})" if len(entries) > 1 else ""
            parts.append(f"<p>Load{who}: {escape(e.result.plant.load.describe())}, adding to u: v = G(s)·(u − F(v) "
                         "+ L(x)).</p>")

    parameters = parameter_table(entries, truth) if len(entries) == 1 else compared_parameter_table(entries, truth)
    parts += ["<h2>Identified parameters</h2>", parameters,
              '<p class="note">Intervals: 95 % from the Gauss–Newton covariance of the final fit, written as the '
              "value ± the half-width (two significant digits; the value to the half-width's last digit, so that "
              "the bounds differ), or as [low, high] when not centred on the value. Parameters not listed keep the "
              "structure file's values.</p>", *separation_html(entries),
              "<h2>The identified G(s)</h2>",
              *[transfer_function_html(e.result.plant, e.label if len(entries) > 1 else "") for e in entries],
              "<h2>The paper's table layout</h2>", paper_table(entries, truth)]

    if data is not None:
        skipped = f" {data.skipped} experiment(s) reached no steady state and were not used." if data.skipped else ""
        refit = "; ".join(f"{e.label}: {recomputed_fitness(e, data):.3e} (stored {e.result.fitness:.3e})"
                          for e in entries)
        parts += ["<h2>Fit at each experiment</h2>", experiment_table(entries, data),
                  f'<p class="note">The model columns simulate the identified plant to steady state at each '
                  f"experiment of the plan (relative tolerance {POLISH_RTOL:g}). The fitness recomputed from them: "
                  f'<span id="refit">{escape(refit)}</span>.{escape(skipped)}</p>']
    else:
        parts += ["<h2>Fit to each record</h2>", records_table(entries),
                  '<p class="note">Fit: 100·(1 − ‖y − ŷ‖/‖y − mean y‖) on the signal each record measures (the '
                  "velocity, or the position with its zero removed). Residual tests: see Validation.</p>"]
    parts += ["<h2>Stages</h2>", stage_table(entries)]

    parts.append("<h2>Figures</h2>")
    # one figure per view, the results overlaid (a comparison's methods on shared axes)
    figures = bode_figures(entries, data_file, data) if data is not None else [records_figure(entries)]
    if data_file.kind == "broadband":
        figures.append(bla_report_figure(entries, data_file))
    parts += [figure(caption, png, caption.split(":")[0]) for caption, png in figures]
    caption, png = friction_figure(entries, truth, velocity_range(data_file))
    parts.append(figure(caption, png, "friction against velocity"))
    convergence = convergence_figure(entries)
    if convergence is not None:
        parts.append(figure(*convergence, "PSO convergence"))

    for label, v in validation or ():
        parts += [f"<h2>Validation on {escape(Path(v.data_file.path).name)}"
                  + (f" ({escape(label)})" if len(validation) > 1 else "") + "</h2>", *validation_html(v)]
    parts += ["<h2>Provenance</h2>", provenance_table(entries, Path(data_file.path), source),
              f'<p class="note">Made by servofmu {escape(__version__)} on {escape(utc_now())}.</p>']
    return page(title, parts)


def make_report(source: str | Path, output: str | Path, data: str | Path | None = None,
                truth: str | Path | None = None, validate: str | Path | None = None, overwrite: bool = False) -> Path:
    """Read a result or comparison file (and the data it was identified from), write the HTML report ``output``
    (an existing one only with ``overwrite``); with ``validate``, a data file to validate every result on (a
    section of `servofmu validate`)."""
    output = claim_output(output, output_mode(overwrite), inputs=(source, data, validate))
    source = Path(source)
    labelled = read_entries(source)
    true_plant = load_plant(truth) if truth is not None else None
    data_file = read_identified_data([r for _, r in labelled], source, data)
    entries = compute_entries(labelled, data_file)
    validation = None
    if validate is not None:
        other = read_data_file(validate)
        validation = [(label, validate_model(result, other, controller=loop_controller(result))) for label, result in labelled]
    return atomic_write(output, report_html(entries, data_file, true_plant, source=source, validation=validation))
