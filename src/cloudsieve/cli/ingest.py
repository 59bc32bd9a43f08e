"""``cloudsieve ingest SRC STORE``: stream a point cloud file into a point store."""

from __future__ import annotations

import argparse
import sys

from ..store import DEFAULT_CHUNK_SIZE
from ._common import FORMATS, positive_int

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
    p.add_argument("src", metavar="SRC", help="input file (format by extension, or --format)")
    p.add_argument("store", metavar="STORE", help="point store to create (folder or fsspec URL)")
    p.add_argument("--format", choices=FORMATS, help="input format (default: from the extension)")
    p.add_argument("--chunk-size", type=positive_int, default=DEFAULT_CHUNK_SIZE, metavar="N", help=f"points per chunk (default {DEFAULT_CHUNK_SIZE})")
    p.add_argument("--delimiter", help="XYZ/TXT/CSV column separator (default: sniffed)")
    p.add_argument("--columns", help="XYZ/TXT/CSV column names, comma separated (default: header row or x,y,z,...)")
    p.add_argument("--drop-invalid", action="store_true", help="drop points with NaN/infinite coordinates (default: refuse)")
    p.add_argument("--overwrite", action="store_true", help="replace STORE if it exists")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .. import progress
    from ..store import ingest
    from ..io import open_reader

    options = {}
    if args.delimiter:
        options["delimiter"] = args.delimiter
    if args.columns:
        options["columns"] = [c.strip() for c in args.columns.split(",")]
    with open_reader(args.src, format=args.format, **options) as reader:
        total = reader.count
    with progress.bar(f"ingest {args.src}", total, enabled=not args.no_progress) as update:
        store = ingest(
            args.src,
            args.store,
            format=args.format,
            chunk_size=args.chunk_size,
            drop_invalid=args.drop_invalid,
            overwrite=args.overwrite,
            progress=update,
            **options,
        )
    dropped = store.group.attrs["cloudsieve"].get("dropped_invalid", 0)
    msg = f"ingested {store.count} points ({len(store.dimensions) - 1} attributes) from {args.src} into {args.store}"
    if dropped:
        msg += f"; dropped {dropped} points with NaN or infinite coordinates"
    print(msg, file=sys.stderr)
    return 0
