"""``cloudsieve run PIPELINE``: run a declarative pipeline file."""

from __future__ import annotations

import argparse

ORDER = 70


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "run",
        help="run a pipeline file (readers, filters.entropy, writers, evaluate, compare)",
        description=(
            "Run a JSON pipeline: an ordered list of stages like PDAL's pipelines. "
            "See pipelines/ in the project for examples and cloudsieve.pipeline for the format."
        ),
    )
    p.add_argument("pipeline", metavar="PIPELINE", help="the pipeline's JSON file")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="STAGE.OPTION=VALUE",
        help="override an option, e.g. --set readers.las.filename=scan.laz (repeatable; VALUE parsed as JSON when it is)",
    )
    p.add_argument("--check", action="store_true",
                   help="validate the pipeline and check that its inputs can be read; run nothing")
    p.add_argument("--no-progress", action="store_true", help="no progress bars (nor, without a terminal, the log "
                                                                 "line of each stage)")
    p.set_defaults(func=run, wording=stage_wording(None))


def stage_wording(pipeline):
    """How ``cloudsieve run`` words an option an error advises: the stage key that sets it, and its ``--set``
    (``"overwrite": true in the writers.las stage (or --set writers.las.overwrite=true)``)."""
    def wording(name, value):
        import json

        from ..rule_table import Metavar
        from ..pipeline import stage_options

        if isinstance(value, Metavar):  # a value left to the user: the key alone
            return f'"{name}"'

        stages = [] if pipeline is None else [pipeline.reader, *pipeline.stages]
        owner = next((s["type"] for s in stages if name in stage_options(s["type"])), None)
        text = json.dumps(value)
        if owner is None:
            return f'"{name}": {text} in its stage'
        return f'"{name}": {text} in the {owner} stage (or --set {owner}.{name}={text})'

    return wording


def run(args: argparse.Namespace) -> int:
    from functools import partial

    from ..pipeline import check_inputs, load_pipeline, run_pipeline
    from ..progress import bar

    pipeline = load_pipeline(args.pipeline, overrides=args.overrides)
    args.wording = stage_wording(pipeline)
    if args.check:
        check_inputs(pipeline)
        print(f"{args.pipeline}: valid; {len(pipeline.inputs)} input(s)")
        for path in pipeline.inputs:
            print(f"  {path}")
        print("stages: " + " -> ".join([pipeline.reader["type"], *(s["type"] for s in pipeline.stages)]))
        return 0
    bar = partial(bar, enabled=not args.no_progress)
    with bar("pipeline", None) as progress:
        results = run_pipeline(pipeline, progress=progress, bars=bar)
    for entry in results:
        line = f"{entry['input']}"
        summary, report = entry["summary"], entry["report"]
        if entry["output"]:
            line += f" -> {entry['output']}"
        if summary is not None and hasattr(summary, "kept"):
            line += f": kept {summary.kept:,} of {summary.points_in:,} points"
        print(line)
        if isinstance(report, dict) and "markdown" in report:  # compare
            print(report["markdown"])
        elif isinstance(report, dict) and "point" in report:  # evaluate
            fwd = report["point"]["forward"]
            print(f"  point error: mean {fwd['mean_pct']:.4f}%, RMS {fwd['rms_pct']:.4f}%, max {fwd['max_pct']:.4f}% of the diagonal")
    return 0
