"""What an identification is given, read and checked once: the data (a data file's path or a DataFile held in
memory), the structure (a plant file, an example's name or a Plant), the network, and the provenance a result
records of them."""
from __future__ import annotations

from ..errors import UserError
from ..measurement.datafile import DataFile, as_data_file, data_name
from ..measurement.duplicates import file_items, refuse_repeats
from ..model.plant import Plant, load_plant
from .ann import AnnModel, load_ann
from .criterion import check_structure, record_data, sine_data
from .identifier import check_method
from .methods import NEEDS_ANN
from .prior import identified_names

__all__ = ["load_identification_inputs", "identification_provenance", "structure_of", "structure_name"]


def structure_of(structure) -> Plant:
    """``structure`` itself when it is a Plant, else the plant file or example it names."""
    return structure if isinstance(structure, Plant) else load_plant(structure)


def structure_name(structure) -> str:
    """What names a structure in provenance: its file or example name, or for a Plant its source."""
    return (structure.source or structure.name) if isinstance(structure, Plant) else str(structure)


def load_identification_inputs(data_path, structure_path, ann_path, method: str, command: str = "",
                               skip: float = 0.0):
    """(structure, SineData | RecordData, AnnModel | None, provenance) for an identification.

    ``data_path``, ``structure_path`` and ``ann_path`` are files or the objects read from them (DataFile, Plant,
    AnnModel).  Refuses a structure that does not match the plant the data was measured on (when the data says
    which), and a network trained for another plan or structure.  ``skip``: seconds left out at the start of every
    record.
    """
    check_method(method)
    structure = structure_of(structure_path)
    ds = as_data_file(data_path)
    where = data_name(data_path)
    check_structure(structure, ds, f"the structure {structure_name(structure_path)}")
    refuse_repeats(file_items(ds), "import each record once")
    if ds.kind == "records":
        data = record_data(ds, skip)
    else:
        if skip:
            raise UserError(f"{where}: skip applies to records, not to stepped-sine experiments")
        if not ds.experiments:
            raise UserError(f"{where}: the file holds no experiments")
        data = sine_data(ds)
    ann = None
    if method in NEEDS_ANN:
        if ann_path is None:
            raise UserError(f"method {method} needs a trained network (made by `servofmu dataset` and "
                            "`servofmu train`); or use method pso")
        ann = ann_path if isinstance(ann_path, AnnModel) else load_ann(ann_path)
        if list(ann.layout.parameter_names) != identified_names(structure):
            raise UserError(f"{ann_path if not isinstance(ann_path, AnnModel) else 'the network'} estimates "
                            f"{', '.join(ann.layout.parameter_names)}; the structure "
                            f"{structure_name(structure_path)} has {', '.join(identified_names(structure))}")
    ann_name = "" if ann_path is None or isinstance(ann_path, AnnModel) else ann_path
    return structure, data, ann, identification_provenance(ds, structure_name(structure_path), command, ann_name,
                                                           skip)


def identification_provenance(data: DataFile, structure_path, command: str, ann_path=None, skip: float = 0.0,
                              **extra) -> dict:
    """What a result records of its inputs: the data read (its path or name, the SHA-256 of the very bytes that
    were read and identified from — of the records' samples for data held in memory — and the digest of every
    record's or experiment's samples: servofmu.measurement.duplicates), the structure, the network, the command,
    the skipped seconds and ``extra`` entries."""
    provenance = {"data_file": str(data.path), "data_sha256": data.sha256, "structure_file": str(structure_path),
                  "ann_file": str(ann_path) if ann_path else "", "command": command,
                  "data_digests": [digest for _, digest in file_items(data)], **extra}
    if skip:
        provenance["skip"] = skip
    return provenance
