"""Declarative pipelines: an ordered list of stages, like PDAL's JSON pipelines (the stages, their order
and options: README, "Pipelines").

Options are validated at load (:mod:`cloudsieve.pipeline_load`), naming the
stage, and the stages run on them. ``$VAR`` in paths is expanded (unset: an
error); :func:`check_inputs` checks the inputs; ``--set STAGE.OPTION=VALUE``
overrides any option.
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
    """Raise PipelineError unless the reader can read every input of *pipeline* (file system checks only).
    The message names the pipeline, stage 1 and the input: ``"simplify.json: stage 1 (readers.las): input.laz: no
    such file"``."""
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
    *progress* ``(n)`` gets each input's points once done; *bars* as :func:`cloudsieve.progress.bar`. Returns one
    dict per input: ``input``, ``output`` (or None), ``summary``, ``report``."""
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
                if entry["summary"].outputs:  # nested outputs (a list of ratios): later stages read the first
                    dst = entry["summary"].outputs[0]["destination"]
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
