"""The pipeline file read and checked (stages, options validated once, ``--set``, ``$VAR`` paths, inputs):
:func:`load_pipeline` gives a :class:`Pipeline`. The format: :mod:`cloudsieve.pipeline`.
"""

from __future__ import annotations

import copy
import glob
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import InvalidParameterError, PipelineError
from .params import COMMANDS, check, validate
from .rule_table import Metavar

__all__ = ["Pipeline", "load_pipeline", "stage_options", "READERS", "WRITERS", "STAGE_COMMANDS", "PATH_OPTIONS"]

READERS = {
    "readers.las": None,
    "readers.copc": "copc",
    "readers.ply": "ply",
    "readers.e57": "e57",
    "readers.text": "xyz",
    "readers.store": "store",
}
WRITERS = {"writers.las": None, "writers.ply": "ply", "writers.text": "xyz"}
TOP_LEVEL = {"pipeline", "scheduler", "workers"}
PATH_OPTIONS = {"filename", "report_dir", "store"}
#: the options of a reader stage and of a writer stage
READER_OPTIONS = {"filename", "drop_invalid", "merge"}
WRITER_OPTIONS = {"filename", "overwrite"}
#: a variable left in a path after expansion: not set in the environment
_UNSET_VARIABLE = re.compile(r"\$(?:\{(\w+)\}|(\w+))")


@dataclass
class Pipeline:
    """A parsed, validated pipeline: ``inputs`` (the reader's glob expanded, sorted), ``reader`` (its stage),
    ``stages`` (those after it), ``options`` (top-level keys), ``source`` (for messages)."""

    inputs: list[str]
    reader: dict
    stages: list[dict]
    options: dict = field(default_factory=dict)
    source: str = "<pipeline>"
    #: the validated options of each stage after the reader that runs a command, by index in *stages*
    validated: dict = field(default_factory=dict)


#: stage type -> its command in :data:`cloudsieve.params.COMMANDS`
STAGE_COMMANDS = {"filters.entropy": "simplify", "evaluate": "evaluate", "compare": "compare"}
#: options a stage does not take: the writer gives the destination's format and overwrite, the reader drop_invalid
_FROM_WRITER = {"format", "overwrite"}
_FROM_READER = {"drop_invalid"}


def stage_options(kind: str) -> set[str]:
    """The options of stage type *kind*, from the parameter spec."""
    if kind in READERS:
        return READER_OPTIONS
    if kind in WRITERS:
        return WRITER_OPTIONS
    return set(COMMANDS[STAGE_COMMANDS[kind]]) - _FROM_WRITER - _FROM_READER


def _check_values(stage: dict, run_options: dict, label: str) -> dict | None:
    """Validate a stage's option values (types, ranges, together) as the API would; PipelineError naming the stage.

    Returns the validated options of a stage that runs a command (None for a reader or a writer)."""
    kind = stage["type"]
    extra = set(stage) - stage_options(kind) - {"type"}
    if extra:
        raise PipelineError(f"{label}: unknown option(s) {sorted(extra)}; accepted: {sorted(stage_options(kind))}")
    if kind in READERS or kind in WRITERS:
        if "filename" not in stage:
            raise PipelineError(f"{label}: a {'reader' if kind in READERS else 'writer'} needs a \"filename\"")
        if not isinstance(stage["filename"], str) or not stage["filename"]:
            raise PipelineError(f"{label}: filename must be a path, got {stage['filename']!r}")
    values = {k: v for k, v in stage.items() if k not in ("type", "filename")}
    try:
        if kind in READERS or kind in WRITERS:
            for name, value in values.items():  # overwrite, drop_invalid
                check(name, value)
        else:
            if kind == "filters.entropy":
                values = {**run_options, **values}
            return validate(STAGE_COMMANDS[kind], values, caller=kind)
    except InvalidParameterError as exc:
        # the label names the stage: only the values left to the user are reworded (ratio=R -> "ratio")
        advice = {k: v for k, v in exc.advice.items() if isinstance(v, Metavar)}
        raise PipelineError(f"{label}: {exc}", advice=advice) from None
    return None


def _apply_override(doc: dict, item: str, where: str) -> None:
    key, sep, value = item.partition("=")
    stage_type, _, option = key.rpartition(".")
    if not sep or not stage_type or not option:
        raise PipelineError(f"{where}: --set takes STAGE.OPTION=VALUE, got {item!r}")
    try:
        parsed: Any = json.loads(value)
    except json.JSONDecodeError:
        parsed = value
    if stage_type in ("pipeline", ""):
        doc[option] = parsed
        return
    matches = [s for s in doc["pipeline"] if isinstance(s, dict) and s.get("type") == stage_type]
    if not matches:
        raise PipelineError(f"{where}: --set {item!r}: the pipeline has no stage of type {stage_type!r}")
    for stage in matches:
        stage[option] = parsed


def _expand(stage: dict, label: str) -> None:
    """Expand ``$VAR`` / ``${VAR}`` in the stage's paths; PipelineError naming a variable that is not set."""
    for key in sorted(PATH_OPTIONS & set(stage)):
        if not isinstance(stage[key], str):
            continue
        value = os.path.expandvars(stage[key])
        unset = _UNSET_VARIABLE.search(value)
        if unset:
            raise PipelineError(
                f"{label}: {key} {stage[key]!r} uses the environment variable {unset[1] or unset[2]}, which is not set")
        stage[key] = value


def load_pipeline(source: str | os.PathLike | dict, *, overrides: list[str] | tuple = ()) -> Pipeline:
    """Parse and validate a pipeline file (a JSON path, or its content as a mapping).
    *overrides* are ``STAGE.OPTION=VALUE`` items applied first (VALUE parsed as JSON when valid, else a string).
    Raises PipelineError naming the file, the stage (number and type) and the problem."""
    if isinstance(source, dict):
        doc, where = copy.deepcopy(source), "<pipeline>"
    else:
        path = Path(source)
        where = str(path)
        try:
            text = path.read_text()
        except FileNotFoundError:
            raise PipelineError(f"{where}: no such pipeline file") from None
        except IsADirectoryError:
            raise PipelineError(f"{where}: is a directory, not a pipeline file") from None
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise PipelineError(f"{where}: not valid JSON: {exc.msg} at line {exc.lineno}, column {exc.colno}") from None
    if isinstance(doc, list):
        doc = {"pipeline": doc}
    if not isinstance(doc, dict) or not isinstance(doc.get("pipeline"), list):
        raise PipelineError(f"{where}: expected an object with a \"pipeline\" list of stages")
    unknown = set(doc) - TOP_LEVEL
    if unknown:
        raise PipelineError(f"{where}: unknown top-level key(s) {sorted(unknown)}; accepted: {sorted(TOP_LEVEL)}")
    for item in overrides:
        _apply_override(doc, item, where)
    stages: list[dict] = []
    for i, stage in enumerate(doc["pipeline"], 1):
        if isinstance(stage, str):
            stage = {"type": "readers.las" if i == 1 else "writers.las", "filename": stage}
        if not isinstance(stage, dict) or not isinstance(stage.get("type"), str):
            raise PipelineError(f"{where}: stage {i} must be an object with a string \"type\", got {stage!r}")
        stages.append(dict(stage))
    if not stages:
        raise PipelineError(f"{where}: the pipeline has no stages")

    reader, rest = stages[0], stages[1:]
    if reader["type"] not in READERS:
        raise PipelineError(
            f"{where}: stage 1 must be a reader ({', '.join(READERS)}), got {reader['type']!r}"
        )
    try:
        run_options = validate("pipeline", {k: v for k, v in doc.items() if k != "pipeline"})
    except InvalidParameterError as exc:
        raise PipelineError(f"{where}: {exc}") from None
    run_options = {k: v for k, v in run_options.items() if k in doc}
    _check_values(reader, run_options, f"{where}: stage 1 ({reader['type']})")
    seen: list[str] = []
    validated: dict[int, dict] = {}
    for i, stage in enumerate(rest, 2):
        kind = stage["type"]
        label = f"{where}: stage {i} ({kind})"
        if kind in READERS:
            raise PipelineError(f"{label}: only one reader is allowed, and it must come first")
        if kind not in WRITERS and kind not in STAGE_COMMANDS:
            known = ", ".join([*WRITERS, *STAGE_COMMANDS])
            raise PipelineError(f"{label}: unknown stage type; known after the reader: {known}")
        checked = _check_values(stage, run_options, label)
        if checked is not None:
            validated[i - 2] = checked
        family = "writer" if kind in WRITERS else kind
        if family in seen:
            raise PipelineError(f"{label}: only one {family} stage is allowed")
        if kind == "evaluate" and "writer" not in seen:
            raise PipelineError(f"{label}: evaluate needs a writer before it (it compares the input with the output)")
        seen.append(family)
    if "filters.entropy" in seen and "writer" not in seen:
        raise PipelineError(f"{where}: filters.entropy needs a writers.* stage to write its output")
    if "compare" in seen and ("filters.entropy" in seen or "writer" in seen):
        raise PipelineError(f"{where}: compare runs every method itself; use it without filters.entropy and writers")
    if not seen:
        raise PipelineError(f"{where}: the pipeline only reads; add filters.entropy and a writer, or compare")

    for i, stage in enumerate(stages, 1):
        _expand(stage, f"{where}: stage {i} ({stage['type']})")
    pattern = reader["filename"]
    merge = bool(reader.get("merge", False))
    if merge and (reader["type"] != "readers.las" or {"evaluate", "compare"} & set(seen)):
        raise PipelineError(f"{where}: stage 1 ({reader['type']}): merge reads LAS/LAZ/COPC files as one cloud "
                            f"(readers.las) and is not used with evaluate or compare")
    if glob.has_magic(pattern) and not merge:  # a URL's pattern lists its objects
        from . import storage

        inputs = storage.glob(pattern) if storage.is_url(pattern) else sorted(glob.glob(pattern))
    else:
        inputs = [pattern]
    if not inputs:
        raise PipelineError(f"{where}: stage 1 ({reader['type']}): no file matches {pattern!r}")
    if len(inputs) > 1:
        for stage in rest:
            for key in PATH_OPTIONS & set(stage):
                if "{stem}" not in stage[key] and "{name}" not in stage[key]:
                    raise PipelineError(
                        f"{where}: stage {stage['type']}: {key} {stage[key]!r} must contain {{stem}} or {{name}} "
                        f"because the reader matches {len(inputs)} files"
                    )
    options = {k: v for k, v in doc.items() if k != "pipeline"}
    return Pipeline(inputs=inputs, reader=reader, stages=rest, options=options, source=where, validated=validated)
