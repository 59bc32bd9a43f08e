"""A store's group and arrays opened once per stage in a task's process (handles.py)."""

from __future__ import annotations

import numpy as np
from conftest import shared_file

from cloudsieve.store import PointStore, ingest
from cloudsieve.handles import per_stage


def _open_twice(path: str) -> tuple:
    """Two openings in one task: the group, an array looked up in each, and a derived array's shape."""
    a, b = PointStore.open(path, "r+"), PointStore.open(path, "r+")
    return a.group is b.group, a.group["intensity"] is b.group["intensity"], "intensity" in b.group


def test_a_stage_opens_a_store_once_and_nothing_is_kept_outside(tmp_path):
    path = str(tmp_path / "s.zarr")
    ingest(shared_file("simple.laz"), path, chunk_size=100)
    assert _open_twice(path)[:2] == (False, False)  # the driver: every opening reads the store
    stage = per_stage(_open_twice)
    assert stage.__name__ == "_open_twice"
    assert stage(path) == (True, True, True)
    assert _open_twice(path)[:2] == (False, False)  # past the task: nothing kept for the caller


def _create_then_open(path: str, n: int) -> tuple:
    st = PointStore.open(path, "r+")
    first = st.group["simplify/mask"].shape if "simplify/mask" in st.group else None
    st.create_array("simplify/mask", shape=(n,), dtype="int32", overwrite=True)  # drops what this process kept
    return first, PointStore.open(path, "r+").group["simplify/mask"].shape


def test_an_array_created_in_a_task_is_seen_by_its_later_lookups(tmp_path):
    path = str(tmp_path / "s.zarr")
    ingest(shared_file("simple.laz"), path, chunk_size=100)
    PointStore.open(path, "r+").create_array("simplify/mask", shape=(5,), dtype="int32")
    stage = per_stage(_create_then_open)
    assert stage(path, 7) == ((5,), (7,))
    assert stage(path, 9) == ((7,), (9,))
    assert per_stage(_create_then_open)(path, 3) == ((9,), (3,))  # a new stage: nothing of the last one
    np.testing.assert_array_equal(PointStore.open(path).read("simplify/mask"), np.zeros(3, np.int32))
