"""The out-of-core run: :func:`run_store` runs the stages :mod:`.simplify` lists on a checked run
(:func:`.checks.check_run`). A small input's run (:mod:`.small`) imports none of this."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..core._validation import ratio_count
from ..core.rules import ELIMINATION
from ..core.rules import get as get_rule
from ..errors import TargetNotMetError
from ..io import detect_format
from ..paths import local_path
from ..progress import both, stage_bar
from .. import staging
from ..store import delete_store, export
from ..rule_table import targets_of
from . import cells, merge, workstore
from . import threshold as thresholds
from .checks import RunChecks
from .cell_scheme import run_cells, stage_params
from .class_policy import ClassPolicy, run_class_counts, run_class_rows
from .density import DensityTarget, run_area_counts
from .eliminate import StoreCells
from .partition import build_partition, reusable_partition
from .runner import PeakMemory, Runner
from .sample import IngestSample
from .summary import Summary

__all__ = ["run_store"]

logger = logging.getLogger("cloudsieve.engine.simplify")  # the name users filter on


@dataclass(frozen=True)
class RunHooks:
    """How a run reports: *account* once the kept count is known, before DST is written; *progress* with
    the points done; *finished* with the summary before it is stored; *bars*, *notify* as in simplify."""

    account: Callable[[Summary], None]
    progress: Callable[[int], None]
    finished: Callable[[Summary], Summary]
    bars: Any = None
    notify: Callable[[str], None] | None = None


def run_store(checked: RunChecks, src: str, dst: str, opts: dict, params: dict, summary: Summary, hooks: RunHooks, *,
              client=None) -> Summary:
    """The run through the work store of *checked*, reported through *hooks*; returns *summary*."""
    account, progress, bars, notify, finished = hooks.account, hooks.progress, hooks.bars, hooks.notify, hooks.finished
    (rule, ratio, count, cluster_size, cell_size, workers, memory_limit, seed, overwrite, format, chunk_size,
     context, k0, k_min, drop_invalid, tile_size) = (
        opts[name] for name in ("rule", "ratio", "count", "cluster_size", "cell_size", "workers", "memory_limit",
                                "seed", "overwrite", "format", "chunk_size", "halo_context", "k0", "k_min",
                                "drop_invalid", "tile_size"))
    st, store_path, default_store = checked.store, checked.store_path, checked.default_store
    scheduler = checked.scheduler

    with PeakMemory() as peak:
        runner = Runner(scheduler, workers, memory_limit, client, bars, warm=targets_of(rule))

        def close_runner():
            if runner.remote_client is not None:  # no sample in flight on a closing client
                peak.stop()
            runner.close()

        summary.scheduler = runner.name
        if runner.remote_client is not None:  # the workers' memory, not the client's
            peak.watch_workers(runner.remote_client)
        if runner.dashboard_link:
            logger.info("dask dashboard: %s", runner.dashboard_link)
            if notify is not None:
                notify(f"dask dashboard: {runner.dashboard_link}")
        try:
            t0 = time.perf_counter()
            taken = None  # sampled during a streamed ingest
            if st is None:
                runner.prestart()  # workers start during the ingest
                taken = IngestSample(cell_size, seed)
                st = workstore.ingest_source(src, store_path, chunk_size=chunk_size, progress=progress,
                                             drop_invalid=drop_invalid, on_chunk=taken, run=runner, bars=bars)
                workstore.record_params(st, params, overwrite)
            summary.store = store_path
            summary.points_in = st.count
            summary.seconds["ingest"] = time.perf_counter() - t0
            summary.stage_cpu["ingest"] = _cpu_lap(runner, summary)

            t0 = time.perf_counter()
            target, policy, classes = None, ClassPolicy.from_options(opts), None
            if ratio is not None or count is not None:
                target = ratio_count(ratio, st.count) if ratio is not None else min(int(count), st.count)
            if policy is not None:  # each group's target; r_max for all the points kept
                classes = run_class_counts(st, runner)
                target = policy.asked(classes)
            density = DensityTarget.from_options(opts)
            if density is not None:  # r_max for all the points kept
                before = run_area_counts(st, runner, density)
                target = density.target(before[1])
            elim = target if get_rule(rule).engine == ELIMINATION else None
            halo = bool(context) or elim is not None
            part = reusable_partition(st, cell_size=cell_size, cluster_size=cluster_size, seed=seed, halo=halo,
                                      eliminate_target=elim)
            if part is None:
                workstore.clear_derived(st)
                part = build_partition(
                    st, cell_size=cell_size, cluster_size=cluster_size, seed=seed, run=runner, k0=k0, k_min=k_min,
                    halo=halo, eliminate_target=elim, sample=taken.sample(st.count) if taken else None,
                )
            if policy is not None:
                run_class_rows(st, runner)
            progress(st.count)
            summary.cells = part.n_cells
            summary.seconds["partition"] = time.perf_counter() - t0
            summary.stage_cpu["partition"] = _cpu_lap(runner, summary)

            t0 = time.perf_counter()
            block = workstore.region_block(cell_size, remote=local_path(st.path) is None)
            regions, total = workstore.regions(part.cell_counts, block)
            workstore.ensure_cell_arrays(st, part.n_cells, total, block, regions, workstore.region_block(cell_size),
                                         groups=0 if policy is None else policy.groups)
            if target is None:
                computed, reused, points = cells.run_keep(st, part, regions, params, runner)
                progress(points)
            elif elim is not None:
                policy_params = stage_params(policy, density)
                if params.get("max_gap") is not None:
                    workstore.ensure_fill_array(st)
                computed, reused, points, distinct = run_cells(StoreCells(st.path), part, regions,
                                                               {**params, **policy_params}, runner,
                                                               target if policy is None else policy.targets(classes))
                if params.get("max_gap") is not None:  # the gap bound: a fill, then its check, every cell final
                    from .gap import run_gap

                    summary.gap = run_gap(StoreCells(st.path), part, regions, {**params, **policy_params}, runner)
                progress(points)
                summary.duplicates = summary.points_in - distinct  # from the shares: no read per cell
            else:
                reused, points = cells.run_score(st, part, regions, params, runner)
                progress(points)
                with runner.stage("cells: threshold"):  # one bar for all rounds
                    summary.threshold = thresholds.global_threshold(st, part, regions, runner, st.count - target)
                computed = cells.run_apply(st, part, regions, params, runner, summary.threshold)
            summary.cells_computed, summary.cells_reused = computed, reused
            if target is None or elim is None:
                summary.duplicates = int(st.group["simplify/duplicates"][:].sum())
            summary.seconds["cells"] = time.perf_counter() - t0
            summary.stage_cpu["cells"] = _cpu_lap(runner, summary)

            t0 = time.perf_counter()
            workstore.ensure_keep_array(st)
            kept_counts = merge.run_merge(st, runner, fill=summary.gap is not None)
            summary.kept = sum(kept_counts)
            summary.removed = summary.points_in - summary.kept
            if policy is not None:
                summary.classes = policy.report(classes, run_class_counts(st, runner, "simplify/keep"))
            if density is not None:
                summary.density = density.report(before, run_area_counts(st, runner, density, "simplify/keep"))
            account(summary)
            progress(st.count)
            summary.seconds["merge"] = time.perf_counter() - t0
            summary.stage_cpu["merge"] = _cpu_lap(runner, summary)

            t0 = time.perf_counter()
            # tasks write the parts or tiles; other formats (PLY, XYZ) stream here
            tasks = tile_size is not None or detect_format(dst, format) in ("las", "laz", "copc")
            if not tasks:
                close_runner()  # frees the workers' memory
            staging.remove_stale_scratch(dst, checked.sources)  # a URL: parts an interrupted run left
            with stage_bar(bars, "export", summary.kept, "pt") as bar:
                export(st, dst, format=format, mask="simplify/keep", overwrite=overwrite, progress=both(bar, progress),
                       run=runner if tasks else None, counts=kept_counts if tasks else None, tile_size=tile_size)
            summary.seconds["export"] = time.perf_counter() - t0
            summary.cpu_seconds["workers"], retries = runner.worker_counts()
            summary.stage_cpu["export"] = max(0.0, summary.cpu_seconds["workers"] - sum(summary.stage_cpu.values()))
            summary.storage = {"retries": retries}  # the driver's are added at the end
        except TargetNotMetError:
            if default_store:  # complete and would end the same
                delete_store(store_path)
            raise
        finally:
            close_runner()
    summary.peak_memory, summary.peak_memory_of = int(peak.peak), peak.scope
    finished(summary)
    workstore.record_summary(st, summary.to_dict())
    if default_store:
        delete_store(store_path)
        summary.store = ""
    return summary


def _cpu_lap(runner, summary) -> float:
    """The workers' CPU seconds since the stages *summary* holds (one request to a cluster's workers)."""
    return max(0.0, runner.worker_counts()[0] - sum(summary.stage_cpu.values()))
