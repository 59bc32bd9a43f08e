"""The cell tasks' arguments: one small frozen CellTask per cell, independent of the number of cells."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from engine_data import plane, write_laz

from cloudsieve.engine import partition as P
from cloudsieve.engine import simplify, workstore
from cloudsieve.engine.cells import CellTask, cell_seed, cell_tasks, largest_first
from cloudsieve.store import PointStore

FAST = dict(method="km", rule="threshold", cluster_size=100, seed=7)


@pytest.mark.parametrize("context", [False, True])
def test_task_arguments_do_not_grow_with_the_number_of_cells(tmp_path, context):
    """Cell tasks get the centres of their cell and halo sources only, and read their runs from the store."""
    src = write_laz(tmp_path / "p.laz", plane(12_000, side=100.0))
    store = tmp_path / "w.zarr"
    simplify(src, tmp_path / "a.laz", cell_size=300, chunk_size=3_000, scheduler="sync", store=store, halo_context=context,
             **FAST)
    st = PointStore.open(str(store))
    part = P.Partition.load(st)
    assert part.n_cells == 40
    regions, _ = workstore.regions(part.cell_counts, workstore.region_block(300))
    params = st.attrs[workstore.SIMPLIFY_ATTR]["params"]  # the parameters the run recorded
    assert params["context"] == context and params["cell_size"] == 300
    tasks = cell_tasks(st, part, regions, range(part.n_cells), params)
    assert [t.cell for t in tasks] == list(range(part.n_cells))
    for task in tasks:
        assert isinstance(task, CellTask)
        assert set(task.centers) == {task.cell, *task.halo} and (len(task.halo) > 0) == context
        assert len(task.halo) < part.n_cells / 2
        fields = [*dataclasses.astuple(task), *task.centers.values()]
        assert all(np.size(a) < part.n_cells for a in fields if isinstance(a, np.ndarray))
        assert len(pickle.dumps((task,))) < 2_000 + 200 * len(task.halo)
        assert task.region == regions[task.cell] and task.params["threads"] == 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        tasks[0].cell = 3


def test_largest_cells_first_ties_by_id():
    part = P.Partition(
        centers=np.zeros((5, 3)), cell_counts=np.array([3, 7, 3, 9, 0]), halo_ptr=np.zeros(6, np.int64),
        halo_src=np.empty(0, np.int64), margin=0.0, chunk_size=10, n_chunks=3, n_runs=5,
    )
    assert largest_first(part, [0, 1, 2, 3, 4]) == [3, 1, 0, 2, 4]
    assert largest_first(part, [2, 0]) == [0, 2]
    assert largest_first(part, []) == []


def test_cell_seed_depends_on_the_seed_and_the_cell_only():
    assert cell_seed(0, 5) == cell_seed(0, 5)
    assert len({cell_seed(0, j) for j in range(100)}) == 100
    assert cell_seed(1, 5) != cell_seed(0, 5)
    assert 0 <= cell_seed(7, 3) < 2**32
