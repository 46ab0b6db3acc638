"""Records held in memory (servofmu.Records) and the drive's loops as python-control systems: built from arrays
and a DataFrame exactly as `import` builds them from a file, cut, detrended, resampled and merged against numpy
written here, saved and loaded unchanged; control.margin of the loop against servofmu's own margins."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from clitools import run

import servofmu as sf
from servofmu.model.controller import controller_from_dict

RATE = 1000.0


def position_log(n=3000, seed=0):
    """A position record on a jittering 1 kHz clock: time, force, position."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE + 1e-7 * rng.standard_normal(n)
    u = 20 * np.sin(2 * np.pi * 1.5 * t) + 5 * np.sin(2 * np.pi * 7 * t)
    x = 0.01 * np.sin(2 * np.pi * 1.5 * t - 0.3) + 1e-4 * t
    return t, u, x


def test_records_from_a_dataframe_equal_the_import_of_the_same_columns(tmp_path):
    t, u, x = position_log()
    frame = pd.DataFrame({"t": t, "force": u, "x": x})
    frame.to_csv(tmp_path / "log.csv", index=False, float_format="%.17g")
    assert run("import", tmp_path / "log.csv", "--time", "t", "--input", "force", "--output-variable", "x",
               "--kind", "position", "-o", tmp_path / "log.h5").returncode == 0
    imported = sf.read_data_file(tmp_path / "log.h5").records[0]
    mine = sf.Records.from_dataframe(frame, time="t", input="force", output="x", kind="position", name="log")
    r = mine.records[0]
    for name in ("time", "u", "v", "position"):
        np.testing.assert_array_equal(getattr(r.series, name), getattr(imported.series, name))
    assert (r.sample_rate, r.velocity_cutoff, r.time_step) == (imported.sample_rate, imported.velocity_cutoff,
                                                               imported.time_step)
    # the frequency response of the records in memory is the one `servofmu frf` computes from the file
    from servofmu.broadband.records_frf import records_frf

    (in_memory,), (from_file,) = mine.frf(), records_frf(tmp_path / "log.h5")[1]
    np.testing.assert_array_equal(in_memory.direct.G, from_file.direct.G)
    assert len(repr(in_memory)) <= 300 and "Hz" in repr(in_memory)
    # the index stands for the time column when none is named
    by_index = sf.Records.from_dataframe(frame.set_index("t"), input="force", output="x", kind="position")
    np.testing.assert_array_equal(by_index.records[0].series.v, r.series.v)
    # saved and loaded back unchanged
    mine.save(tmp_path / "mine.h5")
    again = sf.Records.load(tmp_path / "mine.h5").records[0]
    for name in ("time", "u", "v", "position"):
        np.testing.assert_array_equal(getattr(again.series, name), getattr(r.series, name))
    assert again.kind == "position" and again.intersample == "zoh"


def test_between_detrend_resample_and_merge_against_numpy():
    t, u, x = position_log()
    data = sf.Records.from_arrays(t, u, x, kind="position", name="a")
    cut = data.between(0.5, 1.5).records[0].series
    keep = (t >= 0.5) & (t <= 1.5)
    np.testing.assert_array_equal(cut.time, t[keep])
    np.testing.assert_array_equal(cut.position, x[keep])
    # a linear detrend leaves no mean and no slope: numpy's own fit of what is left is zero
    flat = data.detrend("linear").records[0].series
    slope, mean = np.polyfit(t - t[0], flat.position, 1)
    assert abs(slope) < 1e-12 and abs(mean) < 1e-12
    np.testing.assert_allclose(flat.position, x - np.polyval(np.polyfit(t - t[0], x, 1), t - t[0]), atol=1e-15)
    # resampled to 250 Hz: a uniform clock, the slow sine kept (the filter is zero-phase), the held input held
    slow = data.resample(250.0).records[0].series
    np.testing.assert_allclose(np.diff(slow.time), 1 / 250.0, rtol=1e-9)
    truth = 0.01 * np.sin(2 * np.pi * 1.5 * slow.time - 0.3) + 1e-4 * slow.time
    inner = slice(50, -50)  # the filter's ends
    assert np.max(np.abs(slow.position[inner] - truth[inner])) < 2e-6
    # merged: both records, the repeated name made unique
    both = sf.Records.merge(data, sf.Records.from_arrays(t, -u, -x, kind="position", name="a"))
    assert len(both) == 2 and len(set(both.names)) == 2
    assert both.to_data_file().kind == "records"
    # records of no sine have no first harmonics: a Bode plot over them draws the model alone
    noise = np.random.default_rng(3).standard_normal(t.size)
    fig = sf.bode(sf.load_plant("g1"), data=sf.Records.from_arrays(t, noise, np.cumsum(noise), name="noise"))
    assert len(fig.axes) == 2 and fig.axes[0].lines
    assert all(line.get_linestyle() != "None" for line in fig.axes[0].lines)  # curves, no measured markers


@pytest.mark.parametrize("call, fragment", [
    (lambda t, u, x: sf.Records.from_arrays(t, u, x[:-1]), "different lengths"),
    (lambda t, u, x: sf.Records.from_arrays(t, np.r_[u[:1500], np.nan, u[1501:]], x),
     "argument 'input': sample 1501 is NaN"),
    (lambda t, u, x: sf.Records.from_arrays(t[::-1], u, x), "not strictly increasing"),
    (lambda t, u, x: sf.Records.from_arrays(t, u, x, kind="speed"), "kind must be velocity or position"),
    (lambda t, u, x: sf.Records.from_dataframe(pd.DataFrame({"t": t}), time="t", input="f"), "no column 'f'"),
    (lambda t, u, x: sf.Records.from_arrays(t, u, x).detrend("cubic"), "detrend kind 'cubic'"),
    (lambda t, u, x: sf.Records.from_arrays(t, u, x, reference=x).detrend(), "a drive's log is not detrended"),
    (lambda t, u, x: sf.Records.from_arrays(t, u, x).resample(-1), "resample rate -1"),
    (lambda t, u, x: sf.Records.from_arrays(t, u, x)[3], "record index 3 out of range"),
    (lambda t, u, x: sf.Records.merge(sf.Records.from_arrays(t, u, x), sf.Records.from_arrays(t, u, x)),
     "holds the same samples"),
])
def test_bad_arrays_and_options_are_one_line_user_errors(call, fragment):
    with pytest.raises(sf.UserError, match=None) as err:
        call(*position_log())
    assert fragment in str(err.value) and "\n" not in str(err.value)


DRIVE = {"name": "drive", "sample_time": 1e-3, "delay": 2, "position": {"kp": 60.0},
         "velocity": {"kp": 400.0, "ki": 9000.0, "filter": "first-order", "time_constant": 2e-3}}


@pytest.mark.parametrize("drive", [DRIVE, {**DRIVE, "delay": 1, "velocity": {"kp": 300.0, "filter": "moving-average",
                                                                               "window": 3}}])
def test_control_margin_of_the_loops_agrees_with_servofmus_margins(drive):
    control = pytest.importorskip("control")
    plant, controller = sf.load_plant("g1"), controller_from_dict(drive)
    loops = sf.control_loops(plant, controller)
    gms, pms, _, _, wgcs = control.stability_margins(loops.loop, returnall=True)[:5]
    mine = sf.analyse_loop(plant, controller)
    # servofmu's gain margin is the upper one (the factor that destabilises the loop by raising its gain): the
    # smallest of python-control's margins above 1 (inf when there is none)
    upper = min([g for g in gms if g > 1], default=np.inf)
    assert upper == pytest.approx(mine.gain_margin, rel=0.01)
    assert pms[np.argmax(wgcs)] == pytest.approx(mine.phase_margin, rel=0.01)
    assert max(wgcs) == pytest.approx(mine.crossover, rel=0.01)
    assert loops.margins()["gain_margin"] == pytest.approx(mine.gain_margin, rel=0.01)
    # the closed position loop from its parts (P, F, C, the delay) is stable exactly when servofmu says so, and
    # follows a constant reference (a position loop around an integrating plant)
    assert control.isdtime(loops.position_loop) and loops.position_loop.dt == drive["sample_time"]
    assert bool(np.all(np.abs(loops.position_loop.poles()) < 1)) == mine.stable
    assert abs(loops.position_loop.dcgain() - 1.0) < 1e-6
