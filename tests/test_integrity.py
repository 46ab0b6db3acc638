"""The digest of servofmu's HDF5 files and the reader's bounded first pass (docs/hdf5.md, Integrity)."""
import hashlib

import h5py
import numpy as np
import pytest
from hdf5edit import edit_hdf5

from servofmu import integrity
from servofmu.errors import UserError
from servofmu.identification.results import Result, Stage, read_result, write_result
from servofmu.integrity import InspectionFailed, inspect_image
from servofmu.measurement.datafile import Record, Series, read_data_file, write_records
from servofmu.model.plant import load_plant


def listing_digest(path) -> str:
    """The digest as docs/hdf5.md describes its listing, written anew from the text: header, the root's
    attributes, then every object by path in sorted order (a dataset's type, shape and values), each followed by
    its attributes sorted by name; text as length-prefixed UTF-8."""
    def value(v) -> bytes:
        a = np.asarray(v)
        if a.dtype.kind in "OUS":
            items = [x if isinstance(x, bytes) else str(x).encode() for x in a.ravel()]
            return b"T" + repr(a.shape).encode() + b"".join(len(x).to_bytes(8, "little") + x for x in items)
        return repr(a.dtype.descr).encode() + repr(a.shape).encode() + np.ascontiguousarray(a).tobytes()

    def attributes(obj, skip=()) -> bytes:
        return b"".join(k.encode() + b"\0" + value(obj.attrs[k]) + b"\0" for k in sorted(obj.attrs) if k not in skip)

    h = hashlib.sha256(b"servofmu-content-1\0")
    with h5py.File(path, "r") as f:
        h.update(b"G/\0" + attributes(f, ("content_sha256",)))
        names = []
        f.visit(names.append)
        for name in sorted(names, key=lambda n: n.split("/")):  # depth first, siblings by name
            obj = f[name]
            if isinstance(obj, h5py.Dataset):
                h.update(b"D/" + name.encode() + b"\0" + value(obj[()]))
            else:
                h.update(b"G/" + name.encode() + b"\0")
            h.update(attributes(obj))
    return h.hexdigest()


@pytest.fixture
def files(tmp_path):
    t = np.linspace(0.0, 1.0, 101)
    record = Record(index=0, name="r", source="r.csv", source_sha256="0" * 64, kind="velocity",
                    columns={"time": "t", "u": "u", "v": "v"}, series=Series(time=t, u=np.sin(t), v=np.cos(t)),
                    sample_rate=100.0, velocity_estimate="measured", velocity_cutoff=None, analysis=None,
                    note="a note with ünïcode", intersample="zoh")
    data = tmp_path / "data.h5"
    write_records(data, [record], {"package": "servofmu", "command": "servofmu import r.csv"})
    g1 = load_plant("g1")
    theta = np.array([-10.0, 1.0, 0.5, 0.4])
    result = tmp_path / "result.h5"
    write_result(result, Result(method="pso", structure=g1, plant=g1, names=("pole1", "dc_gain", "fc_pos", "fc_neg"),
                                theta=theta, intervals=np.column_stack([theta, theta]), fitness=0.0, seconds=0.0,
                                evaluations=0, stages=(Stage("pso", None, 0.0, 0.0, 0),), history=np.zeros(3),
                                provenance={"data_file": "data.h5", "seed": 0}))
    return {"data": data, "result": result}


@pytest.mark.parametrize("kind", ["data", "result"])
def test_the_stored_digest_is_the_documented_listing(files, kind):
    with h5py.File(files[kind], "r") as f:
        stored = f.attrs["content_sha256"].decode()
    assert stored == listing_digest(files[kind])


def test_the_sha256_read_is_that_of_the_bytes(files):
    assert read_data_file(files["data"]).sha256 == hashlib.sha256(files["data"].read_bytes()).hexdigest()
    assert read_result(files["result"]).sha256 == hashlib.sha256(files["result"].read_bytes()).hexdigest()


def test_a_file_without_the_digest_reads_as_before(files):
    before = read_data_file(files["data"])
    edit_hdf5(files["data"], lambda f: None, digest=False)
    after = read_data_file(files["data"])
    assert after.records[0].note == before.records[0].note == "a note with ünïcode"
    np.testing.assert_array_equal(after.records[0].series.v, before.records[0].series.v)


def test_a_changed_text_attribute_is_refused(files):
    with h5py.File(files["result"], "r+") as f:  # a method name of the same length, in the global heap
        f.attrs["method"] = "pzo"
    with pytest.raises(UserError, match="does not match the digest"):
        read_result(files["result"])


def test_a_first_pass_that_does_not_end_is_killed(files, monkeypatch):
    """The looping global heap of the fault suite (test_p09), with 1 s of processor time instead of 10."""
    image = bytearray(files["result"].read_bytes())
    heap = image.index(b"GCOL")
    end = heap + int.from_bytes(image[heap + 8:heap + 16], "little")
    first = heap + 16
    size = int.from_bytes(image[first + 8:first + 16], "little")
    p = first
    while int.from_bytes(image[p:p + 2], "little"):
        p += 16 + -(-int.from_bytes(image[p + 8:p + 16], "little") // 8) * 8
    bit = next(b for b in range(4, 16) if p + 16 <= first + 16 + -(-(size ^ 1 << b) // 8) * 8 <= end - 16
               and not any(image[first + 16 + -(-(size ^ 1 << b) // 8) * 8:][:16]))
    image[first + 8 + bit // 8] ^= 1 << bit % 8
    monkeypatch.setattr(integrity, "BASE_DEADLINE", 1.0)
    with pytest.raises(InspectionFailed) as info:
        inspect_image(bytes(image))
    assert info.value.kind == "hang"
