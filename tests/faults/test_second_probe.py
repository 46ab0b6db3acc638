"""Faults found by a second, independent probe (about 200 commands with bad inputs, signals, races and resource
limits; single-bit flips through the readers), each reproduced.  A test is named after the probe's item:
``test_p01_...`` is its item 1.  Every test here failed before servofmu handled the fault (scripts/fault_suite.py
--against shows it)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
from harness import AGAINST, assert_one_line, command_env, run_here, run_servofmu, sample


def copy_file(source: Path, target: Path) -> Path:
    target.write_bytes(source.read_bytes())
    return target


def miswired(source: Path, target: Path) -> Path:
    """The axis archive with the force connected to a connector the plant does not have."""
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(target, "w") as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "SystemStructure.ssd":
                data = data.replace(b'endConnector="u"', b'endConnector="uu"')
            dst.writestr(item, data)
    return target


# ---- 1. silent wrong answers: an SSP connection to a connector that does not exist ---------------------------------
@pytest.mark.parametrize("engine", ["fmpy", "libcosim"])
def test_p01_a_connection_to_a_missing_connector_is_refused_on_either_engine(inputs, tmp_path, engine):
    ssp = miswired(inputs["axis"], tmp_path / "axis.ssp")
    rc, err = run_here(["cosim", ssp, "--engine", engine, "-o", "rec.h5"], tmp_path)
    assert_one_line(err, rc, 2, "axis.ssp", "plant.uu")
    assert not (tmp_path / "rec.h5").exists()


# ---- 2. silent wrong answers: a flipped bit in a text attribute (a global heap no HDF5 checksum covers) -------------
def flip_in(path: Path, needle: bytes, at: int, bit: int) -> Path:
    """Flip ``bit`` of the byte ``at`` of the one occurrence of ``needle`` in the file: one flipped bit."""
    image = bytearray(path.read_bytes())
    assert image.count(needle) == 1, (needle, image.count(needle))
    image[image.index(needle) + at] ^= 1 << bit
    path.write_bytes(image)
    return path


# kind -> (the text flipped: its bytes, the byte and bit; the command that reads the file, {bad} for it); each flip
# leaves text the old readers took as it came (a seed 0 → 1, a "2" → "3" in a command line, lbfgs → lbfgr)
TEXT_FLIPS = {
    "result": ((b'"seed": 0', 8, 0), ["export", "{bad}", "--format", "json", "-o", "out.json"]),
    "data": ((b"--amplitudes 2,0.6", 13, 0), ["identify", "{bad}", "--structure", "g1", "--method", "pso", "-o",
                                              "out.h5"]),
    "ds": ((b"dc_gain = 1.0", 10, 1), ["train", "{bad}", "-o", "out.h5"]),
    "ann": ((b"lbfgs", 4, 0), ["identify", "{data}", "--structure", "g1", "--ann", "{bad}", "-o", "out.h5"]),
}


@pytest.mark.parametrize("kind", TEXT_FLIPS)
def test_p02_a_flipped_bit_in_a_text_attribute_is_reported_not_read(inputs, tmp_path, kind):
    (needle, at, bit), argv = TEXT_FLIPS[kind]
    bad = flip_in(copy_file(inputs[kind], tmp_path / f"bad-{kind}.h5"), needle, at, bit)
    rc, err = run_here([a.format(bad=bad, **{k: str(v) for k, v in inputs.items()}) for a in argv], tmp_path)
    assert_one_line(err, rc, 2, str(bad), "damaged", "does not match the digest")
    assert not list(tmp_path.glob("out.*"))


# ---- 3. an input replaced while it is read: the hash recorded is that of the bytes identified from ---------------
def test_p03_identify_records_the_hash_of_the_data_it_identified_from(inputs, tmp_path):
    """Data file A replaced over and over (``mv B A``, ``cp B A``) while identify reads it: each run either
    identifies from one version and records that version's SHA-256, or stops with one line; it read the file once
    (before, it hashed the file apart from parsing it and recorded one file's hash with the other's parameters)."""
    import hashlib
    import threading

    import h5py

    from servofmu.measurement.datafile import add_experiments, create_measurement, read_data_file

    data = read_data_file(inputs["data"])  # and the same without one experiment: other parameters
    create_measurement(tmp_path / "fewer.h5", data.plan, data.provenance, data.parameters)
    add_experiments(tmp_path / "fewer.h5", data.experiments[:-1])
    versions = [inputs["data"].read_bytes(), (tmp_path / "fewer.h5").read_bytes()]
    sha = [hashlib.sha256(v).hexdigest() for v in versions]

    def identify(name: str) -> tuple[int, str, dict]:
        rc, err = run_here(["identify", name, "--structure", "g1", "--method", "pso", "--force", "-o", "r.h5"], tmp_path)
        if rc:
            return rc, err, {}
        with h5py.File(tmp_path / "r.h5") as f:
            return rc, err, {"theta": f["theta"][()].tolist(), "data_sha256": json.loads(f.attrs["provenance"])
                             ["data_sha256"]}

    reference = []
    for k, image in enumerate(versions):
        (tmp_path / f"v{k}.h5").write_bytes(image)
        rc, err, got = identify(f"v{k}.h5")
        assert rc == 0, err
        reference.append(got["theta"])
    assert reference[0] != reference[1]
    target, stop = tmp_path / "a.h5", threading.Event()
    target.write_bytes(versions[0])

    def replace_again_and_again():
        k = 0
        while not stop.is_set():
            k += 1
            if k % 4:  # mv B A
                (tmp_path / "next.h5").write_bytes(versions[k % 2])
                os.replace(tmp_path / "next.h5", target)
            else:  # cp B A: truncated and written in place
                with open(target, "r+b") as fh:
                    fh.truncate(0)
                    fh.write(versions[k % 2])
            time.sleep(0.001)

    swapper = threading.Thread(target=replace_again_and_again, daemon=True)
    swapper.start()
    outcomes = []
    try:
        for _ in range(12):
            outcomes.append(identify("a.h5"))
    finally:
        stop.set()
        swapper.join()
    for rc, err, got in outcomes:
        if rc:
            assert_one_line(err, rc, 2, "a.h5")
            continue
        if got["data_sha256"] in sha:  # (a read that spans a cp may hold bytes of both: a hash of neither)
            assert got["theta"] == reference[sha.index(got["data_sha256"])], "parameters of one file, hash of the other"


# ---- 9. a file that made the HDF5 library loop for ever ------------------------------------------------------------
def looping_result(inputs, folder: Path) -> Path:
    """The result file with one bit flipped in the size of the first object of its global heap (where its text
    attributes live), so that HDF5's parse of the heap lands in the zeros of its free space, reads an object of
    index 0 and size 0 there, and steps by that size for ever: h5py's read of the attribute never returns, nor
    heeds signals."""
    bad = copy_file(inputs["result"], folder / "loop.h5")
    image = bytearray(bad.read_bytes())
    heap = image.index(b"GCOL")
    end = heap + int.from_bytes(image[heap + 8:heap + 16], "little")
    first = heap + 16  # objects: index (2 bytes), references (2), reserved (4), size (8), data padded to 8 bytes
    size = int.from_bytes(image[first + 8:first + 16], "little")
    p = first
    while int.from_bytes(image[p:p + 2], "little"):  # to the free space, index 0
        p += 16 + -(-int.from_bytes(image[p + 8:p + 16], "little") // 8) * 8
    for bit in range(4, 16):
        land = first + 16 + -(-(size ^ 1 << bit) // 8) * 8
        if p + 16 <= land <= end - 16 and not any(image[land:land + 16]):
            image[first + 8 + bit // 8] ^= 1 << bit % 8
            bad.write_bytes(image)
            return bad
    raise AssertionError("no bit of the first object's size lands in the free space")


def stderr_within(proc, seconds: float, failure: str) -> str:
    """The standard error of ``proc`` once it ended within ``seconds``; else it is killed and the test fails."""
    try:
        return proc.communicate(timeout=seconds)[1]
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(failure)


def test_p09_a_reader_never_hangs_on_a_damaged_file(inputs, tmp_path):
    bad = looping_result(inputs, tmp_path)
    proc = run_servofmu(["export", bad, "--format", "json", "-o", "out.json"], tmp_path, tmp_path)
    err = stderr_within(proc, 90, "export of a damaged result file did not end in 90 s")
    assert_one_line(err, proc.returncode, 2, str(bad), "damaged result file", "did not end")
    assert not (tmp_path / "out.json").exists()


def test_p09_a_stop_signal_ends_a_read_at_once(inputs, tmp_path):
    bad = looping_result(inputs, tmp_path)
    proc = run_servofmu(["export", bad, "--format", "json", "-o", "out.json"], tmp_path, tmp_path)
    time.sleep(3)  # reading the file by now
    proc.send_signal(signal.SIGTERM)
    err = stderr_within(proc, 10, "export did not heed SIGTERM while it read a damaged file")
    assert_one_line(err, proc.returncode, 128 + signal.SIGTERM, "terminated")
    time.sleep(0.5)
    assert subprocess.run(["pgrep", "-s", str(proc.pid)], capture_output=True).stdout == b"", "a reader left running"


# ---- 10. tracebacks: damage the readers did not expect, numbers beyond the floats, a memory limit -------------------
def run_python(code: str, cwd: Path) -> subprocess.CompletedProcess:
    """``python -c CODE`` with the servofmu under test."""
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=command_env(), capture_output=True, text=True,
                          timeout=300)


@pytest.mark.parametrize(("at",), sample([(0,), (7,), (40,), (200,)], 2))
def test_p10_a_flipped_bit_in_an_experiments_header_is_one_line(inputs, tmp_path, at):
    """A bit of the object header of an experiment's group (its attributes, checksummed): h5py then gives None for
    the group, and the reader took its attributes (AttributeError: 'NoneType' object has no attribute 'attrs')."""
    import h5py

    bad = copy_file(inputs["data"], tmp_path / "bad.h5")
    with h5py.File(bad) as f:
        header = h5py.h5o.get_info(f["experiments/exp_0001"].id).addr
    image = bytearray(bad.read_bytes())
    assert image[header:header + 4] == b"OHDR"
    image[header + at] ^= 1 << 3
    bad.write_bytes(image)
    rc, err = run_here(["identify", bad, "--structure", "g1", "--method", "pso", "-o", "r.h5"], tmp_path)
    assert_one_line(err, rc, 2, str(bad), "damaged")
    assert not (tmp_path / "r.h5").exists()


@pytest.mark.parametrize("where, sign", sample([(w, s) for w in ("t_end", "t_start", "values") for s in (1, -1)], 3))
def test_p10_numbers_beyond_the_floats_in_the_harmonic_analysis_are_user_errors(tmp_path, where, sign):
    code = f"""
import numpy as np
from servofmu.errors import UserError
from servofmu.measurement import frf
t = np.linspace(0, 4, 4001); s = np.sin(2 * np.pi * 2 * t)
{"s" if where == "values" else "t"}[{ {"values": 100, "t_end": -1, "t_start": 0}[where]}] = {sign} * 1e308
for call in (lambda: frf.harmonics(t, s, 2.0), lambda: frf.estimate_frequency(t, s),
             lambda: frf.settle_noisy(t, s, 2.0, float(t[0]))):
    try:
        call()
        print("returned")
    except UserError as exc:
        print("UserError", exc)
"""
    proc = run_python(code, tmp_path)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    assert len(lines) == 3 and all(line.startswith(("UserError", "returned")) for line in lines), proc.stdout
    assert any(line.startswith("UserError") for line in lines), proc.stdout


@pytest.mark.parametrize(("at",), sample([(0.5,), (0.1,), (0.9,)], 3))
def test_p10_a_damaged_fmu_archive_under_measure_is_one_line(inputs, tmp_path, at):
    """A flipped bit in the compressed shared library of the FMU (simulate reported it; measure's extraction
    raised zipfile's BadZipFile or zlib's error)."""
    bad = copy_file(inputs["g1_fmu"], tmp_path / "bad.fmu")
    with zipfile.ZipFile(bad) as z:
        item = next(i for i in z.infolist() if i.filename.startswith("binaries/"))
    start = item.header_offset + 30 + len(item.filename.encode()) + len(item.extra)
    image = bytearray(bad.read_bytes())
    image[start + int(at * item.compress_size)] ^= 0x10
    bad.write_bytes(image)
    rc, err = run_here(["measure", bad, "--amplitudes", "2", "--frequencies", "5", "--workers", "0", "-o", "m.h5"],
                       tmp_path)
    assert_one_line(err, rc, 2, "bad.fmu", "not a readable FMU")
    assert not (tmp_path / "m.h5").exists()


@pytest.mark.parametrize("megabytes", [450])
def test_p10_train_under_a_memory_limit_is_one_line(inputs, tmp_path, megabytes):
    """An address-space limit under which torch's libraries cannot be mapped (an ImportError's traceback)."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (megabytes << 20, megabytes << 20))

    proc = run_servofmu(["train", inputs["ds"], "-o", "ann.h5"], tmp_path, tmp_path, preexec_fn=limit)
    _, err = proc.communicate(timeout=300)
    if proc.returncode == 0:
        pytest.skip(f"training fits in {megabytes} MB here")
    assert_one_line(err, proc.returncode, 2, "out of memory")
    assert not (tmp_path / "ann.h5").exists()


# ---- 10. tracebacks: seeds beyond what HDF5 and the generators hold ------------------------------------------------
@pytest.mark.parametrize("command", ["dataset", "measure", "train"])
def test_p10_a_huge_seed_is_one_line(inputs, tmp_path, command):
    seed = str(2 ** 70)
    argv = {"dataset": ["dataset", "g1", "--like", inputs["data"], "--samples", "20", "--seed", seed, "-o", "out.h5"],
            "measure": ["measure", inputs["g1_fmu"], "--amplitudes", "2", "--frequencies", "5", "--workers", "0",
                        "--noise-snr", "40", "--seed", seed, "-o", "out.h5"],
            "train": ["train", inputs["ds"], "--seed", seed, "-o", "out.h5"]}[command]
    rc, err = run_here(argv, tmp_path)
    assert_one_line(err, rc, 2, "seed", str(2 ** 70))
    assert not (tmp_path / "out.h5").exists()


# ---- 11. unbounded work: a controller sampling every 1e-300 s ------------------------------------------------------
def test_p11_an_absurd_sample_time_is_refused_before_any_work(inputs, tmp_path):
    text = inputs["controller_toml"].read_text()
    assert "sample_time = 0.001" in text
    (tmp_path / "fast.toml").write_text(text.replace("sample_time = 0.001", "sample_time = 1e-300"))
    rc, err = run_here(["controller", tmp_path / "fast.toml", "--fmi-version", "2", "-o", "c.fmu"], tmp_path)
    assert_one_line(err, rc, 2, "fast.toml", "sample_time")
    assert not (tmp_path / "c.fmu").exists()


def test_p11_a_run_of_more_steps_than_the_bound_is_refused_up_front(inputs, tmp_path):
    proc = run_servofmu(["cosim", inputs["axis"], "--stop-time", "1e6", "-o", "rec.h5"], tmp_path, tmp_path)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("cosim of 1e9 steps was not refused: it ran for a minute")
    assert_one_line(err, proc.returncode, 2, "1e+06 s", "communication steps")
    assert not (tmp_path / "rec.h5").exists()


# ---- 13. the temporary folders of the libraries servofmu calls --------------------------------------------------
def test_p13_a_stopped_fmpy_cosimulation_leaves_no_folder(inputs, tmp_path):
    """SIGTERM while FMPy runs the system: FMPy's extracted archive and FMUs go with servofmu's folder."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = run_servofmu(["cosim", inputs["axis"], "--engine", "fmpy", "--stop-time", "600", "-o", "rec.h5"],
                        tmp_path, tmp)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not any(p.name.startswith("tmp") for p in tmp.rglob("tmp*")):
        time.sleep(0.05)  # until FMPy has extracted the archive
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert_one_line(err, proc.returncode, 128 + signal.SIGTERM, "terminated")
    assert list(tmp.iterdir()) == []


def test_p13_training_leaves_no_folder(inputs, tmp_path):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = run_servofmu(["train", inputs["ds"], "-o", "ann.h5"], tmp_path, tmp)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert list(tmp.iterdir()) == []


# ---- 8. two runs on one output ------------------------------------------------------------------------------------
def test_p08_a_second_run_on_an_output_another_run_holds_is_refused(inputs, tmp_path):
    """A run that has claimed its output (checked, not yet written: the moment both of two runs started together
    are in) holds it until it ends; the other run is refused in one line and the file stays the first run's."""
    from servofmu.fileio import claim_output, output_claims

    with output_claims():
        claim_output(tmp_path / "out.h5")
        proc = run_servofmu(["measure", inputs["g1_fmu"], "--amplitudes", "2", "--frequencies", "5", "--workers", "0",
                             "-o", "out.h5"], tmp_path, tmp_path)
        _, err = proc.communicate(timeout=300)
        assert_one_line(err, proc.returncode, 2, "out.h5", "another run is writing it")
        assert not (tmp_path / "out.h5").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# ---- 9b. temporary folders of live runs in another PID namespace ----------------------------------------------
def test_p09b_a_live_runs_folder_is_kept_whatever_its_process_id(inputs, tmp_path):
    """A folder whose process ID this process cannot see (another container sharing the temporary directory)
    but whose claim a live process holds is not swept; an abandoned one is."""
    tmp = tmp_path / "tmp"
    live, dead = tmp / "servofmu-999999-build-aaaaaaaa", tmp / "servofmu-999998-build-bbbbbbbb"
    for folder in (live, dead):
        folder.mkdir(parents=True)
        (folder / "model_eqs.c").write_text("/* in use */\n")
        (folder / ".owner.lock").touch()
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, os, sys, time\n"
                               f"fd = os.open({str(live / '.owner.lock')!r}, os.O_RDWR)\n"
                               "fcntl.flock(fd, fcntl.LOCK_EX)\nprint('held', flush=True)\ntime.sleep(120)"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        proc = run_servofmu(["export", "missing.h5", "-o", "out.toml"], tmp_path, tmp)
        _, err = proc.communicate(timeout=120)
        assert_one_line(err, proc.returncode, 2, "missing.h5")
        assert (live / "model_eqs.c").is_file()
        assert not dead.exists()
    finally:
        holder.kill()
        holder.wait()


# ---- 12. names the system allows --------------------------------------------------------------------------------
@pytest.mark.parametrize("length", [250, 255])
def test_p12_an_output_name_of_up_to_255_bytes_is_written(inputs, tmp_path, length):
    name = "r" * (length - len(".toml")) + ".toml"
    rc, err = run_here(["export", inputs["result"], "--format", "toml", "-o", name], tmp_path)
    assert rc == 0, err
    assert (tmp_path / name).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


# ---- 4. a record that excites nothing ------------------------------------------------------------------------------
def test_p04_a_record_whose_input_is_zero_throughout_is_refused(inputs, tmp_path):
    """Nothing excites the plant: every parameter fits and none is determined (it was "identified" with
    zero-width intervals)."""
    import numpy as np

    t = np.arange(0, 2, 1e-3)
    np.savetxt(tmp_path / "rest.csv", np.column_stack([t, 0 * t, 0 * t]), delimiter=",", header="time,u,v",
               comments="")
    rc, err = run_here(["import", "rest.csv", "--time", "time", "--input", "u", "--output-variable", "v", "-o",
                        "rest.h5"],
                       tmp_path)
    assert rc == 0, err
    rc, err = run_here(["identify", "rest.h5", "--structure", "g1", "-o", "r.h5"], tmp_path)
    assert_one_line(err, rc, 2, "rest.h5", "input u is zero throughout")
    assert not (tmp_path / "r.h5").exists()


# ---- 6. a replaced training set that fails at its start ---------------------------------------------------------
@pytest.mark.skipif(bool(AGAINST), reason="makes the run fail in this process")
def test_p06_a_dataset_that_fails_before_its_first_chunk_leaves_the_old_file(inputs, tmp_path, monkeypatch):
    """``dataset --force`` wrote an empty training set over the previous one before any plant was simulated: a
    run that then failed (a memory limit) had lost the old file."""
    import servofmu.identification.training_set as training_set

    old = copy_file(inputs["ds"], tmp_path / "ds.h5")
    before = old.read_bytes()

    def out_of_memory(simulator, item):
        raise MemoryError

    monkeypatch.setattr(training_set, "_simulate_chunk", out_of_memory)
    rc, err = run_here(["dataset", "g1", "--like", inputs["data"], "--samples", "50", "--force", "-o", "ds.h5"],
                       tmp_path)
    assert_one_line(err, rc, 2, "servofmu dataset: error: out of memory")
    assert old.read_bytes() == before


def test_p11_a_plant_of_absurd_order_is_refused_naming_the_key(inputs, tmp_path):
    poles = ", ".join(f"[{-1.0 - k}, 0.0]" for k in range(50))
    (tmp_path / "p50.toml").write_text(f'name = "p50"\n[linear]\npoles = [{poles}]\nzeros = []\ndc_gain = 1.0\n'
                                       '[friction]\nmodel = "coulomb"\nfc_pos = 0.5\nfc_neg = 0.4\n')
    rc, err = run_here(["build", "p50.toml", "-o", "p50.fmu"], tmp_path)
    assert_one_line(err, rc, 2, "p50.toml", "linear.poles", "order 50")
    assert not (tmp_path / "p50.fmu").exists()


# ---- 5. a failed append ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("force", [False, True])
def test_p05_a_csv_value_beyond_range_is_named_and_the_file_appended_to_survives(inputs, tmp_path, force):
    """The values are checked as the CSV is read, before anything is written: the error names the CSV's line and
    column, and the records file it was to be appended to (or replace) stays as it was."""
    good = copy_file(inputs["records"], tmp_path / "good.h5")
    before = good.read_bytes()
    lines = inputs["records_csv"].read_text().splitlines()
    lines[7] = lines[7].split(",")[0] + ",1e300," + lines[7].split(",")[2]
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    mode = "--force" if force else "--append"
    rc, err = run_here(["import", "bad.csv", "--time", "time", "--input", "u", "--output-variable", "v", mode, "-o",
                        "good.h5"],
                       tmp_path)
    assert_one_line(err, rc, 2, "bad.csv", "line 8", "column 'u'", "1e+300")
    assert good.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv", "good.h5"]
