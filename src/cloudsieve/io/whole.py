"""A whole (small) cloud read into memory as the ingest stores it: :func:`read_whole`.

LAS/LAZ/COPC files are read as one ingest piece (:func:`.las_records.read_pieces`); other files are
streamed through :class:`.valid.ValidPoints`. Used by :mod:`cloudsieve.engine.small`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["read_whole"]


def read_whole(sources: list[str], chunk_size: int, drop_invalid: bool) -> tuple:
    """The cloud of *sources* (LAS/LAZ/COPC files, or one file of another format) in memory.
    Returns ``(xyz (n, 3) float64, attributes, dtypes ("xyz" included), header (LAS: "mins"/"maxs" decoded), bounds
    (2, 3), format)``. Raises EmptyInputError, InvalidPointsError, CorruptInputError, MismatchedInputsError."""
    from ..chunk import xyz_bounds
    from ..errors import EmptyInputError
    from . import concatenated, open_reader
    from .las_plan import is_las_source, plan_las
    from .las_records import decode_xyz, read_pieces
    from .valid import ValidPoints

    if not is_las_source(sources):
        with open_reader(sources[0], chunk_size=chunk_size) as reader:
            valid = ValidPoints(sources[0], drop_invalid)
            parts = [dict(chunk.arrays) for chunk in valid.chunks(reader.chunks())]
            if valid.read == 0:
                raise EmptyInputError(f"{sources[0]} holds no points")
            xyz, attrs = concatenated(parts, reader.dtypes)
            return xyz, attrs, reader.dtypes, reader.header, np.array(xyz_bounds(xyz), dtype=np.float64), reader.format
    plan = plan_las(list(sources))
    (_, _, pieces), = plan.tasks(plan.total)  # every record in one task
    names = [n for n in plan.dtypes if n != "xyz"]
    xyz, attrs, lo, hi = read_pieces(pieces, names, parallel=True, decode=(plan.scale, plan.offset))
    bounds = decode_xyz(np.array([lo, hi]), plan.scale, plan.offset)
    header = dict(plan.header)
    header["mins"], header["maxs"] = bounds[0].tolist(), bounds[1].tolist()
    return xyz, attrs, plan.dtypes, header, bounds, plan.format
