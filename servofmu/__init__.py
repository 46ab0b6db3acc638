"""servofmu: servo drives with friction — CasADi plant models as FMUs, stepped-sine measurement, PSO-ANN
identification and export.

The public API, along the pipeline (docs/api.md)::

    import servofmu as sf

    plant = sf.load_plant("g1")                          # model
    sf.build_fmu(plant, "g1.fmu")                        # FMU
    sf.measure("g1.fmu", "g1.h5")                        # measurement
    data = sf.sine_data(sf.read_data_file("g1.h5"))
    est = sf.PSOANNIdentifier(plant, method="pso").fit(data)   # identification
    sf.write_result("g1-result.h5", est.result())
    sf.export_result("g1-result.h5", "g1-identified.fmu")      # export

In a notebook, the same pipeline on objects with no file written (docs/notebook.md)::

    data = sf.Records.from_dataframe(log, time="t", input="force", output="x", reference="r", kind="position")
    selection = sf.select(data.between(0, 10), data.between(10, None), controller=drive)
    result = sf.identify(data, selection.chosen.result.structure, controller=drive)
    sf.bode([result, selection.chosen.result]); sf.control_loops(sf.tune(result, drive))

Names are loaded on first use, so that ``import servofmu`` stays cheap and each part loads only what it needs.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .version import __version__  # noqa: F401  (the one source: servofmu.version)

# name -> module that defines it
_API = {
    "UserError": "servofmu.errors",
    "Plant": "servofmu.model.plant",
    "load_plant": "servofmu.model.plant",
    "build_fmu": "servofmu.fmu.build",
    "simulate": "servofmu.simulation.fmpy_runs",
    "MeasureOptions": "servofmu.measurement.measure",
    "measure": "servofmu.measurement.measure",
    "import_records": "servofmu.measurement.records",
    "read_data_file": "servofmu.measurement.datafile",
    "BroadbandPlan": "servofmu.broadband.signals",
    "estimate_bla": "servofmu.broadband.bla",
    "h1_estimate": "servofmu.broadband.bla",
    "sine_data": "servofmu.identification.criterion",
    "make_training_set": "servofmu.identification.training_set",
    "train_from_file": "servofmu.identification.train",
    "load_ann": "servofmu.identification.ann",
    "PSOANNIdentifier": "servofmu.identification.identifier",
    "write_result": "servofmu.identification.results",
    "read_result": "servofmu.identification.results",
    "fit_casadi_nls": "servofmu.baselines.casadi_nls",
    "fit_chen2002": "servofmu.baselines.chen2002",
    "SelectOptions": "servofmu.selection.select",
    "select_files": "servofmu.selection.run",
    "select_with_report": "servofmu.commands.select",
    "export_result": "servofmu.output.export",
    "analyse_loop": "servofmu.tuning.loop",
    "TuneOptions": "servofmu.tuning.search",
    "tune_axis": "servofmu.tuning.run",
    "Records": "servofmu.api.records",
    "identify": "servofmu.api.workflow",
    "select": "servofmu.api.workflow",
    "compare_models": "servofmu.api.workflow",
    "tune": "servofmu.api.workflow",
    "control_loops": "servofmu.api.control_loops",
    "bode": "servofmu.output.figures",
    "friction_curve": "servofmu.output.figures",
    "validation_overlay": "servofmu.output.figures",
    "residual_tests": "servofmu.output.figures",
}
__all__ = list(_API)

if TYPE_CHECKING:  # what static tools see; at run time the names are loaded by __getattr__
    from .baselines.casadi_nls import fit_casadi_nls  # noqa: F401
    from .broadband.bla import estimate_bla, h1_estimate  # noqa: F401
    from .broadband.signals import BroadbandPlan  # noqa: F401
    from .baselines.chen2002 import fit_chen2002  # noqa: F401
    from .errors import UserError  # noqa: F401
    from .fmu.build import build_fmu  # noqa: F401
    from .identification.ann import load_ann  # noqa: F401
    from .identification.criterion import sine_data  # noqa: F401
    from .identification.identifier import PSOANNIdentifier  # noqa: F401
    from .identification.results import read_result, write_result  # noqa: F401
    from .identification.train import train_from_file  # noqa: F401
    from .identification.training_set import make_training_set  # noqa: F401
    from .measurement.datafile import read_data_file  # noqa: F401
    from .measurement.measure import MeasureOptions, measure  # noqa: F401
    from .measurement.records import import_records  # noqa: F401
    from .model.plant import Plant, load_plant  # noqa: F401
    from .output.export import export_result  # noqa: F401
    from .commands.select import select_with_report  # noqa: F401
    from .selection.run import select_files  # noqa: F401
    from .selection.select import SelectOptions  # noqa: F401
    from .simulation.fmpy_runs import simulate  # noqa: F401
    from .tuning.loop import analyse_loop  # noqa: F401
    from .tuning.run import tune_axis  # noqa: F401
    from .tuning.search import TuneOptions  # noqa: F401
    from .api.control_loops import control_loops  # noqa: F401
    from .api.records import Records  # noqa: F401
    from .api.workflow import compare_models, identify, select, tune  # noqa: F401
    from .output.figures import bode, friction_curve, residual_tests, validation_overlay  # noqa: F401


def __getattr__(name: str):
    if name in _API:
        value = getattr(importlib.import_module(_API[name]), name)
        globals()[name] = value  # loaded once
        return value
    raise AttributeError(f"module 'servofmu' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
