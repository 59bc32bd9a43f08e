"""The user options, as data: one :class:`Option` each and :data:`COMMANDS`, the options of each command.

A leaf: it imports :mod:`cloudsieve.rule_table` and :mod:`cloudsieve.formats` only.
:mod:`cloudsieve.params` checks values against it; :mod:`cloudsieve.cli` builds its flags from it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, make_dataclass
from typing import Any

from . import rule_table as rules
from .formats import READABLE as _READABLE
from .formats import WRITABLE as _WRITABLE

__all__ = [
    "Option",
    "OPTIONS",
    "COMMANDS",
    "METHODS",
    "COMPARE_METHODS",
    "LOCAL_SCHEDULERS",
    "TARGET_RULES",
    "WARM_TARGETS",
    "MEMORY_COMMANDS",
    "OPTION_CLASSES",
    "INT", "FLOAT", "BOOL", "CHOICE", "CHOICES", "FORMAT", "TEXT", "PATH", "SIZE", "SCHEDULER", "JSON",
    "CLASSES", "CLASS_RATIOS",
]

INT, FLOAT, BOOL, CHOICE, CHOICES, FORMAT, TEXT, PATH, SIZE, SCHEDULER, JSON = (
    "int", "float", "bool", "choice", "choices", "format", "text", "path", "size", "scheduler", "json")
#: LAS classification codes ("2,9" or a list), and a ratio per code ("5=0.1,2=1.0" or a dict)
CLASSES, CLASS_RATIOS = "classes", "class_ratios"

#: the refinements into small clusters: fuzzy C-means, K-means (:mod:`cloudsieve.core.refine`)
METHODS = rules.METHODS
#: the methods :func:`cloudsieve.compare` runs: the entropy methods, then the baselines
COMPARE_METHODS = ("km", "fcm", "random", "voxel", "poisson", "fps")
#: the targets of ``cloudsieve warmup`` (:data:`cloudsieve.rule_table.TARGETS`)
WARM_TARGETS = rules.TARGETS
#: dask's local schedulers ("synchronous" is dask's own name for "sync")
LOCAL_SCHEDULERS = ("sync", "synchronous", "threads", "processes")
#: the rules that need a ratio or a count (from the registry)
TARGET_RULES = tuple(r.name for r in rules.RULES.values() if r.needs_target)
_THRESHOLD_RULES = tuple(r.name for r in rules.RULES.values() if r.takes_threshold)


def _and(names: tuple[str, ...]) -> str:
    return ", ".join(names[:-1]) + " and " + names[-1] if len(names) > 1 else "".join(names)


@dataclass(frozen=True)
class Option:
    """One user option: ``name`` (API keyword and pipeline key; flag ``--`` + name with dashes); ``kind``
    (``int``, ``float``, ``bool``, ``choice``, ``choices`` (a list or comma-separated), ``format`` (any
    case, dot optional), ``text``, ``path``, ``size`` (bytes or "2GB"), ``scheduler``); ``default`` (None:
    optional); ``help`` (one ``--help`` line describing the flag: ``--no-NAME`` for a bool defaulting to
    True); ``low``, ``high``, ``low_open`` (range); ``choices``; ``aliases`` (other flags); ``metavar``;
    ``many`` (a number option that also takes a comma-separated list).
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
    many: bool = False  # a number or a comma-separated list of them (simplify's nested outputs)

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
            CLASSES: "LAS classification codes 0..255, comma-separated (e.g. 2,9)",
            CLASS_RATIOS: "CODE=RATIO pairs, comma-separated, codes 0..255 and ratios in (0, 1] (e.g. 5=0.1,2=1.0)",
        }[self.kind]


_OPTIONS = [
    # -- the method
    Option("method", CHOICE, "km", "refinement into small clusters: K-means (default) or fuzzy C-means; unused by --rule eliminate "
           "(no clusters)", choices=METHODS),
    Option("rule", CHOICE, None, f"pruning rule (default: {rules.DEFAULT_RULE}, weighted sample elimination, exactly "
           f"--ratio or --count points; with --threshold alone: {rules.THRESHOLD_RULE}, the paper's one-pass rule); "
           f"{_and(TARGET_RULES)} need --ratio or --count", choices=rules.names()),
    Option("threshold", FLOAT, None, f"entropy-change threshold S of the {'/'.join(_THRESHOLD_RULES)} rules (default "
           f"{rules.PAPER_THRESHOLD:g} with those rules); given alone, it selects the {rules.THRESHOLD_RULE} rule",
           low=0.0, metavar="S"),
    Option("ratio", FLOAT, None, "keep this share of the points, 0 < R <= 1, within 1% (exactly with --rule "
           "eliminate); simplify: a list 0.5,0.2,0.1 writes nested outputs DST-0.5, DST-0.2, DST-0.1 (or DST's "
           "{ratio} replaced) in one run, each a subset of the one before", low=0.0, low_open=True, high=1.0,
           metavar="R", many=True),
    Option("count", INT, None, "keep this many points, within 1% (exactly with --rule eliminate); simplify: a list "
           "writes nested outputs as a list of ratios does (DST-N, or DST's {count} replaced)", low=1, metavar="N",
           many=True),
    Option("rank", BOOL, False, "store each point's rank as the extra dimension cloudsieve_rank (uint64, 0 = the "
           "most important): the first N ranks are the N points to keep, cut later by export's keep-rank option; "
           "LAS/LAZ/COPC out (a COPC's coarse octree levels then hold the lowest ranks), held in memory"),
    Option("keep_rank", INT, None, "write only the points of rank < N of a LAS/LAZ file that simplify wrote with "
           "its rank option (its cloudsieve_rank dimension)", low=0, metavar="N"),
    Option("keep_class", CLASSES, None, "keep every point of these LAS classes whole, e.g. 2,9 (exact records; "
           "they stay context for the others' crowding); --ratio/--count then apply to the points not kept whole "
           "(rule eliminate)", metavar="CODES"),
    Option("class_ratio", CLASS_RATIOS, None, "a ratio per LAS class, e.g. 5=0.1,2=1.0 (1.0: kept whole), each "
           "class's count exact; the classes not listed are thinned together to --ratio/--count (rule eliminate)", metavar="CODE=R,..."),
    Option("max_gap", FLOAT, None, "gap bound: no input point ends farther than D (CRS units, 3D) from the kept set; "
           "points are added back after the elimination, so --ratio/--count become at least that many (rule "
           "eliminate only)", low=0.0, low_open=True, metavar="D"),
    Option("density", FLOAT, None, "instead of --ratio/--count: at most D points per square unit of the horizontal "
           "plane (LAS CRS units) in every --density-cell area; an area holding more keeps exactly floor(D*R^2), "
           "the others stay whole (rule eliminate)", low=0.0, low_open=True, metavar="D"),
    Option("density_cell", FLOAT, None, "the side R of the square areas of --density, in CRS units, on a grid "
           "anchored at 0 (default 10)", low=0.0, low_open=True, metavar="R"),
    Option("density_3d", BOOL, False, "--density counts points per cubic unit in R x R x R cubes (objects), "
           "an area being a cube: floor(D*R^3) points each"),
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
    Option("storage_options", JSON, None,
           "options of the object store's fsspec filesystem for every URL, as a JSON object, e.g. "
           "'{\"endpoint_url\": \"http://host:8333\", \"profile\": \"lidar\"}' (default: the store's own chain: "
           "AWS_* environment variables incl. AWS_ENDPOINT_URL, config files, instance roles)", metavar="JSON"),
    Option("overwrite", BOOL, False, "replace what is at the destination (DST, or ingest's STORE); simplify also "
           "discards a work store left by another source or other options"),
    Option("chunk_size", INT, 1_000_000, "points per chunk read or written", low=1, metavar="POINTS"),
    # -- evaluation
    Option("sample", INT, None, "evaluate a uniform sample of N points per direction (95% confidence intervals)",
           low=1, metavar="N"),
    Option("surface", BOOL, True,
           "point level only: skip the surface level (ball-pivoting meshes, Metro distances, compactness)"),
    Option("tiles", INT, None, "surface tiles (default: evaluate 8, sized by its budget; compare 4)", low=1,
           metavar="T"),
    Option("tile_points", INT, 200_000, "at most M original points per tile (the whole cloud when it has at most M)",
           low=1, metavar="M"),
    Option("surface_budget", FLOAT, 60.0, "seconds for the surface level: random tiles sized to take this long at "
           "the rate measured on 2 cores (not timed: the same tiles anywhere), with standard errors", low=0.0, low_open=True, metavar="SECONDS"),
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
    Option("targets", CHOICES, WARM_TARGETS, "warm-up targets to compile, comma-separated (default: all)",
           choices=WARM_TARGETS, metavar="LIST"),
    Option("mask", TEXT, None, "bool array of the store selecting the points to write (e.g. simplify/keep)",
           metavar="ARRAY"),
]
#: every option, by name (``format`` and compare's ``rule`` are variants, see :data:`COMMANDS`)
OPTIONS: dict[str, Option] = {o.name: o for o in _OPTIONS}

_OUTPUT_FORMAT = Option("format", FORMAT, None, "output format (default: by the destination's extension)",
                        choices=_WRITABLE)
_INPUT_FORMAT = Option("format", FORMAT, None, "input format (default: by the extension)", choices=_READABLE)
_EXACT = Option("exact", BOOL, False, "a ratio or count that cannot be met exactly is an error (exit 2), not a warning")
_RULE_LIST = Option("rule", CHOICES, None, "entropy rule(s), comma-separated; each runs once per method (eliminate: "
                    "once, no clusters) (default: eliminate, with --ratio or --count; with --threshold alone: threshold)",
                    choices=rules.names(), metavar="RULES")


def _command(*names: str, extra: tuple[Option, ...] = ()) -> dict[str, Option]:
    spec = {n: OPTIONS[n] for n in names}
    spec.update({o.name: o for o in extra})
    return spec


#: the in-memory method's own options (its API only: no flag, no pipeline key)
_MEMORY_RULE = Option("rule", CHOICE, rules.MEMORY_RULE, "pruning rule", choices=rules.names())
_MEMORY_THRESHOLD = Option("threshold", FLOAT, rules.PAPER_THRESHOLD, "entropy-change threshold S", low=0.0)
_MEMORY = (
    Option("score", CHOICE, "delta_h", "the score S is compared with: dH or m*dH", choices=("delta_h", "unit_free")),
    Option("coverage", FLOAT, 1.0, "the coverage rule's factor", low=0.0, low_open=True),
    Option("threads", INT, None, "threads (default: all cores)", low=1),
    Option("n_nearest", INT, 8, "FCM: memberships over the L nearest centres", low=1),
    Option("dim", FLOAT, 3.0, "the dimension d of the k-NN density", low=0.0, low_open=True),
    Option("max_rounds", INT, None, "at most this many rounds", low=0),
    # eliminate() (cloudsieve.core.eliminate): RELOCATE_STEPS of core/relocate.py; MIN_CELL_POINTS is this low
    Option("relocate_steps", INT, 1, "restricted Lloyd steps after the elimination", low=0),
    Option("cell_points", INT, None, "run over cells of at most this many points above it (None: one elimination)",
           low=1_024),
)
_MEMORY_OPTIONS = {o.name: o for o in _MEMORY}


def _memory(*names: str) -> dict[str, Option]:
    spec = {n: OPTIONS[n] for n in names if n in OPTIONS}
    spec.update({n: _MEMORY_OPTIONS[n] for n in names if n in _MEMORY_OPTIONS})
    spec.update({o.name: o for o in (_MEMORY_RULE, _MEMORY_THRESHOLD) if o.name in names})
    return spec


#: command -> its options, by name, in the order of ``--help``
COMMANDS: dict[str, dict[str, Option]] = {
    "simplify": _command(
        "method", "rule", "threshold", "ratio", "count", "max_gap", "keep_class", "class_ratio", "density",
        "density_cell", "density_3d", "cluster_size", "cell_size", "scheduler", "workers", "memory_limit", "store",
        "halo_context", "seed", "resume", "overwrite", "chunk_size", "k0", "k_min", "drop_invalid", "keep_duplicates",
        "tile_size", "rank", "storage_options",
        extra=(_OUTPUT_FORMAT, _EXACT)),
    "evaluate": _command(
        "sample", "tiles", "tile_points", "surface", "report_dir", "subset", "strict", "seed", "chunk_size",
        "error_points", "metro_samples", "psnr_peak", "reference_mesh", "drop_invalid",
        "surface_budget", "surface_full", "d2_sample", "storage_options"),
    "compare": _command(
        "methods", "rule", "threshold", "ratio", "count", "cluster_size", "report_dir", "tiles", "tile_points",
        "surface", "seed", "metro_samples", "psnr_peak", "k0", "k_min", "drop_invalid", "keep_duplicates",
        "storage_options", extra=(_RULE_LIST,)),
    "ingest": _command("chunk_size", "delimiter", "columns", "drop_invalid", "overwrite", "storage_options",
                       extra=(_INPUT_FORMAT,)),
    "export": _command("mask", "keep_rank", "chunk_size", "overwrite", "tile_size", "storage_options",
                       extra=(_OUTPUT_FORMAT,)),
    "info": _command("storage_options"),
    "pipeline": _command("scheduler", "workers", "storage_options"),  # a pipeline's top-level keys
    "warmup": _command("targets"),
    # the in-memory API: cloudsieve.core.simplify_points, prune, score_points, refine_labels
    "simplify_points": _memory("method", "rule", "threshold", "ratio", "count", "cluster_size", "seed", "k0",
                               "k_min", "keep_duplicates", "score", "n_nearest", "coverage", "threads"),
    "scores": _memory("k0", "k_min", "dim", "threads"),
    "refine": _memory("method", "cluster_size", "seed", "k_min", "n_nearest", "threads"),
    "prune": _memory("rule", "threshold", "ratio", "count", "score", "k0", "k_min", "dim", "coverage", "max_rounds",
                     "threads", "keep_duplicates"),
    # cloudsieve.core.eliminate.eliminate: the eliminate rule on a whole cloud
    "eliminate": _memory("ratio", "count", "relocate_steps", "threads", "cell_points"),
}
#: the commands of the in-memory API (no resolution of a default rule: theirs is :data:`rules.MEMORY_RULE`)
MEMORY_COMMANDS = ("simplify_points", "prune", "scores", "refine", "eliminate")


def _options_class(command: str) -> type:
    """The frozen options object of *command* (``EvaluateOptions`` for ``evaluate``), one field per option with
    its default; made at first use (start-up reads this module), importable by name so it pickles."""
    name = _CLASS_NAMES[command]
    cls = make_dataclass(name, [(n, Any, field(default=o.default)) for n, o in COMMANDS[command].items()],
                         frozen=True)
    cls.__module__ = __name__
    cls.__doc__ = f"The options of {command}, validated (:func:`cloudsieve.params.options`); frozen."
    globals()[name] = cls
    return cls


class _OptionClasses(Mapping):
    """command -> its frozen options class, each made at its first use."""

    def __getitem__(self, command: str) -> type:
        name = _CLASS_NAMES[command]
        return globals().get(name) or _options_class(command)

    def __iter__(self):
        return iter(COMMANDS)

    def __len__(self) -> int:
        return len(COMMANDS)


_CLASS_NAMES = {command: "".join(word.title() for word in command.split("_")) + "Options" for command in COMMANDS}
#: command -> its frozen options class; :func:`cloudsieve.params.options` builds one at the entry
OPTION_CLASSES: Mapping[str, type] = _OptionClasses()


def __getattr__(name: str) -> type:
    """A command's options class by its name (``EvaluateOptions``), made at its first use (unpickling asks)."""
    for command, class_name in _CLASS_NAMES.items():
        if class_name == name:
            return OPTION_CLASSES[command]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
