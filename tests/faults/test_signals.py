"""Writers that continue an interrupted file (measure, dataset) stopped by SIGTERM, SIGINT (Ctrl-C) or SIGKILL at a
seeded random moment: one line and exit 128 + the signal (none for SIGKILL, which cannot be handled), no partial
file, no temporary folder left, no worker left; then --resume finishes identical to an uninterrupted run.
A selection (candidates fitted in workers, three files written at the end) stopped anywhere writes nothing."""
from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest
from harness import assert_one_line, no_partial_files, run_servofmu, sample
from test_write_faults import same_measurement, same_training_set

COMMANDS = {
    "measure": (["measure", "{g1_fmu}", "--amplitudes", "2,1,0.6", "--frequencies", "0.5,1,2,5,10", "--workers",
                 "2", "-o", "out.h5"], same_measurement),
    "dataset": (["dataset", "g1", "--like", "{data}", "--samples", "400", "-o", "out.h5"], same_training_set),
}
SIGNALS = {"SIGTERM": (signal.SIGTERM, 143, "terminated (SIGTERM)"), "SIGINT": (signal.SIGINT, 130, "interrupted"),
           "SIGKILL": (signal.SIGKILL, -9, None)}
CASES = [(c, s, seed) for seed in range(3) for c in COMMANDS for s in SIGNALS]


def command_line(command: str, inputs: dict) -> list[str]:
    return [a.format(**{k: str(v) for k, v in inputs.items()}) for a in COMMANDS[command][0]]


@pytest.fixture(scope="module")
def references(inputs, tmp_path_factory):
    """command -> (its output uninterrupted, seconds it took)."""
    out = {}
    for command in COMMANDS:
        folder = tmp_path_factory.mktemp(f"uninterrupted-{command}")
        start = time.monotonic()
        proc = run_servofmu(command_line(command, inputs), folder, folder)
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
        out[command] = (folder / "out.h5", time.monotonic() - start)
    return out


@pytest.mark.parametrize("command, name, seed", sample(CASES, every=9))
def test_a_signal_at_a_random_moment_damages_nothing_and_resume_finishes(inputs, references, tmp_path, command,
                                                                         name, seed):
    argv, same = command_line(command, inputs), COMMANDS[command][1]
    reference, seconds = references[command]
    signum, status, message = SIGNALS[name]
    temp = tmp_path / "tmp"
    work = tmp_path / "work"
    temp.mkdir()
    work.mkdir()
    proc = run_servofmu(argv, work, temp)
    time.sleep(seconds * np.random.default_rng([seed, len(command), signum]).uniform(0.1, 0.9))
    if signum == signal.SIGINT:  # Ctrl-C reaches the terminal's whole process group
        os.killpg(proc.pid, signum)
    else:
        proc.send_signal(signum)
    out, err = proc.communicate(timeout=120)
    if proc.returncode in (0, -signum) and "wrote" in out:  # after main() returned: the default handler ends it
        pytest.skip("the command finished before the signal")
    if message is not None:
        assert_one_line(err, proc.returncode, status, message)
    else:
        assert proc.returncode == status
    if signum != signal.SIGKILL:  # SIGKILL between linking .NAME.part and its rename leaves it: the next run's
        no_partial_files([p.name for p in work.iterdir()])  # write replaces it
    again = run_servofmu([*argv, "--resume"], work, temp)
    _, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    no_partial_files([p.name for p in work.iterdir()])
    same(work / "out.h5", reference)
    deadline = time.monotonic() + 10  # what a killed run left is removed by the next command (the resume)
    while list(temp.iterdir()) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not list(temp.iterdir())


# ---------------------------------------------------------------------------
# Where a stop signal's exception cannot simply be raised
# ---------------------------------------------------------------------------
def test_a_signal_inside_signals_deferred_reaches_its_handler_when_the_block_ends():
    from servofmu.runtime import signals_deferred

    got = []

    def handler(signum, frame):
        got.append(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGUSR1, handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            with signals_deferred((signal.SIGUSR1,)):
                os.kill(os.getpid(), signal.SIGUSR1)
                time.sleep(0.05)  # a handler running now would raise here, inside the block
                assert got == []
        assert got == [signal.SIGUSR1]
        assert signal.getsignal(signal.SIGUSR1) is handler
        assert signal.SIGUSR1 not in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    finally:
        signal.signal(signal.SIGUSR1, previous)


def test_sigterm_that_arrives_inside_a_finaliser_still_stops_the_command_with_one_line(monkeypatch, tmp_path,
                                                                                        capsys):
    """Python drops an exception raised in __del__ or a weakref callback (with a traceback on stderr); the command
    line raises it again right after, in ordinary code."""
    import gc

    from servofmu import cli
    from servofmu.cli import model

    class SignalledWhenCollected:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGTERM)  # its handler runs here, inside the finaliser

    def command(args):
        SignalledWhenCollected()
        gc.collect()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # the work goes on: only the raised-again stop ends it
            time.sleep(0.01)
        raise AssertionError("the stop signal was lost")

    monkeypatch.setattr(model, "cmd_build", command)
    rc = cli.main(["build", "g1", "-o", str(tmp_path / "g1.fmu")])
    err = capsys.readouterr().err
    assert rc == 143
    assert err.strip().splitlines() == ["servofmu build: terminated (SIGTERM)"], err


MOMENTS = 12  # per signal, spread evenly over an uninterrupted run's duration
STOP_MOMENTS = [(name, k) for name in ("SIGTERM", "SIGINT") for k in range(MOMENTS)]


@pytest.mark.long
@pytest.mark.parametrize("name, k", STOP_MOMENTS)
def test_a_stop_at_any_moment_of_a_run_with_workers_ends_it_at_once_with_one_line(inputs, references, tmp_path,
                                                                                   name, k):
    """Stops spread over the whole run, its start (workers being started) included: no hang (a worker stopped while
    it sent its result once left the pool's threads waiting for ever), no traceback (from a worker stopped while it
    read its start-up data, or from the pool's end)."""
    signum, status, message = SIGNALS[name]
    _, seconds = references["measure"]
    temp = tmp_path / "tmp"
    temp.mkdir()
    proc = run_servofmu(command_line("measure", inputs), tmp_path, temp)
    time.sleep(0.3 + 0.8 * seconds * k / MOMENTS)  # 0.3 s: past the interpreter's own start-up
    if signum == signal.SIGINT:
        os.killpg(proc.pid, signum)
    else:
        proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    if proc.returncode in (0, -signum) and (tmp_path / "out.h5").exists():  # after main() returned
        pytest.skip("the command finished before the signal")
    assert_one_line(err, proc.returncode, status, message)


SELECT = ["select", "{data}", "--validate", "{data2}", "--candidates", "coulomb/1,coulomb/2,stribeck/1",
          "--iterations", "5", "--workers", "2", "-o", "out.h5"]


@pytest.fixture(scope="module")
def selection_seconds(inputs, tmp_path_factory) -> float:
    """How long an uninterrupted selection takes."""
    folder = tmp_path_factory.mktemp("uninterrupted-select")
    start = time.monotonic()
    proc = run_servofmu([a.format(**{k: str(v) for k, v in inputs.items()}) for a in SELECT], folder, folder)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    return time.monotonic() - start


@pytest.mark.parametrize("name, k", sample([(name, k) for k in range(4) for name in ("SIGTERM", "SIGINT")], every=3))
def test_a_selection_stopped_at_any_moment_writes_nothing_and_leaves_no_worker(inputs, selection_seconds, tmp_path,
                                                                               name, k):
    """`select` fits its candidates in worker processes and writes three files at the end: a stop anywhere in the
    run is one line, leaves none of them (nor a partial file) and no worker (their temporary folder goes with
    them)."""
    signum, status, message = SIGNALS[name]
    temp, work = tmp_path / "tmp", tmp_path / "work"
    temp.mkdir()
    work.mkdir()
    proc = run_servofmu([a.format(**{key: str(v) for key, v in inputs.items()}) for a in SELECT], work, temp)
    time.sleep(0.3 + 0.8 * selection_seconds * k / 4)
    if signum == signal.SIGINT:
        os.killpg(proc.pid, signum)
    else:
        proc.send_signal(signum)
    out, err = proc.communicate(timeout=60)
    if proc.returncode in (0, -signum) and "wrote" in out:  # after main() returned
        pytest.skip("the command finished before the signal")
    assert_one_line(err, proc.returncode, status, message)
    assert sorted(p.name for p in work.iterdir()) == []
    deadline = time.monotonic() + 10
    while list(temp.iterdir()) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not list(temp.iterdir())
