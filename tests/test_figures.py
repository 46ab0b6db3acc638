"""Figures to place (servofmu.output.figures and every plot function): each returns a matplotlib Figure, draws into
the Axes it is given, and leaves the user's backend alone; the Bode band against an analytic and a Monte-Carlo
band of a first-order G; the friction curve against the formula of docs/model.md; several models overlaid."""
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from servofmu.errors import UserError
from servofmu.identification.residuals import residual_test
from servofmu.identification.results import Result
from servofmu.measurement.datafile import DataFile, ExperimentResult, Record, Series
from servofmu.model.plant import load_plant
from servofmu.output.bode_band import response_band
from servofmu.output.figures import bode, friction_curve, residual_tests, validation_overlay
from servofmu.validation.replay import RecordValidation, Validation

ROOT = Path(__file__).resolve().parent.parent
NAMES = ("pole1", "dc_gain", "fc_pos", "fc_neg")
# pole, gain correlated; the friction levels' variances unknown (NaN): G does not depend on them
COVARIANCE = np.array([[0.04, 1e-3, np.nan, np.nan], [1e-3, 1e-4, np.nan, np.nan],
                       [np.nan, np.nan, np.nan, np.nan], [np.nan, np.nan, np.nan, np.nan]])


def result(method="pso", pole=-10.0, gain=1.0, covariance=COVARIANCE):
    """A g1 result (G = gain·a/(s + a), a = −pole; Coulomb friction) with the given covariance."""
    structure = load_plant("g1")
    names = structure.parameter_names()
    plant = structure.with_parameters([{"pole1": pole, "dc_gain": gain}.get(n, v)
                                       for n, v in zip(names, structure.parameter_vector())])
    theta = np.array([plant.parameters()[n] for n in NAMES])
    half = 1.96 * np.sqrt(np.abs(np.diag(covariance))) if covariance is not None else np.full(4, np.nan)
    return Result(method=method, structure=structure, plant=plant, names=NAMES, theta=theta,
                  intervals=np.column_stack([theta - half, theta + half]), fitness=1e-3, seconds=1.0, evaluations=10,
                  stages=(), history=np.array([1.0, 0.1]), provenance={}, covariance=covariance)


def experiment(index, amplitude, frequency, H):
    t = np.linspace(0, 1 / frequency, 50)
    window = Series(time=t, u=amplitude * np.sin(2 * np.pi * frequency * t),
                    v=abs(H) * amplitude * np.sin(2 * np.pi * frequency * t + np.angle(H)))
    return ExperimentResult(index=index, amplitude=amplitude, frequency=frequency, excitation="builtin", U1=amplitude,
                            V1=H * amplitude, H=H, dc=0.0, harmonics=np.zeros(3, complex), distortion=0.0,
                            converged=True, settling_time=0.1, last_change=0.0, remaining_error=0.0, window_start=0.0,
                            window_periods=1, samples_per_period=50, hold_error=0.0, transient=window, window=window)


def sine_file(plant) -> DataFile:
    """Stepped-sine data: the plant's G at two amplitudes and three frequencies (friction left out)."""
    exps = tuple(experiment(k, m, f, complex(plant.frequency_response(np.array([2 * np.pi * f]))[0]) * (m / 2))
                 for k, (m, f) in enumerate((m, f) for m in (2.0, 0.6) for f in (0.5, 2.0, 10.0)))
    return DataFile(path=Path("sine.h5"), kind="measurement", schema_version=1, complete=True, plan=None,
                    experiments=exps, records=())


def records_file() -> DataFile:
    t = np.arange(0, 2, 1e-3)
    record = Record(index=0, name="r", source="r.csv", source_sha256="0" * 64, kind="velocity",
                    columns={"time": "t", "u": "u", "v": "v"}, series=Series(time=t, u=np.sin(t), v=np.cos(t)),
                    sample_rate=1e3, velocity_estimate="measured", velocity_cutoff=None, analysis=None)
    return DataFile(path=Path("records.h5"), kind="records", schema_version=2, complete=True, plan=None,
                    experiments=(), records=(record,))


def validation(res, data_file, shift: float, seed: int) -> Validation:
    """A validation of two records: the measured output and a model off it by ``shift`` plus seeded noise."""
    rng = np.random.default_rng(seed)
    records = []
    for k in range(2):
        t = np.arange(600) * 1e-3
        u = rng.standard_normal(t.size)
        y = np.sin(2 * np.pi * (k + 1) * t)
        y_model = y + shift + 0.05 * rng.standard_normal(t.size)
        fit = 100 * (1 - np.linalg.norm(y - y_model) / np.linalg.norm(y - y.mean()))
        records.append(RecordValidation(name=f"r{k}", output="velocity", hold="zoh", time=t, u=u, y=y,
                                        y_model=y_model, fit=fit, residuals=residual_test(y_model - y, u, y)))
    return Validation(result=res, data_file=data_file, records=tuple(records), experiments=())


# ---------------------------------------------------------------------------
# the backend, Figure objects, ax=
# ---------------------------------------------------------------------------
def test_plotting_leaves_the_backend_and_pyplot_alone(tmp_path):
    """In a fresh interpreter with the svg backend: every plot function returns a Figure, the file writers write
    their files, and afterwards the backend is still svg, the rcParams unchanged, pyplot never imported."""
    script = textwrap.dedent(f"""
        import sys
        import matplotlib
        matplotlib.use("svg")
        rc = dict(matplotlib.rcParams)
        sys.path.insert(0, {str(ROOT / "tests")!r})
        from matplotlib.figure import Figure
        from test_figures import result, sine_file, records_file, validation
        from servofmu.output import figures, plots, validation_report, report_figures, selection_report
        from servofmu.output.report_entries import Entry
        a, b = result("a"), result("b", pole=-12.0)
        sine, recs = sine_file(a.plant), records_file()
        va, vb = validation(a, recs, 0.0, 1), validation(b, recs, 0.1, 2)
        made = [figures.bode([a, b], data=sine), figures.friction_curve([a, b]),
                figures.validation_overlay([va, vb]), figures.residual_tests([va, vb]),
                plots.plot_bode_points(sine), plots.plot_time_series(sine), plots.plot_time_series(recs),
                validation_report.plot_validation(va, "records"), validation_report.plot_residuals([("a", va)]),
                selection_report.plot_side_by_side([("a", va), ("b", vb)]),
                report_figures.plot_convergence([Entry("a", a)])]
        assert all(isinstance(f, Figure) for f in made), made
        plots.bode_figure(sine, {str(tmp_path / "bode.png")!r})
        plots.time_series_figure(recs, {str(tmp_path / "series.svg")!r})
        report_figures.friction_figure([Entry("a", a)], None, 1.0)
        assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
        assert "matplotlib.pyplot" not in sys.modules
        changed = [k for k, v in matplotlib.rcParams.items() if str(rc[k]) != str(v)]
        assert not changed, changed
        print("ok")
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-3000:]
    assert (tmp_path / "bode.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert b"<svg" in (tmp_path / "series.svg").read_bytes()[:2000]


def test_no_module_uses_pyplot_or_switches_the_backend():
    """The functions the test above cannot call (tuning, compensation, broadband) are held to it by their source."""
    offenders = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "servofmu").rglob("*.py"))
                 if "matplotlib.pyplot" in p.read_text() or "matplotlib.use(" in p.read_text()]
    assert offenders == []


def test_ax_draws_into_the_given_axes():
    fig = Figure()
    mag, ph, fr = fig.subplots(3, 1)
    res = [result("a"), result("b", pole=-12.0)]
    assert bode(res, ax=[mag, ph]) is fig
    assert len(mag.lines) == 2 and len(ph.lines) == 2 and len(mag.collections) == 2  # two curves, two bands
    assert friction_curve(res, ax=fr) is fig and len(fr.lines) >= 2
    single = Figure().subplots()
    assert bode(res[0], ax=single) is single.figure and len(single.lines) == 1  # one Axes: the magnitude only
    recs = records_file()
    va = validation(res[0], recs, 0.0, 1)
    other = Figure()
    axes = other.subplots(2, 3)
    assert validation_overlay(va, ax=axes[:, 0]) is other
    assert residual_tests(va, ax=axes[:, 1:]) is other
    assert [len(a.lines) for a in axes[:, 0]] == [2, 2] and all(len(a.patches) > 0 for a in axes[:, 1:].ravel())
    with pytest.raises(UserError, match="2 panel"):
        validation_overlay(va, ax=[axes[0, 0]])


# ---------------------------------------------------------------------------
# the Bode band against independent references
# ---------------------------------------------------------------------------
def test_bode_band_matches_the_analytic_linearisation_and_monte_carlo():
    """G = g·a/(s + a), a = −p: ln|G| = ln g + ln a − ½ln(a² + ω²), arg G = −atan(ω/a); their gradients over
    (p, g) with the covariance give σ exactly; sampling (p, g) from the covariance (seeded) gives quantiles of
    |G| in dB that the 95 % band matches to the Monte-Carlo error."""
    res = result()
    f = np.geomspace(0.05, 50, 25)
    w, a, g = 2 * np.pi * f, 10.0, 1.0
    C = COVARIANCE[:2, :2]
    grad_log = np.column_stack([-(1 / a - a / (a ** 2 + w ** 2)), np.full(w.size, 1 / g)])
    grad_phase = np.column_stack([-w / (a ** 2 + w ** 2), np.zeros(w.size)])
    band = response_band(res, f)
    assert np.allclose(band.log_sigma, np.sqrt(np.einsum("fi,ij,fj->f", grad_log, C, grad_log)), rtol=1e-5)
    assert np.allclose(band.phase_sigma, np.sqrt(np.einsum("fi,ij,fj->f", grad_phase, C, grad_phase)), rtol=1e-5)

    rng = np.random.default_rng(0)
    p, gs = rng.multivariate_normal([-a, g], C, size=40000).T
    samples = 20 * np.log10(np.abs(gs[:, None] * -p[:, None] / (1j * w[None, :] - p[:, None])))
    lo, hi = band.magnitude_db()
    assert np.allclose(lo, np.percentile(samples, 2.5, axis=0), atol=2e-3 + 0.03 * (hi - lo).max())
    assert np.allclose(hi, np.percentile(samples, 97.5, axis=0), atol=2e-3 + 0.03 * (hi - lo).max())
    phases = np.degrees(-np.arctan2(w[None, :], -p[:, None]))
    plo, phi = band.phase_deg()
    assert np.allclose(plo, np.percentile(phases, 2.5, axis=0), atol=0.03 * (phi - plo).max() + 1e-3)
    assert np.allclose(phi, np.percentile(phases, 97.5, axis=0), atol=0.03 * (phi - plo).max() + 1e-3)

    # the band the figure draws is this band
    fig = bode(res, frequencies=f)
    (poly,) = [c for c in fig.axes[0].collections if isinstance(c, PolyCollection)]
    ys = poly.get_paths()[0].vertices[:, 1]
    assert ys.min() == pytest.approx(lo.min(), abs=1e-9) and ys.max() == pytest.approx(hi.max(), abs=1e-9)


def test_no_covariance_no_band():
    assert response_band(result(covariance=None), [1.0]) is None
    nan = COVARIANCE.copy()
    nan[0, 0] = np.nan  # the pole's variance unknown: G depends on it
    assert response_band(result(covariance=nan), [1.0]) is None
    fig = bode([result("a", covariance=None), result("b")])
    assert len(fig.axes[0].collections) == 1
    assert "no covariance" in fig.axes[0].get_legend().get_texts()[0].get_text()


def test_bode_draws_the_measured_points():
    res = result()
    data = sine_file(res.plant)
    fig = bode(res, data=data)
    measured = [ln for ln in fig.axes[0].lines if (ln.get_gid() or "").startswith("measured-")]
    assert sum(ln.get_xdata().size for ln in measured) == 6 and all(ln.get_linestyle() == "None" for ln in measured)
    xs = np.concatenate([ln.get_xdata() for ln in fig.axes[0].lines[:1]])
    assert xs.min() == pytest.approx(0.25) and xs.max() == pytest.approx(20.0)  # a factor 2 beyond the data


# ---------------------------------------------------------------------------
# friction curve, overlays
# ---------------------------------------------------------------------------
def test_friction_curve_follows_the_coulomb_formula():
    """docs/model.md: F = fc+·max(t, 0) + fc−·min(t, 0) + fv·v, t = tanh(v/v_smooth), for each model drawn."""
    a = result("a")
    b = replace(a, method="b", plant=a.plant.with_parameters(
        [{"fc_pos": 0.8, "fc_neg": 0.2}.get(n, v) for n, v in a.plant.parameters().items()]))
    fig = friction_curve([a, b], v_max=0.5, labels=["first", "second"])
    ax = fig.axes[0]
    for line, plant, label in zip(ax.lines, (a.plant, b.plant), ("first", "second")):
        p = plant.parameters()
        v, force = line.get_xdata(), line.get_ydata()
        t = np.tanh(v / p["v_smooth"])
        assert np.allclose(force, p["fc_pos"] * np.maximum(t, 0) + p["fc_neg"] * np.minimum(t, 0) + p["fv"] * v,
                           rtol=1e-12, atol=1e-14)
        assert line.get_label() == label and np.abs(v).max() == pytest.approx(0.5)


def test_validation_overlay_and_residual_tests_of_two_models():
    recs = records_file()
    va, vb = validation(result("a"), recs, 0.0, 1), validation(result("b"), recs, 0.3, 2)
    fig = validation_overlay({"right": va, "offset": vb})
    assert len(fig.axes) == 2
    for ax, ra, rb in zip(fig.axes, va.records, vb.records):
        measured, model_a, model_b = ax.lines
        assert np.array_equal(measured.get_ydata(), ra.y)
        assert np.array_equal(model_a.get_ydata(), ra.y_model) and np.array_equal(model_b.get_ydata(), rb.y_model)
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert labels == ["measured", f"right: fit {ra.fit:.3f} %", f"offset: fit {rb.fit:.3f} %"]
    fig = residual_tests([va, vb])
    auto, cross = fig.axes[:2]
    r = va.records[0].residuals
    heights = sorted(round(p.get_height(), 12) for p in auto.patches)
    expected = sorted(np.round(np.concatenate([va.records[0].residuals.autocorrelation[1:],
                                               vb.records[0].residuals.autocorrelation[1:]]), 12))
    assert heights == expected
    bounds = sorted({round(y, 12) for ln in cross.lines for y in ln.get_ydata()})
    assert bounds == [round(-r.z * r.cross_sigma, 12), round(r.z * r.cross_sigma, 12)]


def test_overlay_of_results_needs_data():
    with pytest.raises(UserError, match="give validations, or results with data="):
        validation_overlay([result("a")])
