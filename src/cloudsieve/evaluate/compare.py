"""``compare``: entropy simplification vs baselines at the same output count, in memory, one table.

The count is ``count`` or ``ratio`` x n, else the first entropy method's; each method is evaluated with
:func:`cloudsieve.evaluate` (the original's meshes built once).
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .. import staging, storage
from ..atomic import write_text
from ..errors import CloudsieveError, EmptyInputError, InvalidParameterError
from ..io import check_folder
from ..core.rules import MEMORY_RULE
from ..core.rules import get as get_rule
from ..params import COMPARE_METHODS, OPTION_CLASSES, given, options
from ._source import load_points
from .baselines import BASELINES, run_method
from .evaluation import run_evaluation
from .report import border_per_face, db, fmt, holes_note, pct, plot_compactness, plot_point_errors, write_json

logger = logging.getLogger(__name__)

__all__ = ["compare", "run_compare", "compare_runs", "compare_markdown", "METHODS"]

METHODS = COMPARE_METHODS


def _row(name: str, report: dict | None, kept: int, seconds: float, error: str | None = None) -> dict:
    row: dict[str, Any] = {"method": name, "kept": kept, "time": seconds}
    if error:
        row["error"] = error
        return row
    p, s = report["point"], report.get("surface")
    row.update({"point_mean_pct": p["forward"]["mean_pct"], "point_rms_pct": p["forward"]["rms_pct"],
                "point_max_pct": p["forward"]["max_pct"], "hausdorff_pct": p["hausdorff_pct"],
                "d1_psnr": report["psnr"]["d1"]["forward"], "d2_psnr": report["psnr"]["d2"]["forward"],
                "chamfer": report["chamfer"]["value"]})
    if s:
        row.update({"metro_mean_pct": s["mean_pct"], "metro_max_pct": s["max_pct"], "metro_rms_pct": s["rms_pct"],
                    "compact_share": s["compact_share"], "compact": s["compact"], "vertices": s["vertices"],
                    "faces": s["faces"]})
        on = s.get("on_surface") or {}
        row.update({"metro_surface_mean_pct": on.get("mean_pct"), "metro_surface_excluded": on.get("excluded_share")})
    return row


def _margin_lines(rows: list[dict]) -> list[str]:
    """Each entropy row's forward D1/D2 PSNR against the best baseline's (dB), one line each."""
    ok = [r for r in rows if "error" not in r]
    base = [r for r in ok if r["method"] in BASELINES]
    out = []
    for r in ok:
        if r["method"] in BASELINES or not base:
            continue
        figs = []
        for key, label in (("d1_psnr", "D1"), ("d2_psnr", "D2")):
            best = max(base, key=lambda b: float(b[key]))
            if not np.isfinite(float(r[key]) - float(best[key])):  # an error of 0 (infinite PSNR) on one side
                continue
            figs.append(f"{label} {float(r[key]) - float(best[key]):+.2f} dB (best baseline {best['method']})")
        if figs:
            out.append(f"{r['method']} against the best baseline, forward PSNR: " + ", ".join(figs) + ".")
    return ["", *out] if out else []


def compare_markdown(result: dict) -> str:
    """The comparison table (Markdown), as in report.md."""
    n = result["points"]
    lines = [f"# cloudsieve compare: {os.path.basename(str(result['source']))}", "",
             f"{fmt(n)} points, bbox diagonal {fmt(result['diagonal'])}; target {fmt(result['count'])} kept "
             f"({100.0 * result['count'] / n:.1f}%); rule `{result['rule']}`; seed {result['seed']}.", "",
             "Point errors: original → simplified, exact, % of the bbox diagonal. Metro: ball-pivoting meshes, "
             "the larger of both directions, % of the diagonal; on surface: leaving out the samples that face a hole "
             "of the original's mesh. c ≥ 0.6: share of the simplified mesh's triangles "
             f"(original mesh: {pct(result.get('original_compact_share'))}; border edges per face: "
             f"{border_per_face(result.get('original_mesh') or {})}).", "",
             f"D1/D2 PSNR: MPEG pc_error's, original → simplified, dB, peak {fmt(result.get('psnr_peak'))} "
             f"({'the bbox diagonal' if result.get('psnr_peak_from') == 'diagonal' else 'given'}). Chamfer: mean "
             "squared nearest-neighbour distance both ways, summed (squared cloud units).", "",
             "| method | kept | time (s) | point mean % | point RMS % | point max % | D1 PSNR | D2 PSNR | Chamfer | "
             "Metro mean % | Metro max % | Metro RMS % | Metro mean % on surface | c ≥ 0.6 |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["rows"]:
        if "error" in r:
            lines.append(f"| {r['method']} | - | - | {r['error']} | | | | | | | | | | |")
            continue
        lines.append(f"| {r['method']} | {fmt(r['kept'])} | {r['time']:.2f} | {fmt(r['point_mean_pct'])} | "
                     f"{fmt(r['point_rms_pct'])} | {fmt(r['point_max_pct'])} | {db(r['d1_psnr'])} | "
                     f"{db(r['d2_psnr'])} | {fmt(r['chamfer'])} | {fmt(r.get('metro_mean_pct'))} | "
                     f"{fmt(r.get('metro_max_pct'))} | {fmt(r.get('metro_rms_pct'))} | {fmt(r.get('metro_surface_mean_pct'))} | {pct(r.get('compact_share'))} |")
    lines += _margin_lines(result["rows"])
    note = holes_note(result.get("original_mesh") or {})
    lines += ["", f"> {note}", ""] if note else [""]
    return "\n".join(lines)


def _write_html(path: Path, xyz: np.ndarray, kept: dict[str, np.ndarray], md: str, files: dict, seed: int) -> str:
    """compare's report.html: each method's error view and kept points (at most
    ``VIEW_POINTS / methods``, at least 20,000), over one shared original sample."""
    from scipy.spatial import cKDTree

    from .html import VIEW_POINTS, view_sample, write_html

    shown = xyz[view_sample(len(xyz), seed=seed)]
    per = max(VIEW_POINTS // max(len(kept), 1), 20_000)
    errors, points = {}, {}
    for label, idx in kept.items():
        errors[label] = cKDTree(xyz[idx]).query(shown, k=1, workers=-1)[0]
        points[label] = xyz[idx][view_sample(len(idx), size=per, seed=seed)]
    images = {k: v for k, v in files.items() if v.endswith(".png")}
    bounds = np.stack([xyz.min(axis=0), xyz.max(axis=0)])
    return write_html(path, "cloudsieve compare", md, images=images, original=shown, errors=errors, kept=points,
                      bounds=bounds)


def compare_runs(methods, rules) -> list[tuple[str, str, str | None]]:
    """The rows of a comparison: (row name, method, rule or None), entropy methods first; a rule without
    clusters (``eliminate``) runs once, under its own name."""
    runs = []
    first = next((m for m in methods if m in ("km", "fcm")), None)
    for m in methods:
        if m in ("km", "fcm"):
            for r in rules:
                if not get_rule(r).clusters:  # one row, named after the rule
                    if m == first:
                        runs.append((r, m, r))
                    continue
                runs.append((m if len(rules) == 1 else f"{m} ({r})", m, r))
        else:
            runs.append((m, m, None))
    runs.sort(key=lambda x: x[2] is None)  # entropy methods first: without a count they set it
    return runs


def compare(source: Any, *, methods: tuple[str, ...] | list[str] = METHODS, rule: str | list[str] | None = None,
            ratio: float | None = None, count: int | None = None, report_dir: str | os.PathLike | None = None,
            surface: bool = True, tiles: int = 4, tile_points: int = 200_000, seed: int = 0,
            metro_samples: int | None = None, psnr_peak: float | None = None, progress=None,
            drop_invalid: bool = False, storage_options: dict | None = None, **entropy_options) -> dict:
    """Run *methods* on *source* to the same count, evaluate each, one table.

    Parameters
    ----------
    source : path (any format the IO layer reads, or a point store) or ndarray (n, 3)
        Loaded into memory.
    methods : sequence of str
        Among ``km``, ``fcm`` (entropy simplification), ``random``, ``voxel``,
        ``poisson``, ``fps`` (:mod:`.baselines`).
    rule : str or list of str, optional
        Rule(s) of the entropy methods; a comma-separated string or a list
        runs each entropy method once per rule (:func:`compare_runs`).
        Default: ``eliminate`` with *ratio* or *count*, ``threshold`` with
        only ``threshold=``.
    ratio, count : optional
        Kept share or count (one of them).
    report_dir : path, optional
        Writes report.md, report.html, report.json, compactness.png,
        point_errors.png and each method's evaluation in a sub-folder.
    surface, tiles, tile_points, metro_samples, psnr_peak, drop_invalid, storage_options :
        As in :func:`cloudsieve.evaluate`.
    seed : int
        Seeds every method and the evaluation.
    progress : callable, optional
        Called with 1 per method done.
    **entropy_options
        ``threshold``, ``cluster_size``, ``k0``, ``k_min``
        (:func:`cloudsieve.core.simplify.simplify_points`).

    Every option is checked (:func:`cloudsieve.params.validate`) first.

    Returns
    -------
    dict
        ``source``, ``points``, ``diagonal``, ``count``, ``rule``, ``seed``,
        ``rows`` (per method: ``method, kept, time``, the figures of the
        table, or ``error``), ``original_compact_share``, ``original_mesh``,
        ``reports`` (each method's evaluation) and ``markdown``.
    """
    opts = options("compare", {**given("compare", locals()), **entropy_options})  # an unknown one is refused
    return run_compare(source, opts, progress=progress)


#: compare's options for the entropy methods (:func:`cloudsieve.core.simplify_points`)
ENTROPY_OPTIONS = ("threshold", "cluster_size", "k0", "k_min", "keep_duplicates")


def run_compare(source: Any, opts: Any, *, progress=None) -> dict:
    """:func:`compare` with options validated by :func:`cloudsieve.params.options`; none is checked again."""
    with storage.using(opts.storage_options):
        report_dir = opts.report_dir
        if report_dir is None or not storage.is_url(str(report_dir)):
            return _run_compare(source, opts, progress=progress)
        with staging.staged_folder(str(report_dir)) as folder:  # a URL: written here, then uploaded
            result = _run_compare(source, replace(opts, report_dir=folder), progress=progress)
        base = str(report_dir).rstrip("/")
        result["files"] = {k: v.replace(folder, base) for k, v in result.get("files", {}).items()}
        return result


def _run_compare(source: Any, opts: Any, *, progress=None) -> dict:
    methods, rules, ratio, count, report_dir = opts.methods, opts.rule, opts.ratio, opts.count, opts.report_dir
    surface, tiles, tile_points, seed = opts.surface, opts.tiles, opts.tile_points, opts.seed
    metro_samples, psnr_peak, drop_invalid = opts.metro_samples, opts.psnr_peak, opts.drop_invalid
    if report_dir is not None:
        check_folder(report_dir)
    entropy_options = {k: getattr(opts, k) for k in ENTROPY_OPTIONS}
    xyz, _header, name = load_points(source, what="source cloud", drop_invalid=drop_invalid)
    n = len(xyz)
    if ratio is not None:
        count = max(1, int(round(ratio * n)))
    if count is not None and count > n:  # as every surface: all the points, the count said
        logger.info("compare: count %d is more than the %d points of %s: all of them kept", count, n, name)
        count = n
    if count is None and not any(m in ("km", "fcm") for m in methods):
        raise InvalidParameterError("compare needs --ratio or --count (or an entropy method km/fcm to set the count)")
    runs = compare_runs(methods, rules)
    # each method's evaluation: a fixed number of tiles (no budget), the kept points a subset of the source's
    evaluation = OPTION_CLASSES["evaluate"](subset=True, surface=surface, tiles=tiles, tile_points=tile_points,
                                            seed=seed, metro_samples=metro_samples, psnr_peak=psnr_peak,
                                            surface_budget=None)
    tick = progress or (lambda k: None)
    out_dir = Path(report_dir) if report_dir is not None else None
    rows, reports, hists, points_h, kept = [], {}, {}, {}, {}
    cache: dict = {}
    for label, m, r in runs:
        t = time.perf_counter()
        try:
            idx = run_method(m, xyz, count, seed=seed, rule=r or MEMORY_RULE,
                             **(entropy_options if r is not None else {}))
        except (CloudsieveError, ValueError, ImportError) as exc:
            logger.warning("compare: %s failed: %s", m, exc)
            rows.append(_row(label, None, 0, time.perf_counter() - t, error=str(exc)))
            tick(1)
            continue
        seconds = time.perf_counter() - t
        if count is None:
            count = len(idx)
        if len(idx) == 0:
            rows.append(_row(label, None, 0, seconds, error="kept no point"))
            tick(1)
            continue
        sub = None if out_dir is None else out_dir / label.replace(" (", "-").rstrip(")")
        rep = run_evaluation(xyz, xyz[idx], replace(evaluation, report_dir=sub), surface_cache=cache,
                             names=(str(name), f"{label} ({len(idx):,} kept)"))
        rep["method"] = {"name": m, "seconds": seconds, "rule": r}
        if sub is not None:  # rewrite with the method's name and time
            write_json(rep, sub / "report.json")
        reports[label] = rep
        kept[label] = idx
        rows.append(_row(label, rep, int(len(idx)), seconds))
        if rep.get("surface"):
            hists[label] = rep["surface"]["simplified"]["compactness_hist"]
            hists.setdefault("original", rep["surface"]["original"]["compactness_hist"])
        h = rep["point"]["histogram"]
        points_h[label] = {"log10_edges": h["log10_edges"], "per_decade": h["per_decade"], "counts": h["forward"],
                       "zeros": h["forward_zeros"]}
        tick(1)
    if not reports:
        raise EmptyInputError(f"every method failed on {name}: " + "; ".join(f"{r['method']}: {r['error']}" for r in rows))
    any_rep = next(iter(reports.values()))
    result = {"source": str(name), "points": n, "diagonal": any_rep["diagonal"], "count": int(count), "rule": ",".join(rules),
              "seed": seed, "ratio": ratio, "psnr_peak": any_rep["psnr"]["peak"],
              "psnr_peak_from": any_rep["psnr"]["peak_from"], "rows": rows,
              "original_compact_share": (any_rep.get("surface") or {}).get("original", {}).get("compact_share"),
              "original_mesh": {k: v for k, v in ((any_rep.get("surface") or {}).get("original") or {}).items()
                                if k in ("vertices", "faces", "border_edges")},
              "reports": reports}
    result["markdown"] = compare_markdown(result)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        files = {}
        if hists:
            order = {"original": hists.pop("original"), **hists}
            files["compactness plot"] = plot_compactness(order, out_dir / "compactness.png",
                                                         title="Triangle compactness by method")
        if points_h:
            files["point error plot"] = plot_point_errors(points_h, out_dir / "point_errors.png",
                                                          title="Point errors (original → simplified) by method")
        write_text(out_dir / "report.md", result["markdown"])
        files["markdown"] = str(out_dir / "report.md")
        files["html"] = _write_html(out_dir / "report.html", xyz, kept, result["markdown"], files, seed)
        files["json"] = str(out_dir / "report.json")
        result["files"] = files
        write_json({k: v for k, v in result.items() if k != "reports"}, out_dir / "report.json")
    return result
