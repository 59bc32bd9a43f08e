"""Compile the kernels a run needs once, before it needs them: the warm-up targets.

numba compiles a kernel at its first call or loads it from its on-disk cache;
compiling takes far longer (docs/benchmarks.md, "Start-up"). Each target calls
one part's kernels on a tiny input with the real argument types:

- ``common``: LAS/LAZ coordinates, exact copies, the merge (every rule);
- ``partition``: labels and halo bands of the partition's tasks;
- ``eliminate``: the default rule in memory;
- ``scores``: the k-NN and entropy kernels;
- ``km``, ``fcm``: the refinement;
- ``rules``: the rounds of the iterative, target and coverage rules.

:mod:`cloudsieve.rule_table` names the targets of each rule; the fork server
(:mod:`cloudsieve.engine.forkserver_init`) warms them so forked workers inherit the
code; ``cloudsieve warmup`` (:mod:`cloudsieve.cli.warmup`) fills the cache.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import numpy as np

from . import rules
from ..rule_table import TARGETS

__all__ = ["warm_up", "warm_report", "split_targets", "SECOND", "AHEAD", "ahead_parts", "warm_ahead"]


def _points(n: int = 600) -> np.ndarray:
    """A small noisy surface (a tiny real-like cloud: 2-D spread, some relief), float64 (n, 3)."""
    rng = np.random.default_rng(0)
    xy = rng.random((n, 2)) * 10.0
    return np.ascontiguousarray(np.c_[xy, 0.3 * np.sin(xy[:, 0]) + 0.01 * rng.random(n)])


def _merge_scatter() -> None:
    """The merge's scatter of the keep masks back to input order (every rule's last kernel)."""
    from .kernels.scatter import from_groups

    from_groups(np.zeros(2, dtype=np.int32), np.zeros(1, dtype=np.int64), np.ones(2, dtype=bool))


def _common() -> None:
    from .kernels.copies import first_equal
    from .kernels.records import first_call

    P = _points(24)
    first_equal((P + 0.0).view(np.uint64))  # exact copies (every rule's cells)
    first_call()  # a LAS/LAZ input's X, Y, Z (io/las_records.py)
    _merge_scatter()


def _eliminate() -> None:
    from .eliminate import eliminate
    from .eliminate_cells import eliminate_cell
    from .packing import packing_ladder
    from .radius import elimination_radius, point_areas

    P = _points()
    areas, weight = point_areas(P)  # the partition's r_max
    r_max = elimination_radius(areas, 300, weight=weight)
    packing_ladder(P, r_max)
    eliminate_cell(P[:400], 200, r_max, halo=P[400:], decided=np.zeros(200, dtype=bool),
                   halo_keep=np.zeros(200, dtype=bool))
    Q = _points(3_000)  # an engine cell over k-d cells (above 2 x MIN_KEPT kept: cut in two at least)
    areas, weight = point_areas(Q)
    eliminate_cell(Q[:2_600], 1_300, elimination_radius(areas, 1_500, weight=weight), halo=Q[2_600:],
                   decided=np.ones(400, dtype=bool), halo_keep=np.arange(400) % 2 == 0, cell_points=1_000)
    eliminate(P, ratio=0.5)
    from .gap import fill_cell  # --max-gap's fill (its greedy cover kernel)

    fill_cell(P, np.arange(len(P)) % 7 == 0, np.zeros((0, 3)), float(r_max), False)


def _partition() -> None:
    from .kernels.bisector import within_any
    from .kernels.closest import nearest_sites, site_tree

    P = _points(200)
    tree = site_tree(np.ascontiguousarray(P[:8]))
    nearest_sites(tree, P, 2)  # the labels (cloudsieve.engine.label)
    nearest_sites(tree, P[::2], 4)
    planes = np.ascontiguousarray(P[:2])
    within_any(P, planes, planes - P[2], np.ones(2), 0.5)  # the halo bands (cloudsieve.engine.halo)
    from .kernels.scatter import group_rows

    group_rows(np.zeros(2, dtype=np.int64), 2)  # the cells' members in memory (cloudsieve.engine.cell_scheme)


def _scores() -> None:
    from .kernels.entropy import entropy_gain, graph_to_input, grouped_gain, reverse_sums, scores_to_input
    from .kernels.knn import knn_scored, knn_unchecked, take_neighbours
    from .kernels.order import grouped_order

    rng = np.random.default_rng(0)
    P = np.ascontiguousarray(rng.random((24, 3)))
    indptr = np.array([0, 12, 24], dtype=np.int64)
    kq = np.array([5, 5], dtype=np.int64)
    d, i = knn_unchecked(P, indptr, kq, np.ones(24, dtype=bool), 1)
    rows = np.arange(24, dtype=np.int64)
    take_neighbours(i, rows, 5)
    take_neighbours(i, rows, 5, rows)
    cl = np.repeat(np.arange(2, dtype=np.int64), 12)
    nbr = np.ascontiguousarray(i[:, :5])
    kr = np.full(24, 4, dtype=np.int64)
    entropy_gain(rows, cl, 2, d[:, 3].copy(), d[:, 4].copy(), nbr, kr, 3.0, 24)
    entropy_gain(rows, cl, 2, d[:, 3].copy(), d[:, 4].copy(), nbr, kr, 3.0, 24, target_cluster=cl)
    reverse_sums(nbr, kr, d[:, 0].copy(), d[:, 1].copy(), 24)
    # the path of the scores without context (entropy.score_unchecked)
    order, indptr = grouped_order(P, cl, 2, 17)
    kcl = np.array([4, 4], dtype=np.int64)
    koff = np.array([0, 48, 96], dtype=np.int64)
    rk, rk1, nb, _ = knn_scored(P, order, indptr, kcl, koff, 1)
    scored = np.ones(24, dtype=bool)
    gain = grouped_gain(rk, rk1, indptr, kcl, koff, scored, nb, 3.0)
    scores_to_input(order, indptr, kcl, scored, ~scored, np.array([12, 12]), gain)
    graph_to_input(order, indptr, kcl, koff, scored, nb, 4)


def _elimination_tail() -> None:
    """The kernels a default-rule run calls last (packing counts, elimination loop, relocation, merge scatter) on two points.

    A second process compiles these ahead (:data:`AHEAD`), the loop and relocation
    first: the run compiles packing and ``nearest_kept`` itself meanwhile, leaving
    time for the loop, the longest compilation.
    """
    from .kernels import eliminate as ke
    from .kernels.grid import nearest_kept
    from .kernels.packing import packing_from_lists

    P = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    cell, cstart, nstart, ncells = np.array([0, 0]), np.array([0, 2]), np.array([0, 1]), np.array([0])  # one cell
    nptr, nbr = np.array([0, 1, 2]), np.array([1, 0], dtype=np.int32)  # each point the other's only neighbour
    tie, flags, ones = np.array([0, 1]), np.array([1, 0], dtype=np.uint8), np.ones(2)
    ke.eliminate(P, cell, cstart, nstart, ncells, nptr, nbr, np.full(2, 0.5, dtype=np.float32), ones / 2,
                 np.zeros(2, dtype=np.uint8), np.ones(2, dtype=np.uint8), ones, ones, ones / 2, tie,
                 1.0, 1.0, 1, 0.4, 8.0, 10.0, 1, 2, np.full((2, 8), -1, dtype=np.int32), np.array([-1, -1]))
    ke.relocate(P, cell, flags, np.ones(2, dtype=np.uint8), tie, 0.25)
    packing_from_lists(P, nptr, nbr, np.ones(2, dtype=np.uint8), np.array([0.25, 0.5]))
    nearest_kept(P, cell, cstart, nstart, ncells, flags, tie, np.array([0, 1]))
    _merge_scatter()


def _method(method: str) -> Callable[[], None]:
    def warm() -> None:
        from .simplify import simplify_points

        simplify_points(_points(), method=method, rule=rules.THRESHOLD_RULE, cluster_size=100)

    return warm


def _rules() -> None:
    from .simplify import simplify_points

    for rule in rules.RULES.values():  # the entropy rules with a target
        if rule.clusters and rule.takes_target:
            simplify_points(_points(), rule=rule.name, ratio=0.5, cluster_size=100)


#: the function of each warm-up target (:data:`cloudsieve.rule_table.TARGETS`, in that order)
_RUN: dict[str, Callable[[], None]] = {
    "common": _common,
    "partition": _partition,
    "eliminate": _eliminate,
    "scores": _scores,
    "km": _method("km"),
    "fcm": _method("fcm"),
    "rules": _rules,
}
assert tuple(_RUN) == TARGETS, "every target named in cloudsieve.rule_table.TARGETS has its function here"

#: the part of a target a second process can compile meanwhile, and the kernel whose cache file
#: tells whether it is compiled
AHEAD: dict[str, tuple[Callable[[], None], str]] = {"eliminate": (_elimination_tail, "eliminate._eliminate")}


def ahead_parts(targets: Iterable[str]) -> list[str]:
    """The targets with a part in :data:`AHEAD` whose kernel numba's cache lacks (none when the cache index is unreadable)."""
    import importlib
    import os

    out = []
    for name in targets:
        if name not in AHEAD:
            continue
        module, kernel = AHEAD[name][1].rsplit(".", 1)
        try:
            dispatcher = getattr(importlib.import_module(f"{__package__}.kernels.{module}"), kernel)
            cached = os.path.exists(dispatcher._cache._cache_file._index_path)
        except Exception:  # noqa: BLE001 - numba's internals: unknown means "do not compile ahead"
            continue
        if not cached:
            out.append(name)
    return out


#: ``cloudsieve warmup`` on two cores or more: the targets a second process compiles; the first
#: compiles ``scores`` first (:func:`split_targets`), so no kernel compiles twice
SECOND: tuple[str, ...] = ("km", "fcm", "rules")


def split_targets(targets: Iterable[str]) -> tuple[list[str], list[str]]:
    """*targets* as (this process's, the second's): the second gets :data:`SECOND`, this one starts with ``scores``."""
    targets = list(targets)
    second = [t for t in targets if t in SECOND]
    first = [t for t in targets if t not in SECOND]
    if not first or not second:
        return targets, []
    return sorted(first, key=lambda t: t != "scores"), second


def warm_report(targets: Iterable[str], on_target: Callable[[str, dict], None] | None = None) -> dict:
    """:func:`warm_up` of each target, with what numba compiled:
    ``{target: {"seconds", "compile_seconds", "compiled": {kernel: seconds}}}``; ``on_target`` after each.
    """
    from .kernels.compile_log import CompileLog

    out = {}
    for name in targets:
        with CompileLog() as log:
            seconds = warm_up([name])
        kernels = {k: round(v, 3) for k, v in sorted(log.seconds.items(), key=lambda kv: -kv[1])
                   if k.startswith("cloudsieve.")}
        out[name] = {"seconds": round(seconds, 3), "compile_seconds": round(log.total, 3), "compiled": kernels}
        if on_target is not None:
            on_target(name, out[name])
    return out


def warm_ahead(targets: Iterable[str]) -> None:
    """Compile the :data:`AHEAD` parts of *targets* (in the second process)."""
    for name in targets:
        AHEAD[name][0]()


def warm_up(targets: Iterable[str] = ("common", "partition", "scores"), *,
            report: Callable[[str, float], None] | None = None) -> float:
    """Call the kernels of each of *targets* (names of :data:`cloudsieve.rule_table.TARGETS`) once on a tiny input.

    ``report(target, seconds)`` is called after each. Returns the seconds spent.

    Raises
    ------
    KeyError
        An unknown target name.
    """
    t_all = time.perf_counter()
    for name in targets:
        t0 = time.perf_counter()
        _RUN[name]()
        if report is not None:
            report(name, time.perf_counter() - t0)
    return time.perf_counter() - t_all


if __name__ == "__main__":  # the second process of a run or of ``cloudsieve warmup`` (cloudsieve.engine.ahead)
    import json
    import sys

    from ..lifeline import die_with_parent

    die_with_parent()
    if sys.argv[1:2] == ["--targets"]:  # whole targets: what each compiled, as JSON
        print(json.dumps(warm_report(sys.argv[2:])))
    else:
        warm_ahead(sys.argv[1:])
