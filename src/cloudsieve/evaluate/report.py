"""Writing an evaluation report: report.json, report.md, report.html, PNG plots, error PLY.

``report.json`` holds :func:`cloudsieve.evaluate`'s dict as is; ``report.md``
renders it as tables like the paper's Tables 1-4; ``report.html``
(:mod:`.html`) adds 3D views. Plots (matplotlib, Agg): ``compactness.png``
(original vs simplified mesh, the paper's figures 4-5) and
``point_errors.png`` (log-scale error histograms). ``errors.ply``
(:func:`write_error_ply`): original points (at most ``error_points``)
coloured by forward error, red = 0 to blue = max (the paper's figures 6-7),
with a float ``error`` property; x/y/z as double.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import write_text

__all__ = ["write_report", "write_json", "json_ready", "markdown", "field_lines", "db", "border_per_face", "holes_note",
           "pct", "plot_compactness", "plot_point_errors", "write_error_ply", "fmt"]


def json_ready(obj: Any) -> Any:
    """*obj* with numpy values as Python ones, tuples as lists and NaN/inf as None (for ``json.dumps``)."""
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def write_json(report: dict, path: str | os.PathLike) -> str:
    """Write *report* as JSON (NaN/inf become null); returns the path."""
    write_text(path, json.dumps(json_ready(report), indent=1, sort_keys=False) + "\n")
    return str(path)


def fmt(v: Any, digits: int = 4) -> str:
    """A number for a Markdown table: 4 significant digits, '-' for missing."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    v = float(v)
    if not math.isfinite(v):
        return "-"
    if v == 0:
        return "0"
    if abs(v) >= 1e5 or abs(v) < 1e-4:
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}"


#: border edges per face above which the report notes the holes of the original's mesh
HOLEY = 0.1


def border_per_face(m: dict) -> str:
    """Border edges per face of a surface report's mesh totals, 3 decimals ("-" when unknown or no face)."""
    b = m.get("border_edges")
    return "-" if b is None or not m["faces"] else f"{b / m['faces']:.3f}"


def holes_note(m: dict) -> str:
    """A sentence on the holes of the original's mesh (its surface report's totals *m*) when it has more than
    ``HOLEY`` border edges per face; "" otherwise."""
    if not (m.get("border_edges") is not None and m["faces"] and m["border_edges"] > HOLEY * m["faces"]):
        return ""
    return (f"The original's mesh has {border_per_face(m)} border edges per face (holes where ball pivoting found "
            "too few points or too much noise). Metro's backward distances (samples on the simplified mesh) are "
            "large wherever the simplified mesh covers one of them, whatever the sampling.")


def pct(v: Any) -> str:
    """A share as a percentage with two decimals, "-" for None."""
    return "-" if v is None else f"{100.0 * float(v):.2f}%"


def markdown(report: dict) -> str:
    """report.md text: summary, point-level, Metro and compactness tables."""
    lines = ["# cloudsieve evaluation", ""]
    o, s = report.get("original", {}), report.get("simplified", {})
    p = report.get("point")
    lines += ["## Clouds", "", "| | file | points | bbox diagonal |", "|---|---|---:|---:|",
              f"| original | {o.get('name', '-')} | {fmt(o.get('count'))} | {fmt(report.get('diagonal'))} |",
              f"| simplified | {s.get('name', '-')} | {fmt(s.get('count'))} | |", ""]
    if o.get("count") and s.get("count"):
        lines += [f"Kept {fmt(s['count'])} of {fmt(o['count'])} points ({100.0 * s['count'] / o['count']:.2f}%).", ""]
    for w in report.get("warnings", []):
        lines += [f"> warning: {w}", ""]
    if p:
        lines += ["## Point level (nearest-neighbour distances)", "",
                  f"Mode: {p['mode']}" + (f" (uniform sample of {fmt(p['sample'])} points, seed {p['seed']}, 95% CI)"
                                         if p["mode"] == "sampled" else " (every point)") + ".", "",
                  "| direction | points | mean | RMS | max | mean % diag | RMS % diag | max % diag |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for name, label in (("forward", "original → simplified"), ("backward", "simplified → original")):
            d = p[name]
            lines.append(f"| {label} | {fmt(d['count'])} | {fmt(d['mean'])} | {fmt(d['rms'])} | {fmt(d['max'])} | "
                         f"{fmt(d['mean_pct'])} | {fmt(d['rms_pct'])} | {fmt(d['max_pct'])} |")
        lines += ["", f"Symmetric Hausdorff: {fmt(p['hausdorff'])} ({fmt(p['hausdorff_pct'])}% of the diagonal)"
                  + (" — a lower bound (sampled)." if p.get("hausdorff_is_lower_bound") else "."), ""]
        for name in ("forward", "backward"):
            ci = p[name].get("ci")
            if ci:
                lines.append(f"- {name} 95% CI: mean [{fmt(ci['mean'][0])}, {fmt(ci['mean'][1])}], "
                             f"RMS [{fmt(ci['rms'][0])}, {fmt(ci['rms'][1])}]; the sampled max is a lower bound.")
        lines.append("")
    lines += field_lines(report)
    sf = report.get("surface")
    if sf:
        lines += ["## Surface level (ball-pivoting meshes, Metro distances, % of the original's bbox diagonal)", "",
                  sampling_line(sf), "",
                  "| mesh | direction | vertices | faces | mean % | max % | RMS % |", "|---|---|---:|---:|---:|---:|---:|"]
        for name, label, mesh in (("forward", "original mesh → simplified mesh", "simplified"),
                                  ("backward", "simplified mesh → original mesh", "simplified")):
            d = sf.get(name)
            if d:
                m = sf[mesh]
                lines.append(f"| {mesh} | {label} | {fmt(m['vertices'])} | {fmt(m['faces'])} | {fmt(d['mean_pct'])} | "
                             f"{fmt(d['max_pct'])} | {fmt(d['rms_pct'])} |")
        on = sf.get("on_surface") or {}
        if on.get("backward"):
            d, m = on["backward"], sf["simplified"]
            lines.append(f"| simplified | simplified mesh → original mesh, where the original has surface | "
                         f"{fmt(m['vertices'])} | {fmt(m['faces'])} | {fmt(d['mean_pct'])} | {fmt(d['max_pct'])} | "
                         f"{fmt(d['rms_pct'])} |")
            lines += ["", f"Where the original has surface: {pct(on['excluded_share'])} of the backward samples "
                      "left out (their closest point on the original's mesh lies on its border: a hole, or the "
                      f"tile's rim); Metro there (the larger direction): mean {fmt(on['mean_pct'])}%, max "
                      f"{fmt(on['max_pct'])}%, RMS {fmt(on['rms_pct'])}%."]
        lines += ["", "| mesh | vertices | faces | border edges per face | compactness ≥ 0.6 | mean compactness | "
                  "compact (≥ 50%) |", "|---|---:|---:|---:|---:|---:|---|"]
        for mesh in ("original", "simplified"):
            m = sf[mesh]
            lines.append(f"| {mesh} | {fmt(m['vertices'])} | {fmt(m['faces'])} | {border_per_face(m)} | "
                         f"{pct(m['compact_share'])} | {fmt(m['compactness_mean'])} | {fmt(m['compact'])} |")
        ref = sf.get("reference")
        if ref:
            lines += ["", f"Against the reference mesh ({fmt(ref['faces'])} faces; Metro, % of the diagonal, the "
                      "larger of both directions; forward: samples on the reference):", "",
                      "| mesh | mean % | max % | RMS % | forward mean % | backward mean % |",
                      "|---|---:|---:|---:|---:|---:|"]
            for mesh in ("original", "simplified"):
                d = ref.get(mesh) or {}
                if d.get("forward"):
                    lines.append(f"| {mesh} | {fmt(d['mean_pct'])} | {fmt(d['max_pct'])} | {fmt(d['rms_pct'])} | "
                                 f"{fmt(d['forward']['mean_pct'])} | {fmt(d['backward']['mean_pct'])} |")
        if holes_note(sf["original"]):
            lines += ["", f"> {holes_note(sf['original'])}"]
        if len(sf["tiles"]) > 1:
            lines += ["", "Per tile:", "",
                      "| tile | original pts | simplified pts | Metro mean % | Metro max % | Metro RMS % | c≥0.6 orig | c≥0.6 simpl |",
                      "|---:|---:|---:|---:|---:|---:|---:|---:|"]
            for i, t in enumerate(sf["tiles"]):
                f = t.get("forward") or {}
                lines.append(f"| {i} | {fmt(t['points_original'])} | {fmt(t['points_simplified'])} | "
                             f"{fmt(f.get('mean_pct'))} | {fmt(f.get('max_pct'))} | {fmt(f.get('rms_pct'))} | "
                             f"{pct(t['original']['compact_share'])} | {pct(t['simplified']['compact_share'])} |")
        errs = [t["error"] for t in sf["tiles"] if "error" in t]
        for e in errs:
            lines += ["", f"> tile error: {e}"]
        lines.append("")
    files = report.get("files", {})
    if files:
        lines += ["## Files", ""] + [f"- {k}: `{os.path.basename(v)}`" for k, v in files.items()] + [""]
    return "\n".join(lines)


def sampling_line(sf: dict) -> str:
    """How the surface level's tiles were chosen, and the spread of its figures over them (one paragraph)."""
    n, m = len(sf["tiles"]), fmt(sf["tile_points"])
    smp = sf.get("sampling") or {}
    mode = smp.get("mode", "whole" if sf["tiles"] and sf["tiles"][0].get("whole_cloud") else "fixed")
    share = f", {100 * smp['points_share']:.2f}% of the original's points" if smp.get("points_share") else ""
    if mode == "whole":
        text = f"One tile: the whole cloud ({m} points)."
    elif mode == "full":
        text = f"Every original point, in {n} tiles (k-means cells of about {m} points)."
    elif mode == "budget":
        pts = [t["points_original"] for t in sf["tiles"]]
        size = fmt(pts[0]) if min(pts) == max(pts) else f"{fmt(min(pts))} to {fmt(max(pts))}"
        text = (f"A sample of {n} tiles of {size} original points{share}, centred on random original points "
                f"(seeded), sized for a {smp['budget']:g} s budget at {fmt(smp['rate'])} points/s (the rate "
                "measured on 2 cores, not timed here: the same tiles on any machine). The figures are "
                "those of the sampled tiles; `--surface-full` measures the whole cloud.")
    else:
        text = f"{n} tile(s) of at most {m} original points (k-means centres of a uniform sample){share}."
    sp = smp.get("spread") or {}
    errs = [f"{label} mean {fmt(sf[k]['mean_pct'])}% ± {fmt(sp[k]['mean_pct_se'])}, RMS {fmt(sf[k]['rms_pct'])}% ± "
            f"{fmt(sp[k]['rms_pct_se'])}" for k, label in (("forward", "forward"), ("backward", "backward"))
            if sp.get(k) and sf.get(k)]
    if errs:
        text += (f" Spread over the {n} tiles (standard error of the samples-weighted mean, % of the diagonal): "
                 + "; ".join(errs) + f"; simplified mesh c ≥ 0.6 share ± {pct(sp.get('compact_share_se'))}.")
    return text


def db(v: Any) -> str:
    """A PSNR for a table: 2 decimals, "∞" for an MSE of 0 (inf, or None once read back from JSON)."""
    if v is None or math.isinf(float(v)):  # report.json holds an infinite PSNR as null
        return "∞"
    return f"{float(v):.2f}"


def field_lines(report: dict) -> list[str]:
    """report.md's section on MPEG pc_error's D1/D2 PSNR and the Chamfer distance (none without them)."""
    ps, ch = report.get("psnr"), report.get("chamfer")
    if not ps or not ch:
        return []
    normals = "from the file" if ps["normals"] == "file" else f"estimated by PCA of {ps['k_normals']} neighbours"
    lines = ["## Field figures (MPEG pc_error D1/D2 PSNR, Chamfer)", "",
             f"PSNR = 10·log10(3·p²/MSE) dB with peak p = {fmt(ps['peak'])} "
             f"({'the original' + chr(39) + 's bounding-box diagonal' if ps['peak_from'] == 'diagonal' else 'given'}); "
             f"D1 point-to-point, D2 point-to-plane on the original's normals ({normals}); symmetric = the larger "
             "MSE; ∞: no error.", "",
             "| metric | forward PSNR (dB) | backward PSNR (dB) | symmetric PSNR (dB) | forward MSE | backward MSE |",
             "|---|---:|---:|---:|---:|---:|"]
    for m in ("d1", "d2"):
        lines.append(f"| {m.upper()} | {db(ps[m]['forward'])} | {db(ps[m]['backward'])} | {db(ps[m]['symmetric'])} | "
                     f"{fmt(ps['mse'][m]['forward'])} | {fmt(ps['mse'][m]['backward'])} |")
    samp = ps.get("d2_sample") or {}
    for name in ("forward", "backward"):
        if samp.get(name) and ps["mse"]["d2"][name] > 0:
            lines += ["", f"D2 {name}: measured on a uniform random sample of {fmt(samp[name])} points (D1 and "
                      f"Chamfer on every point); standard error of its PSNR ±{ps['d2_se_db'][name]:.3f} dB."]
    lines += ["", f"Chamfer distance: {fmt(ch['value'])} (squared cloud units; {fmt(ch['forward'])} forward + "
              f"{fmt(ch['backward'])} backward, the mean squared nearest-neighbour distances).", ""]
    return lines


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def plot_compactness(series: dict[str, list[int]], path: str | os.PathLike, title: str = "Triangle compactness") -> str:
    """Histograms (50 bins on [0, 1]) of triangle compactness, one line per mesh, as shares of faces."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    edges = np.linspace(0, 1, 51)
    centres = 0.5 * (edges[1:] + edges[:-1])
    for label, counts in series.items():
        c = np.asarray(counts, dtype=float)
        if c.sum() > 0:
            ax.step(centres, 100.0 * c / c.sum(), where="mid", label=label)
    ax.axvline(0.6, color="grey", linestyle="--", linewidth=1)
    ax.set_xlabel("compactness c = 4√3·a / (l1² + l2² + l3²)")
    ax.set_ylabel("% of triangles")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def plot_point_errors(series: dict[str, dict], path: str | os.PathLike, title: str = "Point-level errors") -> str:
    """Histograms of point errors over the fixed log bins; *series* maps a label to a
    report["point"]["histogram"]-like dict with ``log10_edges``, ``per_decade`` and ``forward``."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, h in series.items():
        counts = np.asarray(h.get("counts", h.get("forward", [])), dtype=float)
        if not h.get("log10_edges") or counts.sum() == 0:
            continue
        e0 = h["log10_edges"][0]
        edges = 10 ** (e0 + np.arange(len(counts) + 1) / h["per_decade"])
        total = counts.sum() + h.get("zeros", h.get("forward_zeros", 0))
        ax.stairs(100.0 * counts / total, edges, label=label)
    ax.set_xscale("log")
    ax.set_xlabel("distance to the other cloud (cloud units); zeros not shown")
    ax.set_ylabel("% of points")
    ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def write_error_ply(path: str | os.PathLike, xyz: np.ndarray, error: np.ndarray) -> str:
    """Binary PLY of points *xyz* (n, 3) coloured by *error* (n,) (red = 0, blue = max) with an ``error`` property."""
    import matplotlib

    xyz = np.asarray(xyz, dtype=np.float64)
    error = np.asarray(error, dtype=np.float32)
    mx = float(error.max()) if len(error) else 0.0
    t = error / mx if mx > 0 else np.zeros(len(error), np.float32)
    rgb = (matplotlib.colormaps["jet_r"](t)[:, :3] * 255 + 0.5).astype(np.uint8)
    from ..io import open_writer

    u1 = np.dtype("uint8")
    dtypes = {"xyz": (np.dtype("float64"), (3,)), "red": (u1, ()), "green": (u1, ()), "blue": (u1, ()),
              "error": (np.dtype("float32"), ())}
    with open_writer(path, header={}, dtypes=dtypes, format="ply", overwrite=True) as w:
        w.write({"xyz": xyz, "red": rgb[:, 0].copy(), "green": rgb[:, 1].copy(), "blue": rgb[:, 2].copy(),
                 "error": error})
    return str(path)


def write_report(report: dict, directory: str | os.PathLike, *, error_points: tuple[np.ndarray, np.ndarray] | None = None,
                 kept: np.ndarray | None = None) -> dict:
    """Write report.json, report.md, report.html, the plots and (given points and errors) errors.ply into *directory*.
    *error_points* (xyz (n, 3), error (n,)) and *kept* (m, 3) also feed report.html's 3D views. Returns the file
    kinds' paths (``report["files"]``)."""
    from .html import view_sample, write_html

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    files: dict[str, str] = {}
    sf = report.get("surface")
    if sf:
        files["compactness plot"] = plot_compactness(
            {"original mesh": sf["original"]["compactness_hist"], "simplified mesh": sf["simplified"]["compactness_hist"]},
            d / "compactness.png")
    p = report.get("point")
    if p:
        h = p["histogram"]
        series = {"original → simplified": {"log10_edges": h["log10_edges"], "per_decade": h["per_decade"],
                                            "counts": h["forward"], "zeros": h["forward_zeros"]}}
        if sum(h["backward"]):
            series["simplified → original"] = {"log10_edges": h["log10_edges"], "per_decade": h["per_decade"],
                                               "counts": h["backward"], "zeros": h["backward_zeros"]}
        files["point error plot"] = plot_point_errors(series, d / "point_errors.png")
    if error_points is not None and len(error_points[0]):
        files["error PLY"] = write_error_ply(d / "errors.ply", *error_points)
    files["markdown"] = str(d / "report.md")
    files["html"] = str(d / "report.html")
    files["json"] = str(d / "report.json")
    report["files"] = files
    md = markdown(report)
    write_text(d / "report.md", md)
    seed = (report.get("parameters") or {}).get("seed") or 0
    views: dict[str, Any] = {"bounds": np.asarray(p["bounds"]) if p else None}
    if error_points is not None and len(error_points[0]):
        i = view_sample(len(error_points[0]), seed=seed)
        views.update(original=error_points[0][i], errors={"the simplified cloud": error_points[1][i]})
    if kept is not None and len(kept):
        views["kept"] = {"simplified": kept[view_sample(len(kept), seed=seed)]}
    images = {k: v for k, v in files.items() if v.endswith(".png")}
    write_html(d / "report.html", "cloudsieve evaluation", md, images=images, **views)
    write_json(report, d / "report.json")
    return files
