"""One run, many ratios: nested outputs of the ``eliminate`` rule, each a subset of the one before.

``ratio=(0.5, 0.2, 0.1)`` (or a tuple of counts) writes one output per value,
largest first, named by :func:`level_paths` (``small.laz`` -> ``small-0.5.laz``,
``small-0.2.laz``...; a ``{ratio}`` or ``{count}`` in DST is replaced instead).
The first output is a run at the first value, the same bytes as a run with that
ratio alone. Each next output is the run of the one before, read back as its
source, to the count of its value on the original cloud (``round(r * n)``): so
10% ⊂ 20% ⊂ 50% holds record for record, whatever path each run takes (in
memory, out of core, workers), and output k is the same bytes as
``cloudsieve simplify OUT_{k-1} OUT_k --count N_k``. It is not a run at that ratio on
the original: the radius, the cells' counts and the relocation of an elimination
depend on its count (docs/architecture.md, "Nested outputs").

With ``rank``, :func:`cloudsieve.io.rank.write_ranks` then stores the rank of
every point in every output (extra dimension ``cloudsieve_rank``). COPC outputs
with ``rank`` are written as LAZ in a temporary folder beside the first, ranked,
then each made a COPC file (:func:`cloudsieve.store.copc.export_copc`: each voxel
of a node keeps its point of lowest rank).
"""

from __future__ import annotations

import os
import posixpath
import time
from collections.abc import Callable

from ..core._validation import ratio_count
from ..errors import InvalidParameterError
from .summary import Summary

__all__ = ["listed", "level_label", "level_paths", "run_levels"]

#: the formats a level is written in: each is read back as the next level's source
_READ_BACK = ("las", "laz", "copc", "ply")


def listed(opts: dict) -> str | None:
    """The option holding a list of values (``"ratio"`` or ``"count"``: nested outputs), else None."""
    return next((name for name in ("ratio", "count") if isinstance(opts.get(name), tuple)), None)


def level_label(value: float | int) -> str:
    """A level's name in its path: ``0.5`` for a ratio, ``100000`` for a count."""
    return str(int(value)) if isinstance(value, int) else format(float(value), "g")


def level_paths(dst: str, key: str, values: tuple, folder: bool = False) -> list[str]:
    """The output of each value: ``{key}`` in *dst* replaced by its label, else the label after the name's stem
    (``small.copc.laz`` -> ``small-0.5.copc.laz``; a *folder* of tiles: ``out`` -> ``out-0.5``)."""
    labels = [level_label(v) for v in values]
    placeholder = "{" + key + "}"
    if placeholder in dst:
        return [dst.replace(placeholder, label) for label in labels]
    head, name = posixpath.split(dst.rstrip("/") if folder else dst)
    lower = name.lower()
    ext = "" if folder else ".copc.laz" if lower.endswith(".copc.laz") else os.path.splitext(name)[1]
    stem = name[: len(name) - len(ext)]
    return [posixpath.join(head, f"{stem}-{label}{ext}") if head else f"{stem}-{label}{ext}" for label in labels]


def _check_rank_size(src: str, opts: dict, key: str) -> None:
    """Refuse ``rank`` when the first output could hold more points than a run in memory: the outputs are held
    whole to rank them (:func:`cloudsieve.io.rank.write_ranks`). Counted from the headers; a source that does not
    say (XYZ) is let through."""
    from ..io.sources import expand_sources
    from .inprocess import source_points
    from .small import IN_MEMORY_POINTS

    points = source_points(expand_sources(src))
    if points is None:
        return
    first = opts[key][0] if isinstance(opts[key], tuple) else opts[key]
    kept = ratio_count(first, points) if key == "ratio" else min(int(first), points)
    if kept > IN_MEMORY_POINTS:
        raise InvalidParameterError(f"rank holds the outputs in memory to rank them: at most "
                                    f"{IN_MEMORY_POINTS:,} points in the first output, got {kept:,} ({src})")


def _check_levels(src: str, paths: list[str], opts: dict, key: str) -> None:
    """Refuse what nested outputs cannot write, before any work: formats not read back, a rank out of LAS/LAZ/COPC,
    an existing or unwritable destination after the first (the first run checks its own; ranked COPC: each)."""
    from ..atomic import check_destination
    from ..io import check_writable, detect_format
    from ..paths import local_path
    from .checks import refuse_inputs

    tiles = opts["tile_size"] is not None
    for path in paths:  # first; each run sees only its own source, and ranked COPC runs write elsewhere
        refuse_inputs(src, path.rstrip("/") if tiles else path)
    fmt = "laz" if tiles else detect_format(paths[0], opts["format"])
    if len(paths) > 1 and fmt not in _READ_BACK:
        raise InvalidParameterError(f"a list of {key}s writes LAS, LAZ, COPC, PLY or tiles (each output is the next "
                                    f"one's source), not {fmt}: {paths[0]}")
    if opts["rank"] and (tiles or fmt not in ("las", "laz", "copc") or any(local_path(p) is None for p in paths)):
        raise InvalidParameterError(f"rank writes local LAS, LAZ or COPC files, not "
                                    f"{'tiles' if tiles else fmt if local_path(paths[0]) else 'URLs'}: {paths[0]}")
    if opts["rank"]:
        _check_rank_size(src, opts, key)
    if len(set(paths)) < len(paths):
        raise InvalidParameterError(f"the outputs of {key} {opts[key]} need distinct paths, got {paths}")
    for path in paths if opts["rank"] and fmt == "copc" else paths[1:]:  # ranked COPC: the runs write elsewhere
        if tiles:
            check_destination(path, opts["overwrite"], folder=True)
        else:
            check_writable(path, opts["format"], overwrite=opts["overwrite"])


def _level_store(store: str | None, label: str) -> str | None:
    """The work store of a level after the first: the label after the store's stem; None stays None (default)."""
    if store is None:
        return None
    store = store.rstrip("/")
    return store[: -len(".zarr")] + f"-{label}.zarr" if store.endswith(".zarr") else f"{store}-{label}"


def _ranked_copc(paths: list[str], opts: dict) -> bool:
    """True when the outputs are COPC files to rank: their levels are written as LAZ first."""
    from ..io import detect_format

    return bool(opts["rank"]) and opts["tile_size"] is None and detect_format(paths[0], opts["format"]) == "copc"


def run_levels(src: str, dst: str, opts: dict, run_one: Callable[[str, str, dict], Summary]) -> Summary:
    """The nested outputs of ``opts[listed(opts)]`` (or one output with ``rank``); *run_one(src, dst, opts)* is one run.

    Returns the first level's summary, with ``outputs`` (one record per level) and the whole run's time."""
    from ..atomic import make_temp_path, remove
    from ..store.copc import file_to_copc

    t0 = time.perf_counter()
    key = listed(opts) or ("ratio" if opts["ratio"] is not None else "count")
    values = opts[key] if isinstance(opts[key], tuple) else (opts[key],)  # one value: rank alone, DST as given
    paths = level_paths(dst, key, values, opts["tile_size"] is not None) if len(values) > 1 else [dst]
    _check_levels(src, paths, opts, key)
    if not _ranked_copc(paths, opts):
        return _run_levels(src, paths, opts, key, run_one, t0)
    folder = make_temp_path(paths[0], directory=True)
    try:
        laz = [os.path.join(folder, f"level-{i}.laz") for i in range(len(paths))]
        first = _run_levels(src, laz, {**opts, "format": None}, key, run_one, t0)
        t1 = time.perf_counter()
        for level, path in zip(laz, paths):
            file_to_copc(level, path, overwrite=opts["overwrite"])
        first.seconds["copc"] = time.perf_counter() - t1
    finally:
        remove(folder)
    first.destination = paths[0]
    for record, path in zip(first.outputs, paths):
        record["destination"] = path
    first.seconds["total"] = time.perf_counter() - t0
    return first


def _run_levels(src: str, paths: list[str], opts: dict, key: str, run_one: Callable[[str, str, dict], Summary],
                t0: float) -> Summary:
    """The runs of :func:`run_levels` to *paths*, then the rank."""
    values = opts[key] if isinstance(opts[key], tuple) else (opts[key],)
    summaries, n = [], 0
    for i, (value, path) in enumerate(zip(values, paths)):
        if i == 0:
            level, source = {**opts, key: value, "rank": False}, src
        else:  # the output before as the source, to the count of this level on the original cloud
            asked = ratio_count(value, n) if key == "ratio" else min(int(value), n)
            level = {**opts, "ratio": None, "count": asked, "rank": False, "resume": False, "drop_invalid": False,
                     "store": _level_store(opts["store"], level_label(value))}
            source = paths[i - 1]
        summary = run_one(source, path, level)
        n = n or summary.points_in
        summaries.append(summary)
    first = summaries[0]
    if opts["rank"]:
        from ..io.rank import write_ranks

        t1 = time.perf_counter()
        write_ranks(paths)
        first.seconds["rank"] = time.perf_counter() - t1
    first.outputs = [{key: value, "destination": path, "kept": s.kept, "seconds": s.seconds.get("total", 0.0)}
                     for value, path, s in zip(values, paths, summaries)]
    first.seconds["total"] = time.perf_counter() - t0
    return first
