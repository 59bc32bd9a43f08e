"""Surface-level errors, the paper's, on tiles: ball-pivoting meshes, Metro distances, compactness (:mod:`.mesh`).

Per tile both clouds are meshed and compared both ways; figures are aggregated over tiles (Metro mean and RMS
weighted by samples, max over tiles, compactness over all triangles). Tiles: :mod:`.tiles`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..engine.calls import forked
from ._source import open_source
from .tiles import (BUDGET_TILES, SURFACE_RATE, budget_tile_points, cell_points, choose_tiles, gather_tiles,
                    partition_tiles, random_tiles, spread, uniform_sample)
from .mesh import COMPACT_THRESHOLD, ball_pivoting, border_edges, compactness, compactness_summary, crop_mesh, metro

logger = logging.getLogger(__name__)

__all__ = ["TilePlan", "choose_tiles", "surface_errors"]


def _mesh_figures(mesh: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, dict]:
    """Compactness of each triangle of *mesh*, and its vertices, border edges and compactness summary."""
    c = compactness(*mesh)
    return c, {"vertices": int(len(mesh[0])), "border_edges": len(border_edges(mesh[1])), **compactness_summary(c)}


def _pct(r: dict, diagonal: float) -> dict:
    for key in ("mean", "rms", "max"):
        r[f"{key}_pct"] = r[key] * 100.0 / diagonal if diagonal > 0 else float("nan")
    return r


def _reference(ref: tuple[np.ndarray, np.ndarray], meshes: dict, diagonal: float, samples: int | None,
               max_samples: int) -> dict:
    """Metro of each of *meshes* (name -> mesh) against the reference mesh (cropped to the tile)."""
    out: dict[str, Any] = {"faces": int(len(ref[1]))}
    if len(ref[1]) == 0:
        out["error"] = "the reference mesh has no triangle in this tile"
        return out
    for name, mesh in meshes.items():
        if len(mesh[1]):
            m = metro(ref, mesh, samples=samples, max_samples=max_samples)
            out[name] = {"forward": _pct(m["forward"], diagonal), "backward": _pct(m["backward"], diagonal)}
    return out


def _tile_figures(orig: np.ndarray, simp: np.ndarray, diagonal: float, samples: int | None,
                  max_samples: int, cache: dict | None = None, key: Any = None,
                  reference: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[dict, np.ndarray, np.ndarray]:
    lo, hi = orig.min(0), orig.max(0)
    tile_diag = float(np.linalg.norm(hi - lo))
    rec: dict[str, Any] = {"points_original": int(len(orig)), "points_simplified": int(len(simp)),
                           "diagonal": tile_diag}
    if cache is not None and key in cache and np.array_equal(cache[key][0], orig):
        _, mo, co, figs = cache[key]
        msimp = ball_pivoting(simp)
    else:  # both meshes at once, one forked child each
        mo, msimp = forked([(ball_pivoting, orig), (ball_pivoting, simp)])
        co, figs = _mesh_figures(mo)
        if cache is not None:  # the original's mesh and its figures, for the next simplification of it
            cache[key] = (orig, mo, co, figs)
    cs, rec["simplified"] = _mesh_figures(msimp)
    rec["original"] = dict(figs)
    if reference is not None:
        rec["reference"] = _reference(reference, {"simplified": msimp, "original": mo}, diagonal, samples,
                                      max_samples)
    if len(mo[1]) == 0 or len(msimp[1]) == 0:
        rec["error"] = (f"ball pivoting made no triangle ({len(mo[1])} from {len(orig)} original points, "
                        f"{len(msimp[1])} from {len(simp)} simplified points)")
        return rec, co, cs
    m = metro(mo, msimp, samples=samples, max_samples=max_samples)
    for name in ("forward", "backward"):
        r = m[name]
        for key in ("mean", "rms", "max"):
            r[f"{key}_pct"] = r[key] * 100.0 / diagonal if diagonal > 0 else float("nan")
            r[f"{key}_pct_tile"] = r[key] * 100.0 / tile_diag if tile_diag > 0 else float("nan")
        rec[name] = r
    return rec, co, cs


def _on_surface(recs: list[dict], forward: dict | None, diagonal: float) -> dict | None:
    """Metro where the original's mesh has surface: the backward samples facing a hole (or a tile's rim) left out."""
    rs = [r["backward"]["on_surface"] for r in recs if "on_surface" in r.get("backward", {})]
    if not rs:
        return None
    excluded = int(sum(r["excluded"] for r in rs))
    sampled = [r for r in rs if r["samples"] > 0]
    out: dict[str, Any] = {"excluded": excluded,
                           "excluded_share": excluded / max(sum(float(r["samples"]) for r in rs) + excluded, 1.0),
                           "backward": _pooled(sampled, diagonal) if sampled else None}
    for key in ("mean", "rms", "max", "mean_pct", "rms_pct", "max_pct"):
        vals = [d[key] for d in (forward, out["backward"]) if d is not None]
        out[key] = max(vals) if vals else float("nan")
    return out


def _combine_dirs(recs: list[dict], name: str, diagonal: float) -> dict | None:
    rs = [r[name] for r in recs if name in r]
    return _pooled(rs, diagonal) if rs else None


def _pooled(rs: list[dict], diagonal: float) -> dict:
    """Metro records (``samples``, ``mean``, ``rms``, ``max``) of several tiles as one, weighted by samples."""
    n = np.array([r["samples"] for r in rs], dtype=np.float64)
    mean = float((n * [r["mean"] for r in rs]).sum() / n.sum())
    rms = float(math.sqrt((n * np.square([r["rms"] for r in rs])).sum() / n.sum()))
    mx = float(max(r["max"] for r in rs))
    scale = 100.0 / diagonal if diagonal > 0 else float("nan")
    return {"mean": mean, "rms": rms, "max": mx, "mean_pct": mean * scale, "rms_pct": rms * scale,
            "max_pct": mx * scale, "samples": int(n.sum())}


def _plan(src, tiles: int, tile_points: int, seed: int, budget: float | None, full: bool,
          sample: tuple[np.ndarray, int] | None) -> tuple[list[dict], list[np.ndarray], dict, np.ndarray | None]:
    """The tiles (fixed, budget or full; :mod:`.tiles`), their original points, how they were chosen, and with
    *full* the cells' centres."""
    if budget is None and not full:
        chosen = choose_tiles(src, tiles or 4, tile_points, seed=seed)
        if chosen:
            return (chosen, gather_tiles(src, chosen, tile_points),
                    {"mode": "fixed", "tile_points": int(tile_points), "population": src.count_points()}, None)
        return _whole(src)
    sample, n = sample if sample is not None else uniform_sample(src, seed=seed)
    if full:
        if n <= tile_points:
            return _whole(src)
        chosen, origs, centres = partition_tiles(src, sample, n, tile_points, seed=seed)
        return chosen, origs, {"mode": "full", "tile_points": int(tile_points), "population": n}, centres
    # sized by a measured rate, never by a clock: the same tiles on any machine, under any load
    sampling = {"mode": "budget", "budget": float(budget), "population": n, "rate": float(SURFACE_RATE)}
    if n <= tile_points and n / SURFACE_RATE <= budget:
        chosen, origs, _, _ = _whole(src)
        return chosen, origs, {**sampling, "mode": "whole", "tile_points": n}, None
    count = tiles or BUDGET_TILES
    m = budget_tile_points(SURFACE_RATE, budget, count, tile_points)
    chosen = random_tiles(sample, n, count, m, seed=seed)
    sampling.update({"tile_points": m})
    return chosen, gather_tiles(src, chosen, m), sampling, None


def _whole(src):
    origs = [np.concatenate([chunk.xyz for chunk in src.chunks()])]
    return ([{"centre": None, "radius": None, "whole_cloud": True}], origs,
            {"mode": "whole", "tile_points": len(origs[0]), "population": len(origs[0])}, None)


def _simplified_tiles(simplified: np.ndarray, chosen: list[dict], centres: np.ndarray | None) -> list[np.ndarray]:
    """The points of *simplified* in each tile: all (whole cloud), nearest each cell's centre (*full*), or in each
    ball."""
    if chosen and chosen[0].get("whole_cloud"):
        return [simplified]
    if centres is not None:
        return cell_points(simplified, centres, chosen)
    stree = cKDTree(simplified)
    out = []
    for t in chosen:
        ids = np.sort(stree.query_ball_point(t["centre"], t["radius"], workers=-1, return_sorted=False))
        out.append(simplified[ids.astype(np.int64)])
    return out


@dataclass(frozen=True)
class TilePlan:
    """How :func:`surface_errors` chooses the original's tiles; every field as there."""

    tiles: int | None = 4
    tile_points: int = 200_000
    seed: int = 0
    budget: float | None = None
    full: bool = False


def surface_errors(original: Any, simplified: np.ndarray, tiling: TilePlan = TilePlan(), *,
                   diagonal: float | None = None, samples: int | None = None, max_samples: int = 500_000,
                   progress=None, cache: dict | None = None, reference: tuple[np.ndarray, np.ndarray] | None = None,
                   sample: tuple[np.ndarray, int] | None = None) -> dict:
    """The paper's surface-level figures on tiles of *original* (streamed) and *simplified* (m, 3).

    *tiling*: ``tiles`` T (None: 4, or with a budget as many as fit, sized
    for 8), ``budget`` (seconds at :data:`.tiles.SURFACE_RATE`), ``full``,
    ``tile_points`` M, ``seed``. *sample*: a uniform sample of the original
    and its count, saving a pass. *samples*, *max_samples*: Metro's
    (:func:`.mesh.metro`). *cache*: the original's tiles and meshes across
    calls (compare). *reference*: a mesh both tile meshes are compared with.

    Returns ``tiles``; ``forward``, ``backward``, ``mean, rms, max`` (+
    ``_pct``, the larger direction); ``on_surface`` (without backward samples
    facing a hole of the original's mesh; ``excluded``, ``excluded_share``);
    ``reference``; ``original`` and ``simplified`` mesh totals, the latter
    also at top level; ``sampling`` (``mode``, ``tiles``, ``tile_points``,
    ``seconds``, ``population``, ``points_share``, ``budget``, ``rate``,
    ``spread``).
    """
    t0 = time.perf_counter()
    src = open_source(original)
    simplified = np.ascontiguousarray(simplified, dtype=np.float64)
    tick = progress or (lambda n: None)
    # the original's tiles depend on the original alone: compare plans them once for every method
    plan = cache.get("original_tiles") if cache is not None else None
    if plan is None:
        plan = _plan(src, tiling.tiles, tiling.tile_points, tiling.seed, tiling.budget, tiling.full, sample)
        if cache is not None:
            cache["original_tiles"] = plan
    chosen, origs, sampling, centres = plan
    simps = _simplified_tiles(simplified, chosen, centres)
    if diagonal is None:
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for chunk in src.chunks():
            xyz = chunk.xyz
            if len(xyz):
                lo, hi = np.minimum(lo, xyz.min(0)), np.maximum(hi, xyz.max(0))
        diagonal = float(np.linalg.norm(hi - lo))
    recs, cos, css, used = [], [], [], []
    for i, (t, o, s) in enumerate(zip(chosen, origs, simps)):
        logger.info("surface tile: %d original, %d simplified points", len(o), len(s))
        started = time.perf_counter()
        ref = reference
        if reference is not None and t.get("centre") is not None:
            ref = crop_mesh(reference, t["centre"], t["radius"])
        rec, co, cs = _tile_figures(o, s, diagonal, samples, max_samples, cache, i, ref)
        rec["seconds"] = time.perf_counter() - started
        recs.append({**t, **rec})
        used.append(len(o))
        cos.append(co)
        css.append(cs)
        tick(1)
    sampling = {**sampling, "tiles": len(recs), "seconds": time.perf_counter() - t0}
    if sampling.get("population"):
        sampling["points_share"] = float(sum(used)) / sampling["population"]
    if sampling["mode"] in ("budget", "fixed") and len(recs) > 1:
        sampling["spread"] = spread(recs, diagonal)
    out: dict[str, Any] = {"tiles": recs, "tile_points": int(sampling.get("tile_points", tiling.tile_points)),
                           "diagonal": diagonal, "sampling": sampling,
                           "ball_pivoting": "pymeshlab, radii r and 2r, r = median mean 6-NN distance",
                           "compact_threshold": COMPACT_THRESHOLD}
    for name in ("forward", "backward"):
        out[name] = _combine_dirs(recs, name, diagonal)
    f, b = out["forward"], out["backward"]
    for key in ("mean", "rms", "max", "mean_pct", "rms_pct", "max_pct"):
        vals = [d[key] for d in (f, b) if d is not None]
        out[key] = max(vals) if vals else float("nan")
    out["on_surface"] = _on_surface(recs, f, diagonal)
    if reference is not None:
        out["reference"] = {"faces": int(len(reference[1]))}
        for mesh in ("simplified", "original"):
            sub = [r["reference"][mesh] for r in recs if mesh in r.get("reference", {})]
            figs = {d: _combine_dirs(sub, d, diagonal) for d in ("forward", "backward")}
            if figs["forward"] is not None:
                figs.update({k: max(figs["forward"][k], figs["backward"][k])
                             for k in ("mean", "rms", "max", "mean_pct", "rms_pct", "max_pct")})
            out["reference"][mesh] = figs
    for name, cs_list, recs_key in (("original", cos, "original"), ("simplified", css, "simplified")):
        allc = np.concatenate(cs_list) if cs_list else np.zeros(0)
        out[name] = {"vertices": int(sum(r[recs_key]["vertices"] for r in recs)),
                     "border_edges": int(sum(r[recs_key]["border_edges"] for r in recs)), **compactness_summary(allc)}
    sm = out["simplified"]
    out.update({"vertices": sm["vertices"], "faces": sm["faces"], "compact_share": sm["compact_share"],
                "compact": sm["compact"]})
    return out
