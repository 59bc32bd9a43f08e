"""A whole (small) cloud read into memory as the ingest stores it: :func:`read_whole`.

LAS/LAZ/COPC files (one cloud) are read as the ingest's tasks read them, every record in one piece
(:func:`.las_plan.plan_las`, :func:`.las_records.read_pieces`), x, y, z decoded as the store decodes its
integers; another file is streamed as :func:`cloudsieve.store.ingest` streams it, NaN or infinite
coordinates refused, or dropped with *drop_invalid* (:class:`.valid.ValidPoints`). Used by the small
in-memory run (:mod:`cloudsieve.engine.small`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["read_whole"]


def read_whole(sources: list[str], chunk_size: int, drop_invalid: bool) -> tuple:
    """The cloud of *sources* (LAS/LAZ/COPC files, or one file of another format) in memory.

    Returns
    -------
    xyz : ndarray of shape (n, 3), float64
    attributes : dict of str to ndarray
    dtypes : dict
        ``{name: (dtype, shape)}``, "xyz" included (the reader's, or the plan's).
    header : dict
        With "mins" and "maxs" the decoded extremes for LAS sources.
    bounds : ndarray of shape (2, 3), float64
    format : str
        The source format.

    Raises
    ------
    EmptyInputError, InvalidPointsError, CorruptInputError, MismatchedInputsError
    """
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
