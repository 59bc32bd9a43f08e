"""Declarative pipelines: an ordered list of stages, like PDAL's JSON pipelines.

A pipeline file is JSON::

    {
      "pipeline": [
        {"type": "readers.las", "filename": "scans/*.laz"},
        {"type": "filters.entropy", "method": "fcm", "rule": "iterative", "threshold": 0.001},
        {"type": "writers.las", "filename": "out/{stem}.laz"},
        {"type": "evaluate", "report_dir": "out/{stem}-report"}
      ]
    }

Stages, in this order:

``readers.*`` (exactly one, first)
    ``readers.las``, ``readers.copc``, ``readers.ply``, ``readers.e57``,
    ``readers.text`` or ``readers.store`` (a cloudsieve point store).
    ``filename`` may be a glob; the pipeline then runs once per matching file.
    ``merge`` (default false, ``readers.las``): the glob's files, or a
    directory, list file or VPC as ``filename``, are one cloud
    (:mod:`cloudsieve.io.sources`), simplified in one run; ``{stem}`` is then
    the name of the folder that holds them. Not with ``evaluate`` or ``compare``.
    ``drop_invalid`` (default false): drop the points with NaN or infinite
    coordinates instead of refusing the file, in every stage that reads it.
    A bare string stands for a reader chosen by extension (as in PDAL).
``filters.entropy`` (at most one)
    The simplification; its options are those of :func:`cloudsieve.simplify`
    (``method``, ``rule``, ``threshold``, ``ratio``, ``count``,
    ``cluster_size``, ``cell_size``, ``seed``, ``halo_context``, ...) but
    ``format`` and ``overwrite`` (the writer's) and ``drop_invalid`` (the reader's).
    Without ``rule``, ``ratio`` or ``count`` selects ``eliminate`` (exactly
    that many points) and ``threshold`` alone the paper's ``threshold`` rule;
    with none of them the stage is refused when the file is loaded.
``writers.*`` (one, required after ``filters.entropy``)
    ``writers.las`` (also LAZ, by extension), ``writers.ply``, ``writers.text``.
    ``filename`` may use ``{stem}`` (the input's name without extensions) and
    ``{name}`` (its file name); it must use one of them when the reader's glob
    matches several files. ``overwrite`` (default false) replaces an existing file.
``evaluate`` (optional, after the writer)
    Evaluates the written cloud against the input; options are the keyword
    arguments of :func:`cloudsieve.evaluate` (``report_dir``, ``sample``, ...).
``compare`` (optional, instead of filters/writers)
    Runs :func:`cloudsieve.compare` on the input: the paper's comparison of KM,
    FCM and the baselines at equal count.

Top-level keys beside ``"pipeline"``: ``"scheduler"`` and ``"workers"`` apply to
every stage that runs on dask.

Every option is checked when the file is loaded, as the API checks it (names,
types, ranges, options that contradict each other: :mod:`cloudsieve.params`),
so a bad value fails before any stage runs, naming the stage; ``filters.entropy``,
``evaluate`` and ``compare`` then run on the options validated there
(:func:`cloudsieve.engine.simplify.run_simplify`,
:func:`cloudsieve.evaluate.evaluation.run_evaluation`,
:func:`cloudsieve.evaluate.compare.run_compare`), checked once. Relative paths are relative to the working
folder, as in PDAL; ``$VAR`` and ``${VAR}`` in them are expanded from the
environment (the shipped pipelines use ``$CLOUDSIEVE_DATA``); a variable
that is not set is an error. :func:`check_inputs` (``cloudsieve run --check``,
and :func:`run_pipeline` before any stage) checks that every input can be
read by the reader. Any option can be overridden from the command line with
``--set STAGE.OPTION=VALUE`` (``--set readers.las.filename=scan.laz``).
"""
from __future__ import annotations

import glob
import logging
import os
from pathlib import Path
from typing import Any

from . import storage
from .errors import CloudsieveError, PipelineError, UnknownFormatError
from .params_spec import OPTION_CLASSES
from .pipeline_load import READERS, WRITERS, Pipeline, load_pipeline, stage_options

__all__ = ["Pipeline", "load_pipeline", "check_inputs", "run_pipeline", "stage_options"]

log = logging.getLogger(__name__)


def _fill(value: Any, src: str) -> Any:
    if not isinstance(value, str):
        return value
    from .io.sources import is_many

    if is_many(src) and not os.path.isdir(src) and glob.has_magic(src):
        src = os.path.dirname(src) or "."  # a merged glob: named after its folder
    name = os.path.basename(os.path.abspath(src).rstrip("/"))
    stem = name.split(".")[0] if not name.startswith(".") else name
    return value.replace("{stem}", stem).replace("{name}", name)


def _convert(src: str, dst: str, out_format: str | None, overwrite: bool, drop_invalid: bool = False) -> int:
    """A pipeline with a writer and no filter: a conversion streamed through a temporary store; its points."""
    import tempfile

    from .store import export, ingest

    with tempfile.TemporaryDirectory(prefix="cloudsieve-convert-") as tmp:
        store = ingest(src, os.path.join(tmp, "store.zarr"), drop_invalid=drop_invalid)
        export(store, dst, format=out_format, overwrite=overwrite)
        return store.count


def check_inputs(pipeline: Pipeline) -> None:
    """Raise unless the reader can read every input of *pipeline*; nothing is read but the file system.

    Each input exists, is a file (a point store for ``readers.store``), is
    not empty, can be opened, and its extension is one the reader reads.

    Raises
    ------
    PipelineError
        Naming the pipeline, stage 1 and the input:
        ``"simplify.json: stage 1 (readers.las): input.laz: no such file"``.
    """
    from .io import check_readable, detect_format
    from .store import is_store

    kind = pipeline.reader["type"]
    label = f"{pipeline.source}: stage 1 ({kind})"
    accepted = {"readers.las": ("las", "laz", "copc")}.get(kind, (READERS[kind],))
    from .io.sources import expand_sources

    inputs = pipeline.inputs
    if pipeline.reader.get("merge", False):
        try:
            inputs = expand_sources(inputs[0])
        except CloudsieveError as exc:
            raise PipelineError(f"{label}: {exc}") from None
    for path in inputs:
        try:
            if kind == "readers.store":
                check_readable(path)
                if not is_store(path):
                    raise PipelineError(f"{label}: {path} is not a point store")
                continue
            check_readable(path, format=accepted[0])  # exists, a file, not empty, readable
            found = detect_format(path)
        except UnknownFormatError:
            ext = os.path.splitext(os.path.basename(path.rstrip("/")))[1] or "(none)"
            raise PipelineError(f"{label} cannot read {path}: unknown extension {ext}") from None
        except PipelineError:
            raise
        except CloudsieveError as exc:
            raise PipelineError(f"{label}: {exc}") from None
        if found not in accepted:
            raise PipelineError(f"{label} cannot read {path}: its extension says {found}")


def run_pipeline(pipeline: Pipeline, *, client: Any = None, progress: Any = None, bars: Any = None) -> list[dict]:
    """Run a pipeline, once per input file.

    *progress* ``(n)`` is called with an input's points when it is done (each
    input counted once); *bars* ``(stage, total, unit)`` gives each stage of
    the simplification and the evaluation its own bar (see
    :func:`cloudsieve.progress.bar`).

    Returns
    -------
    list of dict
        One entry per input: ``{"input": path, "output": path or None,
        "summary": ..., "report": ...}``.
    """
    from .params import check

    # the pipeline's top-level key (validated at load), for every stage
    with storage.using(check("storage_options", pipeline.options.get("storage_options"))):
        return _run_pipeline(pipeline, client=client, progress=progress, bars=bars)


def _run_pipeline(pipeline: Pipeline, *, client: Any, progress: Any, bars: Any) -> list[dict]:
    check_inputs(pipeline)
    drop_invalid = bool(pipeline.reader.get("drop_invalid", False))
    results = []
    for src in pipeline.inputs:
        entry: dict[str, Any] = {"input": src, "output": None, "summary": None, "report": None}
        points = 0
        filt = next((s for s in pipeline.stages if s["type"] == "filters.entropy"), None)
        writer = next((s for s in pipeline.stages if s["type"] in WRITERS), None)
        if writer is not None:
            dst = _fill(writer["filename"], src)
            if not storage.is_url(dst):  # an object store has no folders to make
                Path(dst).parent.mkdir(parents=True, exist_ok=True)
            out_format = WRITERS[writer["type"]]
            overwrite = bool(writer.get("overwrite", False))
            log.info("pipeline %s: %s -> %s", pipeline.source, src, dst)
            if filt is None:
                points = _convert(src, dst, out_format, overwrite, drop_invalid)
            else:  # the options validated at load (run_options merged), the paths filled
                from .engine.simplify import run_simplify

                opts = {k: _fill(v, src) for k, v in pipeline.validated[pipeline.stages.index(filt)].items()}
                opts.update(format=out_format, overwrite=overwrite, drop_invalid=drop_invalid)
                entry["summary"] = run_simplify(src, dst, opts, client=client, bars=bars)
                points = entry["summary"].points_in
            entry["output"] = dst
        for i, stage in enumerate(pipeline.stages):
            if stage["type"] == "evaluate":  # on the options validated at load, as filters.entropy
                from .evaluate.evaluation import run_evaluation
                from .io import check_folder

                opts = {k: _fill(v, src) for k, v in pipeline.validated[i].items()}
                opts["drop_invalid"] = drop_invalid
                if opts["report_dir"] is not None:
                    check_folder(opts["report_dir"])
                entry["report"] = run_evaluation(src, entry["output"], OPTION_CLASSES["evaluate"](**opts), bars=bars)
            elif stage["type"] == "compare":  # on the options validated at load, as evaluate
                from .evaluate.compare import run_compare

                opts = {k: _fill(v, src) for k, v in pipeline.validated[i].items()}
                opts["drop_invalid"] = drop_invalid
                entry["report"] = run_compare(src, OPTION_CLASSES["compare"](**opts))
                points = points or entry["report"]["points"]
        if progress is not None:
            progress(points)
        results.append(entry)
    return results
