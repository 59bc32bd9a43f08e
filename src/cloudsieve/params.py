"""Every user option of cloudsieve, defined once: name, type, range, default, help.

Read by the three ways in:

- the command line: :mod:`cloudsieve.cli` builds each subcommand's arguments
  from :data:`COMMANDS` (the flag is the option's name with dashes,
  ``cluster_size`` -> ``--cluster-size``; a bool that defaults to True is
  turned off with ``--no-NAME``; old flags stay as aliases);
- the pipeline parser (:mod:`cloudsieve.pipeline`): a stage accepts the options
  of its command, checked when the file is loaded;
- the API: :func:`cloudsieve.simplify`, :func:`cloudsieve.evaluate` and
  :func:`cloudsieve.compare` call :func:`validate` first, before any work
  starts and before any file or store is created.

So the three accept and refuse the same values with the same message
(``ratio must be a number in (0, 1], got 0``).

Example
-------
>>> from cloudsieve.params import validate
>>> validate("simplify", {"method": "km", "ratio": 0.5})["cluster_size"]
400
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .core import METHODS, PAPER_THRESHOLD, RULES
from .core.kernels.warmup import TARGETS as _WARM_TARGETS
from .errors import InvalidParameterError
from .rule_default import DEFAULT_RULE, Metavar, resolve_rule
from .io import FORMATS
from .scheduler import host_port

__all__ = [
    "Option",
    "OPTIONS",
    "COMMANDS",
    "COMPARE_METHODS",
    "LOCAL_SCHEDULERS",
    "TARGET_RULES",
    "DEFAULT_RULE",
    "Metavar",
    "check",
    "validate",
    "run_record",
]

INT, FLOAT, BOOL, CHOICE, CHOICES, FORMAT, TEXT, PATH, SIZE, SCHEDULER = (
    "int", "float", "bool", "choice", "choices", "format", "text", "path", "size", "scheduler")

#: the methods :func:`cloudsieve.compare` runs: the entropy methods, then the baselines
COMPARE_METHODS = ("km", "fcm", "random", "voxel", "poisson", "fps")
#: dask's local schedulers ("synchronous" is dask's own name for "sync")
LOCAL_SCHEDULERS = ("sync", "synchronous", "threads", "processes")
#: the rules that need a ratio or a count
TARGET_RULES = ("target", "coverage", "eliminate")

_READABLE = tuple(name for name, f in FORMATS.items() if f["reader"] is not None)
_WRITABLE = tuple(name for name, f in FORMATS.items() if f["writer"] is not None)


@dataclass(frozen=True)
class Option:
    """One user option.

    Attributes
    ----------
    name : str
        The API keyword and pipeline key; the CLI flag is ``--`` + name with dashes.
    kind : str
        ``int``, ``float``, ``bool``, ``choice``, ``choices`` (a list, or a
        comma-separated string), ``format`` (a choice in any case, with or
        without a dot: "LAZ", ".laz"), ``text``, ``path``, ``size`` (bytes: an
        int or text such as "2GB") or ``scheduler``.
    default : object
        The default (None for an optional option).
    help : str
        One line for ``--help``, describing the flag: for a bool that
        defaults to True, what ``--no-NAME`` does.
    low, high : float, optional
        Range of an int or float; *low* is excluded when *low_open*.
    choices : tuple of str
        Of a ``choice`` / ``choices`` option.
    aliases : tuple of str
        Old CLI flags that still work.
    metavar : str, optional
        The CLI's name for the value.
    """

    name: str
    kind: str
    default: Any
    help: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    choices: tuple[str, ...] = ()
    aliases: tuple[str, ...] = ()
    metavar: str | None = None

    @property
    def flag(self) -> str:
        """The CLI flag: ``--cluster-size``; ``--no-surface`` for a bool that defaults to True."""
        dashed = self.name.replace("_", "-")
        return f"--no-{dashed}" if self.kind == BOOL and self.default is True else f"--{dashed}"

    def describe(self) -> str:
        """What a valid value is, as in the error messages: ``a number in (0, 1]``."""
        if self.kind == INT:
            return f"an integer >= {self.low:g}"
        if self.kind == FLOAT:
            if self.high is not None:
                return f"a number in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}]"
            return f"a finite number {'>' if self.low_open else '>='} {self.low:g}"
        return {
            BOOL: "true or false",
            CHOICE: "one of " + ", ".join(self.choices),
            FORMAT: "one of " + ", ".join(self.choices),
            CHOICES: "a list of " + ", ".join(self.choices),
            TEXT: "a string",
            PATH: "a path",
            SIZE: "a size in bytes (an integer, or text such as '2GB')",
            SCHEDULER: "sync, threads, processes or a tcp://host:port address",
        }[self.kind]


_OPTIONS = [
    # -- the method
    Option("method", CHOICE, "km", "refinement into small clusters: K-means (default) or fuzzy C-means; unused by --rule eliminate "
           "(no clusters)", choices=METHODS),
    Option("rule", CHOICE, None, "pruning rule (default: eliminate, weighted sample elimination, exactly --ratio or "
           "--count points; with --threshold alone: threshold, the paper's one-pass rule); target, coverage and "
           "eliminate need --ratio or --count", choices=RULES),
    Option("threshold", FLOAT, None, "entropy-change threshold S of the threshold/iterative rules (default "
           f"{PAPER_THRESHOLD:g} with those rules); given alone, it selects the threshold rule", low=0.0,
           metavar="S"),
    Option("ratio", FLOAT, None, "keep this share of the points, 0 < R <= 1, within 1% (exactly with --rule "
           "eliminate)", low=0.0, low_open=True,
           high=1.0, metavar="R"),
    Option("count", INT, None, "keep this many points, within 1% (exactly with --rule eliminate)", low=1, metavar="N"),
    Option("cluster_size", INT, 400, "points per small cluster (at least k_min + 2)", low=1, metavar="M"),
    Option("cell_size", INT, 200_000, "points per cell, i.e. per task; bounds a task's memory", low=1,
           metavar="POINTS"),
    Option("halo_context", BOOL, False,
           "use each cell's halo (and the whole cell) as density context instead of the small cluster alone"),
    Option("k0", FLOAT, 1.0, "k-NN rule k = max(k_min, round(k0 * sqrt(m)))", low=0.0, low_open=True),
    Option("k_min", INT, 4, "smallest k of the k-NN rule", low=1),
    Option("seed", INT, 0, "one seed for everything: same seed, same bytes", low=0),
    Option("keep_duplicates", BOOL, False,
           "keep every exact copy (same x, y, z) of a kept point; default: exact duplicates are scored once and "
           "kept once"),
    # -- the run
    Option("scheduler", SCHEDULER, None,
           "sync, threads, processes or a dask.distributed address tcp://host:port (default: local, no set-up)",
           metavar="SCHED"),
    Option("workers", INT, None, "local dask workers (default: all cores)", low=1, metavar="N"),
    Option("memory_limit", SIZE, None, "memory cap per worker, e.g. 1GB (runs a local dask cluster)", metavar="SIZE"),
    Option("store", PATH, None, "work store (path or fsspec URL), kept after success (to inspect, export or resume); "
           "checked before any work: one made from another source or with other options is refused (--overwrite "
           "discards it); default DST.cloudsieve.zarr, removed on success", metavar="PATH"),
    Option("resume", BOOL, False, "continue a crashed run from its work store"),
    Option("overwrite", BOOL, False, "replace the destination (and discard an incompatible work store)"),
    Option("chunk_size", INT, 1_000_000, "points per chunk read or written", low=1, metavar="POINTS"),
    # -- evaluation
    Option("sample", INT, None, "evaluate a uniform sample of N points per direction (95% confidence intervals)",
           low=1, metavar="N"),
    Option("surface", BOOL, True,
           "point level only: skip the surface level (ball-pivoting meshes, Metro distances, compactness)"),
    Option("tiles", INT, None, "surface tiles (default: evaluate, as many as its time budget allows; compare, 4)", low=1,
           metavar="T"),
    Option("tile_points", INT, 200_000, "at most M original points per tile (the whole cloud when it has at most M)",
           low=1, metavar="M"),
    Option("surface_budget", FLOAT, 60.0, "seconds for the surface level: tiles drawn at random, sized by a timed "
           "pilot to fit, their figures given with standard errors", low=0.0, low_open=True, metavar="SECONDS"),
    Option("surface_full", BOOL, False, "the surface level on the whole cloud (every point in a tile of about "
           "--tile-points points), no time budget: about 1 s per 3,000 original points"),
    Option("d2_sample", INT, 1_000_000, "D2 (point-to-plane) on a uniform sample of at most N points per "
           "direction, its standard error given (D1 and Chamfer on every point)", low=1, metavar="N"),
    Option("subset", BOOL, False, "the simplified cloud must be a subset of the original (error otherwise)"),
    Option("strict", BOOL, True, "compare clouds of different CRS or units, with a warning (default: refuse them)",
           aliases=("--force",)),
    Option("report_dir", PATH, None, "write report.json, report.md and plots into this folder", aliases=("--report",),
           metavar="DIR"),
    Option("error_points", INT, 2_000_000, "at most N points in errors.ply (uniform sample)", low=0, metavar="N"),
    Option("metro_samples", INT, None, "Metro samples per direction and tile (default 10 x faces, at most 500000)",
           low=1, metavar="N"),
    Option("psnr_peak", FLOAT, None, "peak p of the D1/D2 PSNR, 10*log10(3p^2/MSE) dB (default: the original's "
           "bounding-box diagonal)", low=0.0, low_open=True, metavar="P"),
    Option("reference_mesh", PATH, None, "a mesh of the scanned surface (PLY/OBJ/STL/OFF): the simplified and the "
           "original's tile meshes are also compared with it by Metro", metavar="FILE"),
    Option("methods", CHOICES, COMPARE_METHODS, "methods to compare, comma-separated", choices=COMPARE_METHODS,
           metavar="LIST"),
    # -- ingest / export
    Option("delimiter", TEXT, None, "XYZ/TXT/CSV column separator (default: sniffed)"),
    Option("columns", TEXT, None, "XYZ/TXT/CSV column names, comma separated (default: header row or x,y,z,...)"),
    Option("drop_invalid", BOOL, False, "drop points with NaN/infinite coordinates (default: refuse)"),
    Option("merge", BOOL, False, "pipelines' readers.las: the files of a glob (or a directory, list, VPC) are one cloud"),
    Option("tile_size", FLOAT, None,
           "write DST as a folder of square LAZ tiles of edge S (the CRS's units; a grid anchored at 0) and "
           "DST/index.vpc", low=0.0, low_open=True, metavar="S"),
    # -- warmup
    Option("targets", CHOICES, tuple(_WARM_TARGETS), "warm-up targets to compile, comma-separated (default: all)",
           choices=tuple(_WARM_TARGETS), metavar="LIST"),
    Option("mask", TEXT, None, "bool array of the store selecting the points to write (e.g. simplify/keep)",
           metavar="ARRAY"),
]
#: every option, by name (``format`` and compare's ``rule`` are variants, see :data:`COMMANDS`)
OPTIONS: dict[str, Option] = {o.name: o for o in _OPTIONS}

_OUTPUT_FORMAT = Option("format", FORMAT, None, "output format (default: by the destination's extension)",
                        choices=_WRITABLE)
_INPUT_FORMAT = Option("format", FORMAT, None, "input format (default: by the extension)", choices=_READABLE)
#: ingest's and export's overwrite: they have no work store
_OVERWRITE_STORE = Option("overwrite", BOOL, False, "replace an existing point store STORE")
_OVERWRITE_FILE = Option("overwrite", BOOL, False, "replace an existing destination file DST")
#: simplify's strict: off by default (evaluate's strict, on by default, is about CRS and units)
_STRICT_COUNT = Option("strict", BOOL, False,
                       "a ratio or count that cannot be met exactly is an error (exit 2), not a warning")
_RULE_LIST = Option("rule", CHOICES, None, "entropy rule(s), comma-separated; each runs once per method (eliminate: "
                    "once, no clusters) (default: eliminate, with --ratio or --count; with --threshold alone: threshold)",
                    choices=RULES, metavar="RULES")


def _command(*names: str, extra: tuple[Option, ...] = ()) -> dict[str, Option]:
    spec = {n: OPTIONS[n] for n in names}
    spec.update({o.name: o for o in extra})
    return spec


#: command -> its options, by name, in the order of ``--help``
COMMANDS: dict[str, dict[str, Option]] = {
    "simplify": _command(
        "method", "rule", "threshold", "ratio", "count", "cluster_size", "cell_size", "scheduler", "workers",
        "memory_limit", "store", "halo_context", "seed", "resume", "overwrite", "chunk_size", "k0", "k_min",
        "drop_invalid", "keep_duplicates", "tile_size", extra=(_OUTPUT_FORMAT, _STRICT_COUNT)),
    "evaluate": _command(
        "sample", "tiles", "tile_points", "surface", "report_dir", "subset", "strict", "seed", "chunk_size",
        "error_points", "metro_samples", "psnr_peak", "reference_mesh", "drop_invalid",
        "surface_budget", "surface_full", "d2_sample"),
    "compare": _command(
        "methods", "rule", "threshold", "ratio", "count", "cluster_size", "report_dir", "tiles", "tile_points",
        "surface", "seed", "metro_samples", "psnr_peak", "k0", "k_min", "drop_invalid", "keep_duplicates",
        extra=(_RULE_LIST,)),
    "ingest": _command("chunk_size", "delimiter", "columns", "drop_invalid", "overwrite",
                       extra=(_INPUT_FORMAT, _OVERWRITE_STORE)),
    "export": _command("mask", "chunk_size", "overwrite", "tile_size", extra=(_OUTPUT_FORMAT, _OVERWRITE_FILE)),
    "pipeline": _command("scheduler", "workers"),  # a pipeline's top-level keys
    "warmup": _command("targets"),
}


# ---------------------------------------------------------------- one value


def _refuse(option: Option, value: Any) -> InvalidParameterError:
    return InvalidParameterError(f"{option.name} must be {option.describe()}, got {value!r}")


def _number(option: Option, value: Any) -> float | int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise _refuse(option, value)
    if option.kind == INT:
        if not float(value).is_integer():  # 1e6 from JSON is an integer; 2.5 is not
            raise _refuse(option, value)
        value = int(value)
    else:
        value = float(value)
        if not math.isfinite(value):
            raise _refuse(option, value)
    low, high = option.low, option.high
    if low is not None and (value < low or (option.low_open and value == low)):
        raise _refuse(option, value)
    if high is not None and value > high:
        raise _refuse(option, value)
    return value


def _scheduler(option: Option, value: Any) -> str:
    if not isinstance(value, str):
        raise _refuse(option, value)
    if "://" in value:
        host_port(value)  # a tcp:// address needs a host and a port
    elif value not in LOCAL_SCHEDULERS:
        raise InvalidParameterError(
            f"unknown scheduler {value!r}: use sync, threads, processes or a tcp://host:port address")
    return value


def _size(option: Option, value: Any) -> int | str:
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)) and value >= 1:
        return int(value)
    if isinstance(value, str):
        if value == "auto":
            return value
        from dask.utils import parse_bytes

        try:
            if parse_bytes(value) >= 1:
                return value
        except (ValueError, TypeError):
            pass
    raise _refuse(option, value)


def _choices(option: Option, value: Any) -> list[str]:
    items = value.split(",") if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not all(isinstance(v, str) for v in items):
        raise _refuse(option, value)
    items = [v.strip() for v in items if v.strip()]
    bad = [v for v in items if v not in option.choices]
    if bad or not items:
        singular = option.name[:-1] if option.name.endswith("s") else option.name
        raise InvalidParameterError(f"unknown {singular}(s) {bad or items}; choose among {', '.join(option.choices)}")
    return items


def check(option: Option | str, value: Any) -> Any:
    """Validate one value of *option*; returns it normalised (Python int/float/bool/str/list).

    None is accepted where the default is None (an optional option).

    Raises
    ------
    InvalidParameterError
        ``"<name> must be <what>, got <value>"``.
    """
    if isinstance(option, str):
        option = OPTIONS[option]
    if value is None and option.default is None:
        return None
    kind = option.kind
    if kind in (INT, FLOAT):
        return _number(option, value)
    if kind == BOOL:
        if not isinstance(value, (bool, np.bool_)):
            raise _refuse(option, value)
        return bool(value)
    if kind == CHOICE:
        if not isinstance(value, str) or value not in option.choices:
            raise _refuse(option, value)
        return value
    if kind == FORMAT:
        if not isinstance(value, str) or value.lower().lstrip(".") not in option.choices:
            raise _refuse(option, value)
        return value
    if kind == CHOICES:
        return _choices(option, value)
    if kind == PATH and isinstance(value, os.PathLike):
        return os.fspath(value)
    if kind in (TEXT, PATH):
        if not isinstance(value, str) or not value:
            raise _refuse(option, value)
        return value
    if kind == SIZE:
        return _size(option, value)
    return _scheduler(option, value)


# ---------------------------------------------------------------- a command's options


def _target(o: dict) -> None:
    if o["ratio"] is not None and o["count"] is not None:
        raise InvalidParameterError(f"give ratio or count, not both (got ratio={o['ratio']}, count={o['count']})")


def _cluster_size(o: dict) -> None:
    if o["cluster_size"] < o["k_min"] + 2:
        raise InvalidParameterError(
            f"cluster_size={o['cluster_size']!r} is too small: a cluster needs at least "
            f"k_min+2={o['k_min'] + 2} points")


def _simplify(o: dict) -> None:
    rule, has_target = o["rule"], o["ratio"] is not None or o["count"] is not None
    if rule in TARGET_RULES and not has_target:
        raise InvalidParameterError(f"rule {rule!r} needs a ratio or a count")
    if rule == "threshold" and has_target:
        raise InvalidParameterError(
            f"rule 'threshold' takes a threshold only, not ratio={o['ratio']}/count={o['count']}: "
            "use rule 'target' or 'iterative'")
    _cluster_size(o)
    if o["cell_size"] < o["cluster_size"]:
        raise InvalidParameterError(f"cell_size ({o['cell_size']}) must be >= cluster_size ({o['cluster_size']})")
    if o["memory_limit"] is not None and o["scheduler"] not in (None, "processes"):
        raise InvalidParameterError(
            f"memory_limit ({o['memory_limit']}) needs worker processes: use the default scheduler or "
            f"'processes', not {o['scheduler']!r}")


def _compare(o: dict) -> None:
    _cluster_size(o)


_CROSS = {"simplify": _simplify, "compare": _compare}


def validate(command: str, values: Mapping[str, Any], *, caller: str | None = None) -> dict[str, Any]:
    """Validate the options of *command* (a key of :data:`COMMANDS`), alone and together.

    For ``simplify`` and ``compare`` the rule is resolved here, once: no
    rule given -> :data:`DEFAULT_RULE` (``eliminate``) with a ratio or a
    count, ``threshold`` with a threshold alone, an error with neither (or
    with a threshold beside a ratio/count); a threshold not given becomes
    :data:`PAPER_THRESHOLD`. The result holds the resolved values, so
    validating it again gives it back.

    Parameters
    ----------
    command : str
        ``simplify``, ``evaluate``, ``compare``, ``ingest``, ``export`` or
        ``pipeline`` (a pipeline's top-level keys).
    values : mapping of str to object
        Some of the command's options; the others take their defaults.
    caller : str, optional
        The name an error gives the call (default ``cloudsieve.<command>``;
        the command line passes ``cloudsieve simplify``).

    Returns
    -------
    dict
        Every option of the command, normalised.

    Raises
    ------
    InvalidParameterError
        An unknown option, a value out of its range, or options that
        contradict each other (ratio and count; no rule and neither a ratio, a
        count nor a threshold; rule target without a ratio or a count;
        cluster_size < k_min + 2; cell_size < cluster_size; ...).
    """
    spec = COMMANDS[command]
    unknown = sorted(set(values) - set(spec))
    if unknown:
        raise InvalidParameterError(f"{command}: unknown option(s) {unknown}; accepted: {sorted(spec)}")
    out = {name: check(opt, values.get(name, opt.default)) for name, opt in spec.items()}
    if command in _CROSS:
        _target(out)
        resolve_rule(command, out, caller or f"cloudsieve.{command}",
                     {name: OPTIONS[name].metavar for name in ("ratio", "count", "threshold")})
        _CROSS[command](out)
    return out


def run_record(options: Mapping[str, Any]) -> dict[str, Any]:
    """The options that define a simplification, as recorded in its work store (resume compares them).

    The halo_context option is recorded under its version-1 key ``"context"``,
    and keep_duplicates only when True, so work stores left by earlier runs
    still resume.
    """
    keys = ("method", "rule", "threshold", "ratio", "count", "cluster_size", "cell_size", "seed")
    record = {k: options[k] for k in keys}
    record.update(context=options["halo_context"], k0=options["k0"], k_min=options["k_min"])
    if options.get("keep_duplicates"):
        record["keep_duplicates"] = True
    return record
