"""The validation verdict on noise-free data: the residual tests do not apply, and every page says so alike — the
text, the JSON, the HTML validation page and the report's records table — instead of "white: yes" above
correlations far outside their bounds."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from servofmu.identification.residuals import EXACT, residual_test
from servofmu.validation.replay import RecordValidation, Validation, validation_json, validation_text


def _validation(noise: float) -> Validation:
    """One record of a smooth input; the residuals ``noise`` times the output's spread, plus a smooth (strongly
    correlated) part at 1e-3 of ``EXACT``: what a simulation's rounding leaves on noise-free data."""
    rng = np.random.default_rng(0)
    t = np.arange(2000) * 1e-3
    u = np.sin(2 * np.pi * 3 * t)
    y = 0.1 * np.sin(2 * np.pi * 3 * t - 0.5)
    e = 1e-3 * EXACT * np.std(y) * np.sin(2 * np.pi * 0.7 * t) + noise * np.std(y) * rng.standard_normal(t.size)
    record = RecordValidation(name="r1", output="v", hold="zoh", time=t, u=u, y=y, y_model=y + e,
                              fit=99.99, residuals=residual_test(e, u, y))
    result = SimpleNamespace(method="pso", structure=SimpleNamespace(name="g1"))
    return Validation(result=result, data_file=SimpleNamespace(path="r.h5"), records=(record,), experiments=())


@pytest.fixture(scope="module")
def noise_free():
    v = _validation(0.0)
    auto = v.records[0].residuals
    assert auto.exact and auto.outside_per_lag()[0] > 10  # the correlations are far outside: nothing white in them
    return v


def test_the_text_says_the_residual_tests_do_not_apply(noise_free):
    text = validation_text(noise_free)
    row = next(line for line in text.splitlines() if line.startswith("r1"))
    assert row.split()[-3:] == ["n/a", "n/a", "passed"] and "yes" not in row
    assert "verdict: passed" in text and "the residual tests do not apply: the data is noise-free" in text


def test_the_json_says_the_residual_tests_do_not_apply(noise_free):
    out = validation_json(noise_free)
    assert out["passed"] is True and out["residual_tests_apply"] is False
    assert "do not apply" in out["verdict"]
    test = out["records"][0]["residual_test"]
    assert test["applies"] is False and test["white"] is None and test["passed"] is None


def test_the_html_page_and_the_report_say_the_residual_tests_do_not_apply(noise_free, monkeypatch):
    from servofmu.output import report, validation_report

    monkeypatch.setattr(validation_report, "validation_figure", lambda v, which: None)  # the text, not the images
    monkeypatch.setattr(validation_report, "residual_figure", lambda v: None)
    monkeypatch.setattr(validation_report, "figure", lambda *a: "")
    html = "".join(validation_report.validation_html(noise_free))
    assert "do not apply" in html and "n/a (noise-free)" in html and ">yes<" not in html
    entry = SimpleNamespace(records=noise_free, label="")
    assert "n/a (noise-free)" in report.records_table([entry]) and ">passed<" not in report.records_table([entry])


def test_noisy_residuals_are_still_tested():
    v = _validation(1e-2)
    assert v.records[0].residuals_apply
    out = validation_json(v)
    assert out["residual_tests_apply"] is True and out["records"][0]["residual_test"]["white"] is True
    assert "within their joint 99 % bounds" in validation_text(v) and "n/a" not in validation_text(v)
