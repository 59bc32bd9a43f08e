"""``cloudsieve export STORE DST``: write a point store (or its kept points) to a file."""

from __future__ import annotations

import argparse
import sys

from ._common import add_options, option_values, task_runner

ORDER = 30


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export",
        help="write a point store to LAS/LAZ/COPC/PLY/XYZ",
        description=(
            "Write the points of STORE to DST (format by extension or --format) in chunks, with "
            "every attribute and, for LAS sources, the original header (counts and bounds "
            "updated). With --mask, only the points a bool array of the store keeps (e.g. "
            "simplify/keep). With --keep-rank N, STORE is a LAS/LAZ file that simplify wrote with its rank "
            "option and DST gets its N highest-ranked points (rank < N). A LAS/LAZ/COPC file as STORE with a COPC "
            "DST is written through a temporary store; a cloudsieve_rank dimension (simplify's rank option) then "
            "puts each voxel's lowest rank in the coarse octree levels. Written under a temporary name and "
            "renamed when complete."
        ),
    )
    p.add_argument("store", metavar="STORE", help="point store (folder or fsspec URL); with --keep-rank, or a COPC DST, a LAS/LAZ "
                   "(or COPC) file")
    p.add_argument("dst", metavar="DST", help="output file (.las, .laz, .copc.laz, .ply, .xyz/.txt/.csv/.pts; or "
                   "--format), or with --tile-size a folder of LAZ tiles and index.vpc")
    add_options(p, "export")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..store import export
    from ..errors import ArrayNotFoundError
    from ..store import PointStore

    option_values(args, "export", check=True)
    if args.keep_rank is not None:
        return _keep_rank(args)
    if _file_and_copc(args):
        return _file_copc(args)
    store = PointStore.open(args.store)
    if args.mask and args.mask not in store:
        raise ArrayNotFoundError(f"{args.store} has no array {args.mask!r}")
    total = store.count if args.mask is None else None  # the points written: a mask's count is not known yet
    with task_runner(f"export {args.dst}", total, args.no_progress) as (runner, update):
        export(
            store,
            args.dst,
            format=args.format,
            mask=args.mask,
            chunk_size=args.chunk_size,
            overwrite=args.overwrite,
            progress=update,
            run=runner,  # LAS/LAZ, COPC and tiles: written by local worker processes
            tile_size=args.tile_size,
        )
    print(f"exported {args.store} to {args.dst}", file=sys.stderr)
    return 0


def _keep_rank(args: argparse.Namespace) -> int:
    """``export FILE DST --keep-rank N``: the points of rank < N of a file written by ``simplify --rank``."""
    from ..errors import InvalidParameterError
    from ..io.rank import cut_rank
    from ..store import is_store

    if args.mask is not None or args.tile_size is not None or args.format is not None:
        raise InvalidParameterError("--keep-rank writes one LAS/LAZ file by DST's extension: give it without "
                                    "--mask, --tile-size or --format")
    if is_store(args.store):
        raise InvalidParameterError(f"--keep-rank cuts a LAS/LAZ file written by cloudsieve simplify --rank, not "
                                    f"the point store {args.store}")
    written = cut_rank(args.store, args.dst, args.keep_rank, overwrite=args.overwrite, chunk_size=args.chunk_size)
    print(f"exported {written:,} points of rank < {args.keep_rank:,} of {args.store} to {args.dst}", file=sys.stderr)
    return 0


def _file_and_copc(args: argparse.Namespace) -> bool:
    """True for ``export FILE DST.copc.laz``: STORE a LAS/LAZ/COPC file, not a point store, DST a COPC file."""
    from ..errors import UnknownFormatError
    from ..io import detect_format
    from ..store import is_store

    try:
        return (args.tile_size is None and detect_format(args.dst, args.format) == "copc"
                and detect_format(args.store) in ("las", "laz", "copc") and not is_store(args.store))
    except UnknownFormatError:  # the store's or DST's own errors come from the export
        return False


def _file_copc(args: argparse.Namespace) -> int:
    """``export FILE DST.copc.laz``: the file through a temporary point store (a ranked file: voxels by rank)."""
    from ..errors import InvalidParameterError
    from ..store.copc import file_to_copc

    if args.mask is not None:
        raise InvalidParameterError(f"--mask names a bool array of a point store; {args.store} is a file")
    with task_runner(f"export {args.dst}", None, args.no_progress) as (runner, update):
        out = file_to_copc(args.store, args.dst, overwrite=args.overwrite, run=runner, progress=update)
    how = " (each voxel's lowest cloudsieve_rank first)" if out["ranked"] else ""
    print(f"exported {out['points']:,} points of {args.store} to {args.dst}{how}", file=sys.stderr)
    return 0
