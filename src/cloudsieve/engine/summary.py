"""What a :func:`~cloudsieve.engine.simplify` run reports: its :class:`Summary`, and
:func:`missed_target`, the words for a ratio or count it could not meet."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from ..core._validation import ratio_count

__all__ = ["Summary", "missed_target"]


def missed_target(src: str, ratio, count, n: int, kept: int, duplicates: int = 0,
                  keep_duplicates: bool = False, exact: bool = False, asked: int | None = None) -> str | None:
    """What to say when a ratio or count was asked and the kept count differs, else None.

    ``"SRC: asked to keep A points, kept K: why"``, logged as a warning or
    raised with the option ``exact``. With *exact* (a rule keeping exactly the count,
    ``eliminate``) only the input's size and its duplicates explain a miss.
    *asked*: the count of class policies (:meth:`.class_policy.ClassPolicy.asked`).
    """
    if ratio is None and count is None:
        return None
    if asked is None:
        asked = ratio_count(ratio, n) if ratio is not None else int(count)
    if kept == asked:
        return None
    if asked > n:
        why = f"the input holds only {n:,} points"
        if duplicates and not keep_duplicates:
            why += f", {duplicates:,} of them exact duplicates, kept once (keep_duplicates keeps them)"
    elif duplicates and keep_duplicates and kept > asked:
        why = "the exact copies of kept points are kept too (keep_duplicates)"
    elif duplicates and asked > n - duplicates:
        why = f"{duplicates:,} of the {n:,} points are exact duplicates, kept once (keep_duplicates keeps them)"
    elif exact:
        why = "the rule missed its exact count (a bug: please report it with the input)"
    else:
        why = ("points with equal scores at the global threshold go or stay together, exact duplicates "
               "count once, and clusters too small to thin are kept whole")
    return f"{src}: asked to keep {asked:,} points, kept {kept:,}: {why}"


@dataclass
class Summary:
    """What a :func:`simplify` run did.

    Attributes
    ----------
    points_in, kept, removed, cells : int
    cells_computed, cells_reused : int
        Cells computed in this run, and cells found done in the store (resume).
    duplicates, duplicates_kept : int, bool
        Exact duplicate points (same x, y, z as an earlier point), and whether
        they were kept with their first copy (``keep_duplicates``).
    threshold : float or None
        The global threshold on the unit-free score of a ratio/count with the
        target, iterative or coverage rule; None otherwise.
    seconds : dict str -> float
        Wall time per stage ("ingest", "partition", "cells", "merge", "export") and "total".
    cpu_seconds : dict str -> float
        ``{"driver": d, "workers": w}`` (:meth:`cloudsieve.engine.runner.Runner.worker_cpu`).
    stage_cpu : dict str -> float
        The workers' CPU seconds in each stage of a run through the work store (their sum is
        ``cpu_seconds["workers"]``); empty for a small input run in memory.
    peak_memory, peak_memory_of : int, str
        Peak resident memory (bytes), sampled, and what it covers (:mod:`.memory`).
    storage : dict or None
        ``{"retries": n}``, object-store requests sent again
        (:mod:`cloudsieve.storage_retries`); None, absent from :meth:`to_dict`, on local paths.
    scheduler, source, destination : str
    store : str
        The work store, "" when it was removed (the default store, after success).
    outputs : list of dict
        Nested outputs (a list of ratios or counts, :mod:`.levels`): per output its
        ``ratio`` or ``count``, ``destination``, ``kept`` and ``seconds``; the other
        fields are the first output's. Empty, absent from :meth:`to_dict`, otherwise.
    classes : dict or None
        With ``keep_class``/``class_ratio``: ``asked``, per policy and per class the
        input and kept points (:meth:`cloudsieve.engine.class_policy.ClassPolicy.report`);
        None, absent from :meth:`to_dict`, without them.
    density : dict or None
        With ``density``: per area of side ``side`` the points per square unit, ``min``, ``median``,
        ``p95`` and ``max`` over the ``areas`` holding points, ``before`` and ``after``, and the areas
        ``thinned`` to ``floor`` points (:meth:`cloudsieve.engine.density.DensityTarget.report`); None,
        absent from :meth:`to_dict`, without it.
    gap : dict or None
        With ``max_gap``: ``{"bound": D, "filled": points added back after
        the elimination (in *kept*), "max": the largest distance from an input
        point to the kept set, checked exactly, "fill_to": the distance the
        cells filled to}``; None, absent from :meth:`to_dict`, otherwise.
    """

    points_in: int = 0
    kept: int = 0
    removed: int = 0
    cells: int = 0
    cells_computed: int = 0
    cells_reused: int = 0
    duplicates: int = 0
    duplicates_kept: bool = False
    threshold: float | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    cpu_seconds: dict[str, float] = field(default_factory=lambda: {"driver": 0.0, "workers": 0.0})
    stage_cpu: dict[str, float] = field(default_factory=dict)
    peak_memory: int = 0
    peak_memory_of: str = "this process and its children"
    storage: dict[str, int] | None = None
    scheduler: str = ""
    source: str = ""
    destination: str = ""
    store: str = ""
    classes: dict | None = None
    density: dict | None = None
    outputs: list[dict[str, Any]] = field(default_factory=list)
    gap: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        record = asdict(self)
        for name in ("storage", "classes", "density", "outputs", "gap"):
            if record[name] in (None, []):
                del record[name]
        return record

    def __str__(self) -> str:
        s = self
        pct = 100.0 * s.kept / s.points_in if s.points_in else 0.0
        rate = s.points_in / s.seconds["total"] if s.seconds.get("total") else 0.0
        lines = [
            f"points in     {s.points_in:>14,}",
            f"kept          {s.kept:>14,}  ({pct:.2f}%)",
            f"removed       {s.removed:>14,}",
            f"cells         {s.cells:>14,}  (computed {s.cells_computed}, reused {s.cells_reused})",
            f"duplicates    {s.duplicates:>14,}  (exact copies {'kept' if s.duplicates_kept else 'removed'})",
        ]
        if s.gap is not None:
            g = s.gap
            to = f"; filled to {g['fill_to']:.6g}, the halo's reach" if g["fill_to"] < g["bound"] else ""
            lines.insert(2, f"gap bound     {g['bound']:>14.6g}  (at least the count: {g['filled']:,} points added "
                            f"back; largest gap {g['max']:.6g}, checked exactly{to})")
        if s.threshold is not None:
            lines.append(f"threshold     {s.threshold:>14.6g}  (global, on m*dH)")
        if s.classes is not None:
            lines.append("classes       (--ratio/--count apply to the points not kept whole and not in --class-ratio)")
            lines += [f"  class {c['class']:<5} {c['policy']:<18} in {c['points_in']:>12,}  kept {c['kept']:>12,}  "
                      f"({100.0 * c['ratio']:.2f}%)" for c in s.classes["classes"]]
        if s.density is not None:
            d = s.density
            cube, unit = ("cubes", "cubic") if d["dims"] == 3 else ("areas", "square")
            lines.append(f"density       {d['thinned']:>14,}  of {d['areas']:,} {cube} of side {d['side']:g} "
                         f"thinned to {d['floor']:,} points (at most {d['density']:g} per {unit} unit)")
            lines += [f"  {when:<11} min {d[when]['min']:.3g}, median {d[when]['median']:.3g}, 95th "
                      f"{d[when]['p95']:.3g}, max {d[when]['max']:.3g} points per {unit} unit"
                      for when in ("before", "after")]
        stages = ", ".join(f"{k} {v:.2f}s" for k, v in s.seconds.items() if k != "total")
        lines.append(f"time          {s.seconds.get('total', 0.0):>13.2f}s  ({stages}); {rate:,.0f} points/s")
        cpu = s.cpu_seconds
        lines.append(f"cpu           {cpu['driver'] + cpu['workers']:>13.2f}s  (driver {cpu['driver']:.2f}s, "
                     f"workers {cpu['workers']:.2f}s)")
        if s.stage_cpu:
            lines.append("  workers     " + ", ".join(f"{k} {v:.2f}s" for k, v in s.stage_cpu.items()))
        lines.append(f"peak memory   {s.peak_memory / 2**20:>12.0f} MiB  ({s.peak_memory_of})")
        if s.storage is not None:
            lines.append(f"storage       {s.storage['retries']:>14,}  retries (requests sent again after a timeout, "
                         f"throttling or a 5xx)")
        lines.append(f"scheduler     {s.scheduler}")
        for out in s.outputs:
            key = "ratio" if "ratio" in out else "count"
            lines.append(f"output        {out['kept']:>14,}  {key} {out[key]:g}: {out['destination']} "
                         f"({out['seconds']:.2f}s)")
        return "\n".join(lines)
