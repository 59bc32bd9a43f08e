"""``evaluate(original, simplified)``: what simplification cost, as one report.

The original is streamed (any size); the simplified cloud is loaded into memory. Levels: :mod:`.points`,
:mod:`.planes` (PSNR), :mod:`.surface`; files: :mod:`.report`.

Report keys (``report.json`` holds the same dict); ``*_pct`` is in % of ``diagonal``, the original's
bounding-box diagonal (cloud units):

- ``original``, ``simplified``: ``name``, ``count``, ``format``, ``crs`` (LAS).
- ``point`` (:func:`.points.point_errors`): ``forward`` (original -> simplified) and ``backward``, each
  ``mean``, ``rms``, ``max`` (+ ``_pct``), ``count`` and, when sampled, ``ci`` (95% intervals); ``hausdorff``,
  ``hausdorff_pct``, ``mode``, ``subset``, ``histogram``.
- ``psnr`` (:mod:`.planes`): ``peak``, ``peak_from``, ``d1`` and ``d2``, each ``forward``, ``backward``,
  ``symmetric`` (larger MSE) in dB, None for an MSE of 0; ``mse``, ``normals``, ``k_normals``.
- ``chamfer``: ``value`` = ``forward`` + ``backward`` mean squared nearest-neighbour distances (squared
  units), ``value_pct2``, ``definition``.
- ``surface`` (:func:`.surface.surface_errors`, unless ``surface=False``): Metro ``mean``, ``rms``, ``max``
  (+ ``_pct``), ``forward``, ``backward``, ``compact_share`` (share of triangles with c >= 0.6), ``compact``,
  ``vertices``, ``faces``, ``original``, ``simplified``, ``tiles``.
- ``warnings``, ``timing`` (seconds per level), ``parameters``, ``files``.
"""

from __future__ import annotations

import logging
import time
import warnings
from typing import Any

import numpy as np

from .. import staging, storage
from ..errors import IncompatibleCloudsError, IncompatibleCloudsWarning
from ..io import check_folder
from ..params import given, options
from ..progress import both, stage_bar
from ..store import DEFAULT_CHUNK_SIZE
from ._source import load_points, open_source
from .mesh import load_mesh
from .planes import field_figures
from .points import PointLevel, point_errors
from .report import write_report
from .surface import TilePlan, surface_errors
from .tiles import SAMPLE_SIZE

logger = logging.getLogger(__name__)

__all__ = ["evaluate", "run_evaluation", "check_compatible"]


def _crs_differ(a: dict | None, b: dict | None) -> tuple[str, str, str] | None:
    """(kind, a's value, b's value) when two header CRS dicts differ, else None (same or not comparable)."""
    if not a or not b:
        return None
    for kind in ("epsg", "wkt", "name"):
        va, vb = a.get(kind), b.get(kind)
        if va is not None and vb is not None:
            if kind == "epsg":
                va, vb = int(va), int(vb)
            else:
                va, vb = " ".join(str(va).split()), " ".join(str(vb).split())
            return None if va == vb else (kind, str(va), str(vb))
    return None


def check_compatible(original_header: dict, simplified_header: dict, original_bounds: np.ndarray | None,
                     simplified: np.ndarray, *, names: tuple[str, str] = ("original", "simplified"),
                     strict: bool = True) -> list[str]:
    """Flag clouds that cannot be compared: different CRS, or different units/scale.
    CRS: EPSG codes when both have one, else WKT (whitespace-normalised), else names. Units: over 10% of the
    simplified points outside the original's bounding box (enlarged by 1% of its diagonal), or a simplified
    diagonal over 3 times the original's. Returns the warnings; a mismatch raises
    :class:`~cloudsieve.errors.IncompatibleCloudsError` when *strict*, else warns and is returned among the
    messages."""
    msgs, problems = [], []
    a, b = (original_header or {}).get("crs"), (simplified_header or {}).get("crs")
    diff = _crs_differ(a, b)
    if diff is not None:
        kind, va, vb = diff
        problems.append(f"different CRS: {names[0]} has {kind} {va[:80]!r}, {names[1]} has {kind} {vb[:80]!r}")
    elif bool(a) != bool(b):
        msgs.append(f"only the {names[0] if a else names[1]} has a CRS; assuming both are in it")
    if original_bounds is not None and len(simplified):
        lo, hi = np.asarray(original_bounds[0], float), np.asarray(original_bounds[1], float)
        diag = float(np.linalg.norm(hi - lo))
        tol = 0.01 * diag
        outside = ~np.all((simplified >= lo - tol) & (simplified <= hi + tol), axis=1)
        share = float(outside.mean())
        sdiag = float(np.linalg.norm(simplified.max(0) - simplified.min(0)))
        if share > 0.10 or (diag > 0 and sdiag > 3 * diag):
            problems.append(
                f"different units or position: {100 * share:.1f}% of the {names[1]} points lie outside the "
                f"{names[0]}'s bounding box {lo.tolist()} - {hi.tolist()} (diagonal {diag:.6g}; {names[1]}'s "
                f"diagonal {sdiag:.6g})")
    for p in problems:
        if strict:
            raise IncompatibleCloudsError(f"{names[0]} vs {names[1]}: {p} (pass strict=False to compare anyway)",
                                          advice={"strict": False})
        # the caller of evaluate() (or of compare()); the command line ignores it: the log line says it
        warnings.warn(p, IncompatibleCloudsWarning, stacklevel=4)
        msgs.append(p)
    for m in msgs:
        logger.warning(m)
    return msgs


def evaluate(original: Any, simplified: Any, *, sample: int | None = None, surface: bool = True, tiles: int | None = None,
             tile_points: int = 200_000, seed: int = 0, subset: bool = False, strict: bool = True,
             report_dir: str | None = None, error_points: int = 2_000_000, chunk_size: int = DEFAULT_CHUNK_SIZE,
             metro_samples: int | None = None, client: Any = None, progress=None, drop_invalid: bool = False,
             bars=None, psnr_peak: float | None = None, reference_mesh: str | None = None,
             surface_budget: float = 60.0, surface_full: bool = False, d2_sample: int = 1_000_000,
             storage_options: dict | None = None) -> dict:
    """Evaluate a simplified cloud against its original; returns the report dict.

    Parameters
    ----------
    original : path (any format the IO layer reads, or a point store), PointStore, or ndarray (n, 3)
        Streamed chunk by chunk; never loaded whole.
    simplified : same kinds
        Loaded into memory (assumed to be the smaller cloud).
    sample : int, optional
        Point level on a uniform seeded sample of this many points per
        direction, with 95% confidence intervals; default every point.
    surface : bool
        Also compute the paper's surface level (meshes, Metro, compactness).
    tiles, tile_points : int
        T tiles of at most M original points (the whole cloud when it has at
        most M points and fits the budget); T None: 8 with a budget, else 4.
    surface_budget : float
        Seconds for the surface level: T random tiles sized by the rate
        measured on 2 cores (not timed, so results do not depend on the
        machine), with standard errors (:mod:`.tiles`).
    surface_full : bool
        The surface level on every point, in tiles of about M points, no budget.
    d2_sample : int
        D2 on a uniform seeded sample of at most this many points per
        direction, with its standard error (D1 and Chamfer stay exact).
    seed : int
        Seeds every sample and the tile choice.
    subset : bool
        Claim the simplified cloud is a subset of the original.
    strict : bool
        Refuse different CRS or units (else a warning in ``report["warnings"]``).
    report_dir : str, optional
        Write report.json, report.md, report.html, plots and errors.ply there.
    error_points : int
        At most this many original points in errors.ply (uniform seeded sample).
    chunk_size : int
        Points per chunk of the original.
    metro_samples : int, optional
        Metro samples per direction and tile (default 10 x faces, at most 500,000).
    client : distributed.Client, optional
        Run the point-level chunk tasks on this dask cluster.
    psnr_peak : float, optional
        Peak p of the D1/D2 PSNR (default: the original's bounding-box diagonal).
    reference_mesh : path, optional
        A mesh of the scanned surface (any file pymeshlab reads), compared by
        Metro with both tile meshes (``report["surface"]["reference"]``).
    progress : callable, optional
        Called with the number of original points done (point level).
    drop_invalid : bool
        Drop points with NaN or infinite coordinates (with a warning) instead
        of refusing the file.
    storage_options : dict, optional
        fsspec options for URL inputs and a URL report folder (:mod:`cloudsieve.storage`).
    bars : callable, optional
        ``bars(stage, total, unit)`` -> context yielding ``update(n)``
        (:func:`cloudsieve.progress.bar`), for "point errors" and "surface".

    Returns
    -------
    dict
        The report (keys in this module's docstring).

    Raises
    ------
    InvalidParameterError
        An option out of its range (checked first, with *report_dir*'s folder).
    EmptyInputError
        Either cloud has no point.
    IncompatibleCloudsError, NotASubsetError
        See *strict* and *subset*.
    InvalidPointsError
        NaN or infinite coordinates and not *drop_invalid*.
    """
    o = options("evaluate", given("evaluate", locals()))
    if o.report_dir is not None:
        check_folder(o.report_dir)
    return run_evaluation(original, simplified, o, client=client, progress=progress, bars=bars)


#: the options a report records under "parameters", in its order
PARAMETERS = ("sample", "surface", "tiles", "tile_points", "seed", "subset", "chunk_size", "metro_samples", "psnr_peak",
              "reference_mesh", "surface_budget", "surface_full", "d2_sample")


def las_grid(header: dict | None) -> tuple[np.ndarray, np.ndarray] | None:
    """(scales, offsets) of a LAS header (the grid its coordinates are stored on), else None."""
    header = header or {}
    if "point_format" not in header or not header.get("scales") or not header.get("offsets"):
        return None
    return np.asarray(header["scales"], dtype=np.float64), np.asarray(header["offsets"], dtype=np.float64)


def run_evaluation(original: Any, simplified: Any, options: Any, *, client: Any = None, progress=None, bars=None,
                   names: tuple[str, str] | None = None, surface_cache: dict | None = None) -> dict:
    """:func:`evaluate` on validated options (:func:`cloudsieve.params.options`).
    *names* overrides the clouds' names in the report; *surface_cache* holds the original's tile meshes across
    calls on one original (compare)."""
    with storage.using(options.storage_options):
        return _evaluation(original, simplified, options, client, progress, bars, names, surface_cache)


def _evaluation(original, simplified, o, client, progress, bars, names, surface_cache) -> dict:
    t0 = time.perf_counter()
    src = open_source(original, chunk_size=o.chunk_size, drop_invalid=o.drop_invalid)
    simp, simp_header, simp_name = load_points(simplified, what="simplified cloud", drop_invalid=o.drop_invalid)
    reference = load_mesh(o.reference_mesh) if o.reference_mesh is not None and o.surface else None
    warn = check_compatible(src.header, simp_header, src.known_bounds(), simp,
                            names=(str(src.name), str(simp_name)), strict=o.strict)
    if names is not None:
        src.name, simp_name = names
    report: dict[str, Any] = {
        "cloudsieve_report": 1,
        "original": {"name": str(src.name), "count": src.count, "format": src.format,
                     "crs": (src.header or {}).get("crs")},
        "simplified": {"name": str(simp_name), "count": int(len(simp)), "crs": (simp_header or {}).get("crs")},
        "parameters": {k: getattr(o, k) for k in PARAMETERS},
        "warnings": list(warn),
        "timing": {},
    }
    ply_parts: list[tuple[np.ndarray, np.ndarray]] = []
    t = time.perf_counter()
    with stage_bar(bars, "point errors", src.count, "pt") as bar:
        level = PointLevel(sample=o.sample, seed=o.seed, chunk_size=o.chunk_size, subset=o.subset,
                           error_points=o.error_points if o.report_dir else 0, d2_sample=o.d2_sample,
                           keep_sample=SAMPLE_SIZE if o.surface and o.surface_budget else 0)
        p = point_errors(src, simp, level, client=client, grid=las_grid(simp_header),
                         on_error_points=lambda x, e: ply_parts.append((x, e)), progress=both(bar, progress))
    uniform = p.pop("uniform_sample", None)
    report["timing"]["point"] = time.perf_counter() - t
    report["point"] = p
    report["diagonal"] = p["diagonal"]
    report["original"]["count"] = p["original_count"]
    report["psnr"], report["chamfer"] = field_figures(p["forward"], p["backward"], diagonal=p["diagonal"],
                                                      peak=o.psnr_peak, normals=p["normals"], k=p["k_normals"])
    if p["subset"] is False and not o.subset:
        logger.info("%d simplified points are not original points", p["not_in_original"])
    if o.surface:
        t = time.perf_counter()
        with stage_bar(bars, "surface", None, "tile") as bar:  # tens of seconds a tile: elapsed time shown
            tiling = TilePlan(tiles=o.tiles, tile_points=o.tile_points, seed=o.seed, budget=o.surface_budget,
                              full=o.surface_full)
            report["surface"] = surface_errors(src, simp, tiling, diagonal=p["diagonal"], samples=o.metro_samples,
                                               cache=surface_cache, progress=bar, reference=reference,
                                               sample=None if uniform is None else (uniform, p["original_count"]))
        report["timing"]["surface"] = time.perf_counter() - t
    report["timing"]["total"] = time.perf_counter() - t0
    if o.report_dir is not None:
        pts = None
        if ply_parts:
            pts = (np.concatenate([a for a, _ in ply_parts]), np.concatenate([e for _, e in ply_parts]))
        with staging.staged_folder(str(o.report_dir)) as folder:  # a URL: written here, then uploaded
            write_report(report, folder, error_points=pts, kept=simp)
        if storage.is_url(str(o.report_dir)):
            report["files"] = {k: v.replace(folder, str(o.report_dir).rstrip("/"))
                               for k, v in report["files"].items()}
    return report
