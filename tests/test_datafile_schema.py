"""The data file's schemas are declared once (servofmu.measurement.schema.Stored on every field); the
declarations agree with the units the file records."""
from dataclasses import fields

from servofmu.measurement.datafile import RESULT_UNITS, ExperimentResult, Record, RecordAnalysis
from servofmu.measurement.schema import ATTRIBUTE, STORED

SCHEMAS = (ExperimentResult, RecordAnalysis, Record)


def test_every_field_declares_how_it_is_stored():
    for cls in SCHEMAS:
        for f in fields(cls):
            assert STORED in f.metadata, f"{cls.__name__}.{f.name}"


def test_every_stored_number_but_an_index_has_a_unit():
    numbers = {f.name for cls in SCHEMAS for f in fields(cls)
               if f.metadata[STORED].kind == ATTRIBUTE and f.metadata[STORED].dtype in (int, float, complex)}
    assert numbers - {"index"} <= set(RESULT_UNITS)
