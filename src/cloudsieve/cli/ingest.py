"""``cloudsieve ingest SRC STORE``: stream a point cloud file into a point store."""

from __future__ import annotations

import argparse
import sys

from ._common import add_options, option_values, task_runner

ORDER = 20


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "ingest",
        help="stream a LAS/LAZ/COPC/PLY/E57/XYZ file into a zarr point store",
        description=(
            "Stream SRC into a new zarr point store STORE (a folder, or an fsspec URL), chunk by "
            "chunk, keeping every attribute and the source header. Written under a temporary "
            "name and renamed when complete."
        ),
    )
    p.add_argument("src", metavar="SRC", help="input file (format by extension, or --format), or LAS/LAZ/COPC files "
                   "as one cloud: a quoted glob ('tiles/*.laz'), a directory, a list file (.lst: one path per line, "
                   "relative to the list's folder) or a VPC (.vpc)")
    p.add_argument("store", metavar="STORE", help="point store to create (folder or fsspec URL)")
    add_options(p, "ingest")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..io import open_reader
    from ..io.sources import is_many
    from ..store import ingest

    option_values(args, "ingest", check=True)
    options = {}
    if args.delimiter:
        options["delimiter"] = args.delimiter
    if args.columns:
        options["columns"] = [c.strip() for c in args.columns.split(",")]
    if is_many(args.src):
        total = None
    else:
        with open_reader(args.src, format=args.format, **options) as reader:
            total = reader.count
    with task_runner(f"ingest {args.src}", total, args.no_progress) as (runner, update):
        store = ingest.unchecked(  # validated above, with delimiter and columns
            args.src,
            args.store,
            format=args.format,
            chunk_size=args.chunk_size,
            drop_invalid=args.drop_invalid,
            overwrite=args.overwrite,
            progress=update,
            run=runner,  # LAS/LAZ/COPC sources: tasks on local worker processes
            **options,
        )
    dropped = store.group.attrs["cloudsieve"].get("dropped_invalid", 0)
    msg = f"ingested {store.count} points ({len(store.dimensions) - 1} attributes) from {args.src} into {args.store}"
    if dropped:
        msg += f"; dropped {dropped} points with NaN or infinite coordinates"
    print(msg, file=sys.stderr)
    return 0
